/*
 * KinComp web UI: the printer's motion limits on the settings page (what the firmware said to
 * M503, or the text a Klipper user pasted, combined with the printer profile's axis speeds).
 * Feeds in mm/min, accelerations in mm/s^2. Saved (settings key "motion_limits") by the
 * settings page's one Save when the text was changed (kincomp_settings.js saveAll).
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;

    function KinCompLimitsViewModel(parameters) {
        var self = this;
        self.access = parameters[0];
        self.loginState = parameters[1];
        self.text = ko.observable("");
        self.status = ko.observable(null);
        self.error = ko.observable("");
        self.saved = ko.observable("");
        self.busy = ko.observable(false);
        self.profileId = null;
        self.staleProfile = ko.observable(false);  // a save refused: another profile in force

        self.canWrite = ko.pureComputed(function () {
            return K.canAdmin(self);
        });

        var value = function (v, digits) {
            return v === undefined || v === null ? "–" : K.fmt(v, digits);
        };

        self.rows = ko.pureComputed(function () {
            var st = self.status();
            var eff = (st && st.effective) || {};
            var feeds = eff.max_feed_mm_min || {}, accels = eff.max_accel_mm_s2 || {};
            var src = eff.sources || {};
            return _.map(["x", "y", "z"], function (a) {
                var from = _.uniq(_.compact([src["max_feed_mm_min." + a], src["max_accel_mm_s2." + a]]));
                return {axis: a, feed: value(feeds[a], 0), accel: value(accels[a], 0),
                        from: from.length ? from.join(", ") : gettext("not known")};
            });
        });

        self.sourceText = ko.pureComputed(function () {
            var st = self.status();
            var stated = (st && st.stated) || {};
            if (stated.source === "m503")
                return _.sprintf(gettext("Read from the printer (%(firmware)s) on %(date)s."),
                                 {firmware: stated.firmware || "?", date: stated.captured || "?"});
            if (stated.source === "pasted") return gettext("Entered by hand.");
            return gettext("No limits stated by the firmware yet: only the printer profile's axis speeds apply.");
        });

        self.notes = ko.pureComputed(function () {
            var st = self.status();
            var read = st && st.read;
            return read ? _.map(read.notes_i18n || [], K.trMsg) : [];
        });

        self.storedText = "";
        self.load = function () {
            return K.get(API("status")).done(function (status) {
                // the printer profile these limits are of (a save names it: see settings)
                self.profileId = status.profile ? status.profile.id : null;
                self.staleProfile(false);
                self.status(status.motion_limits || null);
                var stated = (status.motion_limits && status.motion_limits.stated) || {};
                self.storedText = stated.text || "";
                self.text(self.storedText);
            });
        };
        // the text differs from what is stored (the page's one Save then saves it too)
        self.changed = function () {
            return (self.text() || "").trim() !== (self.storedText || "").trim();
        };

        var post = function (text, message) {
            self.error("");
            self.saved("");
            self.busy(true);
            var body = {motion_limits: {text: text, source: text ? "pasted" : "", captured: null}};
            if (self.profileId !== null && self.profileId !== undefined) body.expected_profile = self.profileId;
            return OctoPrint.postJson(API("settings"), body)
                .done(function () {
                    self.saved(message);
                    self.load();
                })
                .fail(function (xhr) {
                    self.error(K.errorText(xhr));
                    self.staleProfile(K.profileChanged(xhr));
                })
                .always(function () {
                    self.busy(false);
                });
        };

        self.save = function () {
            return post(self.text(), gettext("Motion limits saved."));
        };

        self.clear = function () {
            return post("", gettext("Motion limits forgotten: only the printer profile's axis speeds apply."));
        };

        self.read = function () {
            self.error("");
            self.saved("");
            return OctoPrint.postJson(API("limits/read"), {})
                .done(function () {
                    self.saved(gettext("Asked the printer (M503); its answer appears here."));
                })
                .fail(function (xhr) {
                    self.error(K.errorText(xhr));
                });
        };

        self.onSettingsShown = function () {
            self.saved("");
            self.load();
        };

        self.onDataUpdaterPluginMessage = function (plugin, data) {
            if (plugin === "kincomp" && data && data.type === "motion_limits") self.load();
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompLimitsViewModel,
        dependencies: ["accessViewModel", "loginStateViewModel"],
        elements: ["#kincomp_motion_limits"]
    });
});
