/*
 * KinComp web UI: settings pane, calibration tab (test program, measurement, result with the
 * ballbar polar plot, history) and the server's notifications.
 *
 * Units as on the server: squareness um/m, scale ppm, backlash um, positions mm, feeds mm/min.
 * Every string goes through gettext(); server notifications arrive as English message ids
 * with parameters and are translated here.
 */
$(function () {
    "use strict";

    var API = function (path) {
        return OctoPrint.getBlueprintUrl("kincomp") + path;
    };

    var num = function (value) {
        // a number from a text field ("1,5" accepted as 1.5); NaN when it is not one
        if (typeof value === "number") return value;
        var text = String(value === undefined || value === null ? "" : value).trim();
        if (!text.length) return NaN;
        text = text.replace(",", ".");
        return /^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(text) ? parseFloat(text) : NaN;
    };

    var fmt = function (value, digits) {
        if (value === null || value === undefined || isNaN(value)) return "–";
        return Number(value).toFixed(digits === undefined ? 2 : digits);
    };

    var errorText = function (jqXHR) {
        // the server's {"error": ...} message, or the HTTP status
        var response = jqXHR && (jqXHR.responseJSON || jqXHR.response || jqXHR.responseText);
        if (typeof response === "string") {
            try {
                response = JSON.parse(response);
            } catch (e) {
                return response;
            }
        }
        if (response && response.error) return response.error;
        return _.sprintf(gettext("Request failed (%(status)s)"), {
            status: jqXHR ? jqXHR.status : "?"
        });
    };

    var notify = function (options) {
        // text may carry server or user strings (commands, file names): never as HTML
        return new PNotify(_.extend({title_escape: true, text_escape: true}, options));
    };

    // copy text to the clipboard: the Clipboard API where the page may use it (https,
    // localhost), else a selected text area inside ``near`` (a modal dialog keeps the focus
    // inside itself) and the browser's copy command; calls done(ok)
    var copyText = function (text, near, done) {
        if (navigator.clipboard && window.isSecureContext) {
            navigator.clipboard.writeText(text).then(
                function () { done(true); },
                function () { done(false); });
            return;
        }
        var area = $("<textarea readonly></textarea>")
            .css({position: "fixed", top: 0, left: 0, width: "1px", height: "1px", opacity: 0})
            .val(text);
        $(near || "body").append(area);
        area[0].select();
        var ok = false;
        try {
            ok = document.execCommand("copy");
        } catch (e) {
            ok = false;
        }
        area.remove();
        done(ok);
    };

    // KinComp's version and homepage (README) from a /status response
    var about = function (status) {
        var eq = status.equivalents || {};
        return {version: status.version || "", homepage: (eq.about && eq.about.homepage) || "",
                firmwareHelp: (eq.about && eq.about.firmware_help) || ""};
    };

    // a Flot point symbol (Flot itself draws only circles without its symbol plugin)
    var drawCross = function (ctx, x, y, radius) {
        ctx.moveTo(x - radius, y - radius);
        ctx.lineTo(x + radius, y + radius);
        ctx.moveTo(x - radius, y + radius);
        ctx.lineTo(x + radius, y - radius);
    };

    // a message of KinComp's core: {text, template, params} (params may be such messages
    // too), translated here; a plain string as it is
    var trMsg = function (msg) {
        if (!msg || typeof msg !== "object") return msg;
        if (!msg.template) return msg.text;
        var params = _.mapValues(msg.params || {}, trMsg);
        try {
            return _.isEmpty(params) ? gettext(msg.template) : _.sprintf(gettext(msg.template), params);
        } catch (e) {
            return msg.text;
        }
    };

    var translateNotice = function (data) {
        var text = gettext(data.msgid);
        var params = _.mapValues(data.params || {}, trMsg);
        _.each(data.translate || [], function (key) {
            if (_.has(params, key)) params[key] = gettext(params[key]);
        });
        try {
            return _.sprintf(text, params);
        } catch (e) {
            return data.text;
        }
    };

    /* ---------------------------------------------------------------- settings pane */

    function KinCompSettingsViewModel(parameters) {
        var self = this;
        self.access = parameters[0];
        self.loginState = parameters[1];

        self.enabled = ko.observable(false);
        self.mode = ko.observable("on_the_fly");
        self.chordTol = ko.observable("0.01");
        self.limitsPolicy = ko.observable("warn");
        self.applyChanges = ko.observable("next_print");
        self.passThrough = ko.observable(false);
        self.demo = ko.observable(false);
        self.blFraction = ko.observable("1");
        self.blSmoothing = ko.observable("0");
        self.limits = ko.observable(null);
        self.paramsHash = ko.observable("");
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
        self.saving = ko.observable(false);
        self.loaded = null; // the settings as last loaded (to keep what the form does not show)

        var field = function (id, path, label, hint) {
            return {id: id, path: path, label: label, hint: hint, value: ko.observable("0")};
        };
        self.squareness = [
            field("sq_xy", "params.squareness_um_per_m.xy", gettext("XY"),
                gettext("Positive: X grows with Y (the Y axis leans toward +X).")),
            field("sq_xz", "params.squareness_um_per_m.xz", gettext("XZ"),
                gettext("Positive: X grows with Z.")),
            field("sq_yz", "params.squareness_um_per_m.yz", gettext("YZ"),
                gettext("Positive: Y grows with Z."))
        ];
        self.scale = [
            field("sc_x", "params.scale_ppm.x", gettext("X")),
            field("sc_y", "params.scale_ppm.y", gettext("Y")),
            field("sc_z", "params.scale_ppm.z", gettext("Z"))
        ];
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
            self.enabled(s.enabled);
            self.mode(s.mode);
            self.chordTol(String(s.chord_tol_mm));
            self.limitsPolicy(s.limits_policy);
            self.applyChanges(s.apply_changes);
            self.passThrough(s.pass_through_on_error);
            self.demo(!!(s.demo && s.demo.enabled));
            var p = s.params;
            _.each(self.squareness, function (f) {
                f.value(String(p.squareness_um_per_m[f.id.slice(3)]));
            });
            _.each(self.scale, function (f) {
                f.value(String(p.scale_ppm[f.id.slice(3)]));
            });
            _.each(self.backlash, function (b) {
                var v = p.backlash[b.axis];
                b.table = _.isArray(v) ? v : null; // as stored (may have more than 2 points)
                if (_.isArray(v)) {
                    b.varies(true);
                    b.at0(String(v[0].at_mm));
                    b.um0(String(v[0].um));
                    b.at1(String(v[v.length - 1].at_mm));
                    b.um1(String(v[v.length - 1].um));
                    b.single(String(v[0].um));
                } else {
                    b.varies(false);
                    b.single(String(v));
                }
            });
            self.blFraction(String(p.backlash.fraction));
            self.blSmoothing(String(p.backlash.smoothing_mm));
            self.limits(status.limits);
            self.paramsHash(status.params_hash);
            self.engine(status.engine || "");
            var a = about(status);
            self.version(a.version);
            self.homepage(a.homepage);
            self.firmwareHelp(a.firmwareHelp);
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
            return OctoPrint.get(API("status")).done(function (status) {
                self.fromStatus(status);
                self.errors({});
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
            var params = JSON.parse(JSON.stringify(self.loaded.params));
            _.each(self.squareness, function (f) {
                params.squareness_um_per_m[f.id.slice(3)] = number(f.path, f.value());
            });
            _.each(self.scale, function (f) {
                params.scale_ppm[f.id.slice(3)] = number(f.path, f.value());
            });
            _.each(self.backlash, function (b) {
                var t = b.table;
                var untouched = t && t.length > 2 &&
                    num(b.at0()) === t[0].at_mm && num(b.um0()) === t[0].um &&
                    num(b.at1()) === t[t.length - 1].at_mm && num(b.um1()) === t[t.length - 1].um;
                if (b.varies() && untouched) {
                    params.backlash[b.axis] = t; // the form shows the ends; keep the inner points
                } else if (b.varies()) {
                    params.backlash[b.axis] = [
                        {at_mm: number(b.path, b.at0()), um: number(b.path, b.um0())},
                        {at_mm: number(b.path, b.at1()), um: number(b.path, b.um1())}
                    ];
                } else {
                    params.backlash[b.axis] = number(b.path, b.single());
                }
            });
            params.backlash.fraction = number("params.backlash.fraction", self.blFraction());
            params.backlash.smoothing_mm = number("params.backlash.smoothing_mm", self.blSmoothing());
            return {
                errors: errs,
                data: {
                    enabled: self.enabled(),
                    mode: self.mode(),
                    params: params,
                    chord_tol_mm: number("chord_tol_mm", self.chordTol()),
                    limits_policy: self.limitsPolicy(),
                    apply_changes: self.applyChanges(),
                    pass_through_on_error: self.passThrough(),
                    demo: {enabled: self.demo()}
                }
            };
        };

        self.save = function () {
            self.savedMessage("");
            if (!self.loaded) return $.Deferred().reject().promise();
            var collected = self.collect();
            if (!_.isEmpty(collected.errors)) {
                self.errors(collected.errors);
                self.formError(gettext("Some values are not numbers; see the marked fields."));
                return $.Deferred().reject().promise();
            }
            self.saving(true);
            return OctoPrint.postJson(API("settings"), collected.data)
                .done(function () {
                    self.errors({});
                    self.formError("");
                    self.savedMessage(gettext("Saved."));
                    self.load();
                })
                .fail(function (jqXHR) {
                    var msg = errorText(jqXHR);
                    // the server names the field first: "params.scale_ppm.x: ..."
                    var path = msg.split(":")[0];
                    var errs = {};
                    var match = _.find(self.allPaths(), function (p) {
                        return path === p || path.indexOf(p + ".") === 0 || path.indexOf(p + "[") === 0;
                    });
                    if (match) errs[match] = msg.slice(path.length + 1).trim();
                    self.errors(errs);
                    self.formError(msg);
                })
                .always(function () {
                    self.saving(false);
                });
        };

        self.allPaths = function () {
            return _.pluck(self.squareness, "path")
                .concat(_.pluck(self.scale, "path"))
                .concat(_.pluck(self.backlash, "path"))
                .concat(["params.backlash.fraction", "params.backlash.smoothing_mm", "chord_tol_mm"]);
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
            var before = JSON.stringify({
                enabled: self.loaded.enabled, mode: self.loaded.mode, params: self.loaded.params,
                chord_tol_mm: self.loaded.chord_tol_mm, limits_policy: self.loaded.limits_policy,
                apply_changes: self.loaded.apply_changes,
                pass_through_on_error: self.loaded.pass_through_on_error,
                demo: {enabled: !!(self.loaded.demo && self.loaded.demo.enabled)}
            });
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

    /* ---------------------------------------------------------------- calibration tab */

    var rows = function () {
        return [
        ["squareness_um_per_m", gettext("Squareness"), "µm/m"],
        ["scale_mismatch_ppm", gettext("Scale mismatch"), "ppm"],
        ["servo_mismatch_ms", gettext("Servo mismatch"), "ms"],
        ["backlash_um.a_plus", gettext("Backlash +A"), "µm"],
        ["backlash_um.a_minus", gettext("Backlash −A"), "µm"],
        ["backlash_um.b_plus", gettext("Backlash +B"), "µm"],
        ["backlash_um.b_minus", gettext("Backlash −B"), "µm"],
        ["circularity_um.ccw", gettext("Circularity CCW"), "µm"],
        ["circularity_um.cw", gettext("Circularity CW"), "µm"],
        ["circularity_um.bidirectional", gettext("Circularity bidirectional G(b)"), "µm"],
        ["hysteresis_um", gettext("Hysteresis H"), "µm"]
        ];
    };

    var pick = function (obj, path) {
        _.each(path.split("."), function (part) {
            obj = obj === null || obj === undefined ? undefined : obj[part];
        });
        return obj;
    };

    var NICE = [0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];

    function KinCompTabViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.printerState = parameters[2];

        self.step = ko.observable("program");
        self.error = ko.observable("");
        self.busy = ko.observable(false);
        self.enabled = ko.observable(false);
        self.demo = ko.observable(false);
        self.paramsHash = ko.observable("");
        self.version = ko.observable("");
        self.homepage = ko.observable("");
        self.limits = ko.observable([0, 200, 0, 200, 0, 200]);
        self.outdatedFiles = ko.observableArray([]);

        self.canWrite = ko.pureComputed(function () {
            self.loginState.currentUser(); // re-evaluate on login/logout
            var perm = self.access.permissions.PLUGIN_KINCOMP_ADMIN;
            return perm ? self.loginState.hasPermission(perm) : false;
        });

        // step 1
        self.plane = ko.observable("XY");
        self.cx = ko.observable("100");
        self.cy = ko.observable("100");
        self.cz = ko.observable("10");
        self.radius = ko.observable("100");
        self.feed = ko.observable("1850");
        self.checkMounted = ko.observable(false);
        self.checkHeight = ko.observable(false);
        self.checkClear = ko.observable(false);
        self.mountPause = ko.observable(false);
        self.programPath = ko.observable("");
        self.printing = ko.observable(false);

        self.bed = ko.pureComputed(function () {
            // the bed outline in the test plane and the circle, in mm (SVG y points down)
            var l = self.limits() || [0, 200, 0, 200, 0, 200];
            var plane = self.plane();
            var ia = plane === "YZ" ? 1 : 0;
            var ib = plane === "XY" ? 1 : 2;
            var a0 = l[2 * ia], a1 = l[2 * ia + 1], b0 = l[2 * ib], b1 = l[2 * ib + 1];
            var c = [num(self.cx()), num(self.cy()), num(self.cz())];
            var r = num(self.radius());
            var ca = c[ia], cb = c[ib];
            var ok = !isNaN(ca) && !isNaN(cb) && r > 0;
            var fits = ok && ca - r >= a0 && ca + r <= a1 && cb - r >= b0 && cb + r <= b1;
            var pad = Math.max(a1 - a0, b1 - b0) * 0.05;
            return {
                viewBox: [a0 - pad, -(b1 + pad), a1 - a0 + 2 * pad, b1 - b0 + 2 * pad].join(" "),
                x: a0, y: -b1, w: a1 - a0, h: b1 - b0,
                cx: ok ? ca : 0, cy: ok ? -cb : 0, r: ok ? r : 0,
                dot: Math.max(a1 - a0, b1 - b0) / 100,
                fits: fits,
                caption: ok
                    ? _.sprintf(
                          fits
                              ? gettext("%(plane)s plane: the circle fits the bed (%(a0)s…%(a1)s × %(b0)s…%(b1)s mm).")
                              : gettext("%(plane)s plane: the circle does NOT fit the bed (%(a0)s…%(a1)s × %(b0)s…%(b1)s mm)."),
                          {plane: plane, a0: a0, a1: a1, b0: b0, b1: b1}
                      )
                    : gettext("Enter the centre and the radius.")
            };
        });

        self.canPrint = ko.pureComputed(function () {
            return (
                self.canWrite() &&
                self.checkMounted() &&
                self.checkHeight() &&
                self.checkClear() &&
                self.bed().fits &&
                self.printerState.isOperational() &&
                !self.printerState.isPrinting() &&
                !self.busy()
            );
        });

        self.printHint = ko.pureComputed(function () {
            if (!self.printerState.isOperational()) return gettext("Connect the printer first.");
            if (!(self.checkMounted() && self.checkHeight() && self.checkClear()))
                return gettext("Tick the checklist to print.");
            return "";
        });

        self.progressPct = ko.pureComputed(function () {
            var p = self.printerState.progress();
            return p ? Math.round(p) : 0;
        });
        self.progressText = ko.pureComputed(function () {
            return _.sprintf(gettext("Printing the test program: %(pct)s %%"), {pct: self.progressPct()});
        });

        // step 2
        self.sPlane = ko.observable("XY");
        self.sSquareness = ko.observable("");
        self.sMismatch = ko.observable("");
        self.sBlAp = ko.observable("");
        self.sBlAm = ko.observable("");
        self.sBlBp = ko.observable("");
        self.sBlBm = ko.observable("");
        self.aPlane = ko.observable("XY");
        self.aAC = ko.observable("");
        self.aBD = ko.observable("");
        self.aAD = ko.observable("");

        // step 3 and history
        self.run = ko.observable(null);
        self.trMsg = trMsg;
        self.beforeRun = ko.observable(null);
        self.compareRows = ko.observableArray([]);
        self.runs = ko.observableArray([]);
        self.compareBefore = ko.observable("");
        self.compareAfter = ko.observable("");
        self.plotCaption = ko.observable("");

        self.fmt = fmt;

        self.tableRows = ko.pureComputed(function () {
            var run = self.run();
            if (!run) return [];
            var cmp = self.compareRows();
            return _.map(rows(), function (row) {
                var c = _.findWhere(cmp, {key: row[0]});
                return {
                    label: row[1],
                    unit: row[2],
                    value: fmt(pick(run.diagnostics, row[0])),
                    before: c ? fmt(c.before) : "",
                    reduction: c && c.reduction_pct !== null ? fmt(c.reduction_pct, 1) + " %" : ""
                };
            });
        });

        self.proposedRows = ko.pureComputed(function () {
            var run = self.run();
            if (!run || !run.proposed) return [];
            var p = run.proposed;
            var bl = function (v) {
                if (_.isArray(v)) {
                    return _.map(v, function (pt) {
                        return _.sprintf(gettext("%(um)s µm at %(at)s mm"), {um: fmt(pt.um, 1), at: fmt(pt.at_mm, 0)});
                    }).join(", ");
                }
                return fmt(v, 1) + " µm";
            };
            return [
                {label: gettext("Squareness XY"), value: fmt(p.squareness_um_per_m.xy, 1) + " µm/m"},
                {label: gettext("Squareness XZ"), value: fmt(p.squareness_um_per_m.xz, 1) + " µm/m"},
                {label: gettext("Squareness YZ"), value: fmt(p.squareness_um_per_m.yz, 1) + " µm/m"},
                {label: gettext("Scale X"), value: fmt(p.scale_ppm.x, 1) + " ppm"},
                {label: gettext("Scale Y"), value: fmt(p.scale_ppm.y, 1) + " ppm"},
                {label: gettext("Scale Z"), value: fmt(p.scale_ppm.z, 1) + " ppm"},
                {label: gettext("Backlash X"), value: bl(p.backlash.x)},
                {label: gettext("Backlash Y"), value: bl(p.backlash.y)},
                {label: gettext("Backlash Z"), value: bl(p.backlash.z)}
            ];
        });

        self.fail = function (jqXHR) {
            var msg = errorText(jqXHR);
            self.error(msg);
            notify({title: gettext("KinComp"), text: msg, type: "error"});
        };

        self.refresh = function () {
            var perm = self.access.permissions.STATUS;
            if (!perm || !self.loginState.hasPermission(perm)) return;
            OctoPrint.get(API("status")).done(function (status) {
                self.enabled(status.settings.enabled);
                self.demo(status.demo);
                if (status.settings_problem && !self.problemShown) {
                    self.problemShown = true;
                    notify({
                        title: gettext("KinComp settings reset"),
                        text: _.sprintf(gettext("The stored KinComp settings could not be used (%(reason)s); the defaults apply and compensation is off. Check the settings and save them."), {reason: status.settings_problem}),
                        type: "error",
                        hide: false
                    });
                }
                self.paramsHash(status.params_hash);
                var a = about(status);
                self.version(a.version);
                self.homepage(a.homepage);
                if (status.limits) {
                    self.limits(status.limits);
                    if (!self.programTouched) self.defaultsFromProfile(status.limits, status.max_feeds);
                }
            });
            var files = self.access.permissions.FILES_LIST;
            if (files && self.loginState.hasPermission(files)) {
                OctoPrint.get(API("files")).done(function (resp) {
                    self.outdatedFiles(_.pluck(_.where(resp.files, {outdated: true}), "path"));
                });
            }
        };

        // the test circle starts at the bed centre with the largest standard radius that
        // fits (100 mm, else 50, 25), until the user edits the form
        self.programTouched = false;
        self.defaultsFromProfile = function (l, maxFeeds) {
            var half = Math.min(l[1] - l[0], l[3] - l[2]) / 2 - 5;
            // ISO 230-4's 1850 mm/min, or the slowest axis of the XY plane if it is slower
            var feed = 1850;
            if (maxFeeds) {
                _.each(["x", "y"], function (a) {
                    if (maxFeeds[a] > 0) feed = Math.min(feed, maxFeeds[a]);
                });
            }
            self.feed(String(feed));
            var radius = _.find([100, 50, 25], function (r) {
                return r <= half;
            }) || Math.max(5, Math.floor(half));
            self.cx(String((l[0] + l[1]) / 2));
            self.cy(String((l[2] + l[3]) / 2));
            self.cz(String(Math.min(10, l[5])));
            self.radius(String(radius));
            self.programTouched = false;
        };
        _.each(["cx", "cy", "cz", "radius", "feed", "plane"], function (name) {
            self[name].subscribe(function () {
                self.programTouched = true;
            });
        });

        self.programRequest = function (print) {
            return {
                plane: self.plane(),
                centre: [num(self.cx()), num(self.cy()), num(self.cz())],
                radius: num(self.radius()),
                feed: num(self.feed()),
                mount_pause: self.mountPause(),
                print: print
            };
        };

        self.sendProgram = function (print) {
            self.error("");
            self.busy(true);
            return OctoPrint.postJson(API("program"), self.programRequest(print))
                .done(function (resp) {
                    self.programPath(resp.path);
                    self.printing(resp.printing);
                    if (resp.spec && resp.spec.feed_mm_min !== num(self.feed())) {
                        notify({
                            title: gettext("KinComp"),
                            text: _.sprintf(gettext("Feed capped at %(feed)s mm/min (the slowest axis of the plane)."), {feed: resp.spec.feed_mm_min}),
                            type: "info"
                        });
                    }
                })
                .fail(self.fail)
                .always(function () {
                    self.busy(false);
                });
        };

        self.printProgram = function () {
            self.sendProgram(true);
        };
        self.generateOnly = function () {
            self.sendProgram(false);
        };

        self.showRun = function (run) {
            self.run(run);
            self.error("");
            self.step("result");
            self.plotLater();
        };

        self.analysed = function (run) {
            // after "Re-test", beforeRun holds the previous run: the new one is compared to it
            self.compareRows([]);
            self.showRun(run);
            self.loadRuns();
        };

        self.uploadBlob = function (blob, name) {
            self.busy(true);
            self.error("");
            return OctoPrint.upload(API("trace"), blob, name)
                .done(function (result) {
                    self.analysed(result[0]);
                })
                .fail(function (result) {
                    self.fail(result[0]);
                })
                .always(function () {
                    self.busy(false);
                    $("#kincomp_trace_file").val("");
                });
        };

        self.uploadTrace = function (data, event) {
            var file = event.target.files && event.target.files[0];
            if (file) self.uploadBlob(file, file.name);
        };

        self.useSimulated = function () {
            self.busy(true);
            OctoPrint.get(API("demo/trace"), {dataType: "text"})
                .done(function (text) {
                    var blob = new Blob([text], {type: "text/csv"});
                    self.uploadBlob(blob, "simulated_trace.csv");
                })
                .fail(function (jqXHR) {
                    self.busy(false);
                    self.fail(jqXHR);
                });
        };

        self.analyseSummary = function () {
            var summary = {plane: self.sPlane()};
            var put = function (key, text) {
                var v = num(text);
                if (!isNaN(v)) summary[key] = v;
            };
            put("squareness_um_per_m", self.sSquareness());
            put("scale_mismatch_ppm", self.sMismatch());
            put("backlash_a_plus", self.sBlAp());
            put("backlash_a_minus", self.sBlAm());
            put("backlash_b_plus", self.sBlBp());
            put("backlash_b_minus", self.sBlBm());
            OctoPrint.postJson(API("analyze"), {summary: summary}).done(self.analysed).fail(self.fail);
        };

        self.analyseArtifact = function () {
            OctoPrint.postJson(API("analyze"), {
                artifact: {plane: self.aPlane(), ac: num(self.aAC()), bd: num(self.aBD()), ad: num(self.aAD())}
            })
                .done(self.analysed)
                .fail(self.fail);
        };

        self.applyRun = function () {
            var run = self.run();
            if (!run) return;
            OctoPrint.postJson(API("apply"), {run: run.id, enabled: true})
                .done(function (resp) {
                    self.paramsHash(resp.params_hash);
                    self.enabled(true);
                    OctoPrint.get(API("runs/" + run.id)).done(function (fresh) {
                        self.run(fresh);
                    });
                    var waiting = resp.compensation && resp.compensation.pending_params_hash;
                    notify({
                        title: gettext("KinComp"),
                        text: waiting
                            ? gettext("Parameters saved; a print is running, so they and compensation take effect from the next print on.")
                            : gettext("Parameters applied; compensation is on. Re-test to see the improvement."),
                        type: "success"
                    });
                    self.loadRuns();
                })
                .fail(self.fail);
        };

        self.retest = function () {
            // the next result is compared with this one
            self.beforeRun(self.run());
            self.step("program");
        };

        self.loadRuns = function () {
            OctoPrint.get(API("runs")).done(function (resp) {
                self.runs(
                    _.map(resp.runs, function (r) {
                        return _.extend({}, r, {
                            squareness: r.squareness_um_per_m,
                            circularity: r.circularity_um
                        });
                    })
                );
            });
        };

        self.traceUrl = function (run) {
            return API("runs/" + encodeURIComponent(run.id) + "/trace");
        };

        self.showHistory = function () {
            self.step("history");
            self.loadRuns();
        };

        self.openRun = function (summary) {
            OctoPrint.get(API("runs/" + summary.id)).done(function (run) {
                self.beforeRun(null);
                self.compareRows([]);
                self.showRun(run);
            }).fail(self.fail);
        };

        self.compare = function () {
            var a = self.compareBefore(), b = self.compareAfter();
            $.when(OctoPrint.get(API("runs/" + a)), OctoPrint.get(API("runs/" + b)),
                   OctoPrint.get(API("compare?before=" + encodeURIComponent(a) + "&after=" + encodeURIComponent(b))))
                .done(function (ra, rb, cmp) {
                    self.beforeRun(ra[0]);
                    self.compareRows(cmp[0].table);
                    self.showRun(rb[0]);
                })
                .fail(self.fail);
        };

        // an analysis right after a re-test is compared with the run before it
        self.run.subscribe(function (run) {
            var before = self.beforeRun();
            if (!run || !before || before.id === run.id || self.compareRows().length) return;
            OctoPrint.get(API("compare?before=" + encodeURIComponent(before.id) + "&after=" + encodeURIComponent(run.id)))
                .done(function (cmp) {
                    self.compareRows(cmp.table);
                    self.plotLater();
                });
        });

        /* the classic ballbar plot: deviation magnified around the nominal circle */
        self.plotLater = function () {
            window.setTimeout(self.plot, 50);
        };

        self.plot = function () {
            var run = self.run();
            var target = $("#kincomp_plot");
            if (!run || !run.plot || !target.is(":visible")) return;
            target.height(target.width()); // equal scales: a circle stays a circle
            var runs = [run.plot];
            var before = self.beforeRun();
            if (before && before.plot && before.id !== run.id) runs.push(before.plot);
            var maxDev = 0;
            _.each(runs, function (p) {
                _.each(p.directions, function (d) {
                    _.each(d.dev_um, function (v) {
                        maxDev = Math.max(maxDev, Math.abs(v));
                    });
                });
            });
            // scale: micrometres per division, 3 divisions from the nominal circle outwards
            var perDiv = _.find(NICE, function (n) {
                return n * 3 >= maxDev;
            }) || NICE[NICE.length - 1];
            var R0 = 4; // the nominal circle, in divisions
            var toXY = function (angles, devs) {
                return _.map(angles, function (deg, i) {
                    var r = Math.max(0, R0 + devs[i] / perDiv);
                    var t = (deg * Math.PI) / 180;
                    return [r * Math.cos(t), r * Math.sin(t)];
                });
            };
            var circle = function (r) {
                var pts = [];
                for (var i = 0; i <= 180; i++) {
                    var t = (i / 180) * 2 * Math.PI;
                    pts.push([r * Math.cos(t), r * Math.sin(t)]);
                }
                return pts;
            };
            var series = [];
            _.each([R0 - 2, R0 + 2, R0 - 1, R0 + 1], function (r) {
                series.push({data: circle(r), color: "#dddddd", lines: {lineWidth: 1}, shadowSize: 0});
            });
            series.push({data: circle(R0), color: "#999999", lines: {lineWidth: 1}, shadowSize: 0});
            var colours = {ccw: "#1f5fbf", cw: "#c0392b"};
            var faded = {ccw: "#9fb8e0", cw: "#e4a9a2"};
            _.each(runs, function (p, k) {
                var label = k === 0 ? "" : " (" + gettext("before") + ")";
                _.each(["ccw", "cw"], function (dir) {
                    var d = p.directions[dir];
                    if (!d) return;
                    series.push({
                        data: toXY(d.angle_deg, d.dev_um),
                        color: k === 0 ? colours[dir] : faded[dir],
                        label: (dir === "ccw" ? gettext("CCW") : gettext("CW")) + label,
                        lines: {lineWidth: k === 0 ? 1.5 : 1},
                        shadowSize: 0
                    });
                    if (k === 0) {
                        series.push({
                            data: toXY(d.angle_deg, d.fit_um),
                            color: "#333333",
                            lines: {lineWidth: 0.7},
                            shadowSize: 0,
                            label: dir === "ccw" ? gettext("fitted model") : undefined
                        });
                    }
                });
            });
            // the fitted centre (the least-squares centre the deviations are taken about),
            // magnified like the deviations: where the test circle really was
            var cr = run.plot.centre_removed_um;
            if (cr) {
                // off the scale: drawn at the edge in its direction (the legend has the value)
                var ca = cr.a / perDiv, cb = cr.b / perDiv;
                var off = Math.sqrt(ca * ca + cb * cb);
                if (off > 6) {
                    ca *= 6 / off;
                    cb *= 6 / off;
                }
                series.push({
                    data: [[ca, cb]],
                    color: "#333333",
                    points: {show: true, radius: 4, symbol: drawCross},
                    lines: {show: false},
                    shadowSize: 0,
                    label: _.sprintf(gettext("fitted centre (%(a)s, %(b)s µm)"), {
                        a: cr.a.toFixed(1), b: cr.b.toFixed(1)
                    })
                });
            }
            // a scale bar of one division at the bottom right
            series.push({data: [[5.0, -5.9], [6.0, -5.9]], color: "#000000", lines: {lineWidth: 3}, shadowSize: 0});
            var lim = 6.6;
            $.plot(target, series, {
                xaxis: {min: -lim, max: lim, show: false},
                yaxis: {min: -lim, max: lim, show: false},
                grid: {borderWidth: 0, hoverable: false},
                legend: {position: "nw", backgroundOpacity: 0.6}
            });
            target.find(".kincomp-scalebar").remove();
            target.append($("<div class='kincomp-scalebar'></div>").text(
                _.sprintf(gettext("%(um)s µm"), {um: perDiv})
            ));
            var axes = run.plot.axes || {a: "A", b: "B"};
            self.plotCaption(
                _.sprintf(
                    gettext("%(plane)s plane, R %(r)s mm: radial deviation magnified, %(um)s µm per ring; angle from +%(a)s toward +%(b)s; least-squares centre removed."),
                    {plane: run.plot.plane, r: run.plot.radius_mm, um: perDiv, a: axes.a, b: axes.b}
                ) + (run.simulated ? " " + gettext("SIMULATED data.") : "")
            );
        };

        self.step.subscribe(function (step) {
            if (step === "result") self.plotLater();
        });

        self.onTabChange = function (current) {
            if (current === "#tab_plugin_kincomp") {
                self.refresh();
                self.plotLater();
            }
        };

        self.onUserLoggedIn = function () {
            self.refresh();
        };
        self.onStartupComplete = function () {
            self.refresh();
        };
        self.onEventPrintDone = function () {
            self.printing(false);
        };
        self.onEventPrintFailed = self.onEventPrintDone;
        self.onEventPrintCancelled = self.onEventPrintDone;
        self.onEventSettingsUpdated = function () {
            self.refresh();
        };
        self.onEventFileAdded = function () {
            self.refresh();
        };
        // the custom event plugin_kincomp_params_applied, camel-cased by OctoPrint
        self.onEventPluginKincompParamsApplied = function () {
            self.refresh();
        };

        self.onDataUpdaterPluginMessage = function (plugin, data) {
            if (plugin !== "kincomp" || !data) return;
            if (data.type === "notify") {
                notify({
                    title: gettext("KinComp"),
                    text: translateNotice(data),
                    type: data.severity === "warning" ? "notice" : data.severity,
                    hide: data.severity !== "error"
                });
            } else if (data.type === "demo_trace") {
                self.printing(false);
                self.step("measure");
            } else if (data.type === "job" && data.job) {
                var job = data.job;
                if (job.state === "running") {
                    self.jobNotice = self.jobNotice || notify({
                        title: gettext("KinComp"), text: "", type: "info", hide: false
                    });
                    self.jobNotice.update({
                        text: _.sprintf(gettext("Compensating %(path)s: %(pct)s %%"), {
                            path: job.path, pct: Math.round((job.progress || 0) * 100)
                        })
                    });
                } else if (self.jobNotice) {
                    self.jobNotice.update({
                        text: job.state === "done"
                            ? _.sprintf(gettext("Compensated copy ready: %(path)s"), {path: job.result})
                            : _.sprintf(gettext("Compensation of %(path)s failed: %(error)s"), {path: job.path, error: job.error}),
                        type: job.state === "done" ? "success" : "error",
                        hide: true
                    });
                    self.jobNotice = undefined;
                }
            }
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompSettingsViewModel,
        dependencies: ["accessViewModel", "loginStateViewModel"],
        elements: ["#settings_plugin_kincomp"]
    });
    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompTabViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "printerStateViewModel"],
        elements: ["#tab_plugin_kincomp"]
    });
});
