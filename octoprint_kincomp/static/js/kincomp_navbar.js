/*
 * KinComp in OctoPrint's top bar: "KinComp" with the compensation state (on/off; "no
 * calibration" when the printer profile in force has none; its name in the title), one click
 * to the calibration tab wherever OctoPrint has put it (its overflow menu on narrow
 * windows). Links with the class kincomp-open-tab (the wizard, the settings) open the tab
 * the same way, closing the dialog they are in.
 */
$(function () {
    "use strict";

    var openTab = function () {
        // the settings dialog or the wizard: closed first, the tab is behind them
        $("#settings_dialog.in, #wizard_dialog.in").modal("hide");
        var link = $('#tabs a[href="#tab_plugin_kincomp"]').first();
        if (link.length) link.tab("show");
        $("html,body").scrollTop(0);
        return false;
    };
    window.KinComp.openTab = openTab;
    $(document).on("click", "a.kincomp-open-tab", function (event) {
        event.preventDefault();
        openTab();
    });

    function KinCompNavbarViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.tab = parameters[2];

        // only for who may see KinComp's status (as the tab itself)
        self.visible = ko.pureComputed(function () {
            self.loginState.currentUser();
            var perm = self.access.permissions.STATUS;
            return !!(perm && self.loginState.hasPermission(perm));
        });
        self.title = ko.pureComputed(function () {
            var profile = self.tab.profileName()
                ? " " + _.sprintf(gettext("Printer profile: %(profile)s."), {profile: self.tab.profileName()})
                : "";
            if (!self.tab.profileCalibrated()) {
                return gettext("KinComp: this printer profile has no calibration, prints go out uncompensated. Click to open the calibration tab.") + profile;
            }
            return (self.tab.enabled()
                ? gettext("KinComp: compensation is on. Click to open the calibration tab.")
                : gettext("KinComp: compensation is off. Click to open the calibration tab.")) + profile;
        });
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompNavbarViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "kinCompTabViewModel"],
        elements: ["#navbar_plugin_kincomp"]
    });
});
