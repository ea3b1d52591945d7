/*
 * KinComp web UI: the settings pane (on/off, mode, parameters with their units and signs,
 * backlash, limits, when changes take effect, firmware export with copy buttons).
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var notify = K.notify;
    var copyText = K.copyText;
    var about = K.about;
    var trMsg = K.trMsg;

    function KinCompSettingsViewModel(parameters) {
        var self = this;
        self.access = parameters[0];
        self.loginState = parameters[1];
        self.sensorSettings = parameters[2];  // the live sensor's part of this page
        self.limitsSettings = parameters[3];  // the printer's motion limits' part
        self.docs = ko.observableArray([]);

        // the plain fields, as the server declares them (the template renders the same list)
        var declared = $("#kincomp_settings_fields").text();
        self.settingsForm = new K.SettingsForm(declared ? JSON.parse(declared) : []);
        self.limits = ko.observable(null);
        self.engine = ko.observable("");  // "compiled" or "python" (kernel.py)
        self.conflicts = ko.observableArray([]);
        self.version = ko.observable("");
        self.homepage = ko.observable("");
        self.firmwareHelp = ko.observable("");
        // the firmware export: per firmware its ready-to-paste sections and notes
        self.exports = ko.observableArray([]);
        self.fwTab = ko.observable("marlin");
        self.errors = ko.observable({});
        self.formError = ko.observable("");
        self.savedMessage = ko.observable("");
        // what is wrong with the stored settings (compensation is off until it is fixed)
        self.settingsProblem = ko.observable("");
        self.saving = ko.observable(false);
        // the printer profile whose settings the page shows (sent with a save: the server
        // refuses it when another profile's are in force by then) and its name; whether a
        // save was refused for that reason (the page offers to reload)
        self.profileId = null;
        self.profileName = ko.observable("");
        self.deletedProfiles = ko.observableArray([]);
        self.staleProfile = ko.observable(false);
        self.loaded = null; // the settings as last loaded (to keep what the form does not show)

        // (backlash: a value per axis, or its value at two positions: shown by hand here)
        var shown = K.shownNumber;
        var kept = K.keptNumber;
        self.shown = shown;
        self.backlash = _.map(["x", "y", "z"], function (axis) {
            return {
                axis: axis,
                label: axis.toUpperCase(),
                path: "params.backlash." + axis,
                varies: ko.observable(false),
                single: ko.observable("0"),
                at0: ko.observable("0"),
                um0: ko.observable("0"),
                at1: ko.observable("0"),
                um1: ko.observable("0")
            };
        });

        self.limitsText = ko.pureComputed(function () {
            var l = self.limits();
            if (!l) return gettext("No bed volume known (printer profile).");
            return _.sprintf(
                gettext("Bed volume from the printer profile: X %(x0)s…%(x1)s, Y %(y0)s…%(y1)s, Z %(z0)s…%(z1)s mm"),
                {x0: l[0], x1: l[1], y0: l[2], y1: l[3], z0: l[4], z1: l[5]}
            );
        });

        self.fieldError = function (path) {
            var errs = self.errors();
            return errs[path] || "";
        };

        self.fromStatus = function (status) {
            var s = status.settings;
            self.loaded = s;
            var profile = status.profile || {};
            self.profileId = profile.id === undefined ? null : profile.id;
            self.profileName(profile.name || "");
            self.deletedProfiles(profile.deleted || []);
            self.staleProfile(false);
            self.settingsForm.show(s);
            var p = s.params;
            _.each(self.backlash, function (b) {
                var v = p.backlash[b.axis];
                b.table = _.isArray(v) ? v : null; // as stored (may have more than 2 points)
                if (_.isArray(v)) {
                    b.varies(true);
                    b.at0(shown(v[0].at_mm));
                    b.um0(shown(v[0].um));
                    b.at1(shown(v[v.length - 1].at_mm));
                    b.um1(shown(v[v.length - 1].um));
                    b.single(shown(v[0].um));
                } else {
                    b.varies(false);
                    b.single(shown(v));
                }
            });
            self.limits(status.limits);
            self.engine(status.engine || "");
            var a = about(status);
            self.version(a.version);
            self.homepage(a.homepage);
            self.firmwareHelp(a.firmwareHelp);
            self.docs(K.docs(a.homepage));
            self.showFirmware(status.equivalents);
            self.conflicts(
                _.map(status.firmware.conflicts || {}, function (where, kind) {
                    return kind + ": " + where;
                })
            );
        };

        self.showFirmware = function (eq) {
            if (!eq || !eq.export) return;
            self.exports(_.map(["marlin", "klipper", "reprapfirmware"], function (key) {
                var fw = eq.export[key] || {name: key, sections: [], notes: []};
                return {
                    key: key,
                    name: fw.name,
                    notes: _.map(fw.notes, trMsg),
                    sections: _.map(fw.sections, function (section) {
                        var copied = ko.observable("");
                        return {
                            key: key + "_" + section.key,
                            title: trMsg(section.title),
                            text: section.text,
                            copied: copied,
                            copy: function (data, event) {
                                copyText(section.text, $(event.target).closest(".kincomp-fw-section"),
                                    function (ok) {
                                        copied(ok ? gettext("Copied") : gettext("Select the text and copy it"));
                                        setTimeout(function () { copied(""); }, 3000);
                                    });
                            }
                        };
                    })
                };
            }));
        };

        self.load = function () {
            return K.get(API("status")).done(function (status) {
                self.fromStatus(status);
                var errs = {};
                if (status.settings_problem_field) errs[status.settings_problem_field] = status.settings_problem;
                self.errors(errs);
                self.settingsProblem(status.settings_problem || "");
                self.formError("");
            });
        };

        self.collect = function () {
            // the settings document from the form; field errors for what is not a number
            var errs = {};
            var number = function (path, text) {
                var v = num(text);
                if (isNaN(v)) {
                    errs[path] = gettext("Enter a number");
                }
                return v;
            };
            // the parameters the form does not show are kept as loaded
            var data = {params: JSON.parse(JSON.stringify(self.loaded.params))};
            self.settingsForm.collect(data, errs, num);
            var params = data.params;
            var stored = self.loaded.params;
            _.each(self.backlash, function (b) {
                var t = b.table;
                var sv = stored.backlash[b.axis];
                var first = t ? t[0] : {}, last = t ? t[t.length - 1] : {};
                var ends = {
                    at0: kept(b.at0(), first.at_mm), um0: kept(b.um0(), first.um),
                    at1: kept(b.at1(), last.at_mm), um1: kept(b.um1(), last.um)
                };
                var untouched = t && t.length > 2 &&
                    num(ends.at0) === t[0].at_mm && num(ends.um0) === t[0].um &&
                    num(ends.at1) === t[t.length - 1].at_mm && num(ends.um1) === t[t.length - 1].um;
                if (b.varies() && untouched) {
                    params.backlash[b.axis] = t; // the form shows the ends; keep the inner points
                } else if (b.varies()) {
                    params.backlash[b.axis] = [
                        {at_mm: number(b.path, ends.at0), um: number(b.path, ends.um0)},
                        {at_mm: number(b.path, ends.at1), um: number(b.path, ends.um1)}
                    ];
                } else {
                    params.backlash[b.axis] = number(b.path, kept(b.single(), _.isArray(sv) ? sv[0].um : sv));
                }
            });
            return {errors: errs, data: data};
        };

        self.save = function () {
            self.savedMessage("");
            if (!self.loaded) return $.Deferred().reject().promise();
            // the server names the field first: "params.scale_ppm.x: ..."
            var collected = self.collect();
            if (self.profileId !== null) collected.data.expected_profile = self.profileId;
            return K.saveSettings(self, collected, function (path) {
                return _.find(self.allPaths(), function (p) {
                    return path === p || path.indexOf(p + ".") === 0 || path.indexOf(p + "[") === 0;
                });
            }).done(function () {
                self.load();
            });
        };

        // the page's one Save: the settings and, if they were changed, the live sensor's
        // part and the motion limits (each shows its own errors next to its fields)
        self.saveAll = function () {
            // one after the other: each save is read-merge-write on the server, and a part
            // saved while another's answer is pending would reload stale fields
            var parts = _.filter([self.sensorSettings, self.limitsSettings], function (p) {
                return p && p.changed();
            });
            var all = $.Deferred();
            var next = function (i) {
                if (i >= parts.length) {
                    self.save().done(all.resolve).fail(all.reject);
                    return;
                }
                parts[i].save().always(function () { next(i + 1); });
            };
            next(0);
            return all.promise();
        };
        self.reloadAll = function () {
            if (self.sensorSettings) self.sensorSettings.load();
            if (self.limitsSettings) self.limitsSettings.load();
            return self.load();
        };

        self.allPaths = function () {
            return self.settingsForm.paths.concat(_.pluck(self.backlash, "path"));
        };

        self.onSettingsShown = function () {
            self.savedMessage("");
            self.load();
        };

        self.onSettingsBeforeSave = function () {
            // OctoPrint's own Save button saves the KinComp pane too (through KinComp's API,
            // which refuses invalid values with a message instead of dropping them)
            if (!self.loaded) return;
            var now = JSON.stringify(self.collect().data);
            var before = JSON.stringify(self.settingsForm.stored(
                {params: JSON.parse(JSON.stringify(self.loaded.params))}));
            if (now !== before) {
                self.save().fail(function () {
                    notify({
                        title: gettext("KinComp settings not saved"),
                        text: self.formError(),
                        type: "error",
                        hide: false
                    });
                });
            }
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompSettingsViewModel,
        dependencies: ["accessViewModel", "loginStateViewModel", "kinCompSensorSettingsViewModel",
                       "kinCompLimitsViewModel"],
        elements: ["#settings_plugin_kincomp"]
    });
});
