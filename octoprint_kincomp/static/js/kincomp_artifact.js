/*
 * KinComp web UI: the printed artifact of the calibration tab (calibrate with calipers,
 * issue 27). Print KinComp's artifact (or only add it to the files), measure it in a form
 * beside its drawing (the server's SVG top view, every measurement numbered; up to three
 * readings each, mm), then the result: squareness um/m and scale mismatch ppm with their
 * 1-sigma uncertainties, the findings (what was checked, readings left out by id), apply.
 * The run is stored in the history like a ballbar run. Every string goes through gettext.
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var fmt = K.fmt;
    var trMsg = K.trMsg;

    // (gettext is defined once the view models are made, not when this file runs)
    var severityText = function (severity) {
        return {error: gettext("error"), warning: gettext("warning"),
                info: gettext("info")}[severity] || severity;
    };

    function KinCompArtifactViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.printerState = parameters[2];
        self.tab = parameters[3];

        self.fmt = fmt;
        self.open = ko.observable(false);
        self.view = ko.observable("program");
        self.error = ko.observable("");
        self.busy = ko.observable(false);

        self.planeXY = ko.observable(true);
        self.planeXZ = ko.observable(true);
        self.planeYZ = ko.observable(true);
        self.nozzle = ko.observable("0.4");
        self.hotend = ko.observable("210");
        self.bedTemp = ko.observable("60");
        self.firstLayer = ko.observable("0.2");
        self.caliper = ko.observable("150");
        self.bedClear = ko.observable(false);
        self.loadPath = ko.observable("");

        self.path = ko.observable("");
        self.drawing = ko.observable("");
        self.rows = ko.observableArray([]);
        self.analysedRows = ko.observable(false);
        self.run = ko.observable(null);

        self.canWrite = ko.pureComputed(function () {
            return K.canAdmin(self);
        });

        self.toggle = function () {
            self.open(!self.open());
        };

        self.fail = function (jqXHR) {
            self.error(K.errorText(jqXHR));
        };

        var kindText = function (kind) {
            return kind === "outside" ? gettext("outside") : gettext("inside");
        };

        // the numbered measurements and the drawing of a program (POST /artifact/program or
        // GET /artifact/sheet)
        self.showSheet = function (sheet) {
            self.path(sheet.path);
            self.loadPath(sheet.path);
            self.drawing(sheet.svg);
            self.analysedRows(false);
            self.rows(_.map(sheet.measurements, function (m) {
                return {
                    n: m.n, id: m.id, kind: m.kind, kindText: kindText(m.kind),
                    nominal: m.nominal_mm, hint: m.hint,
                    r1: ko.observable(""), r2: ko.observable(""), r3: ko.observable(""),
                    residual: ko.observable(""), leftOut: ko.observable(false)
                };
            }));
            self.view("measure");
        };

        var programBody = function (print) {
            var planes = [];
            if (self.planeXY()) planes.push("XY");
            if (self.planeXZ()) planes.push("XZ");
            if (self.planeYZ()) planes.push("YZ");
            var body = {
                planes: planes, nozzle: num(self.nozzle()),
                temps: [num(self.hotend()), num(self.bedTemp())],
                first_layer: num(self.firstLayer()), caliper: num(self.caliper()),
                print: print
            };
            var bad = _.find([["nozzle", body.nozzle], ["temps", body.temps[0]],
                              ["temps", body.temps[1]], ["first_layer", body.first_layer],
                              ["caliper", body.caliper]], function (f) { return isNaN(f[1]); });
            if (bad) {
                self.error(_.sprintf(gettext("'%(field)s' must be a number"), {field: bad[0]}));
                return null;
            }
            if (!planes.length) {
                self.error(gettext("Choose at least one part (XY, XZ or YZ)"));
                return null;
            }
            return body;
        };

        var makeProgram = function (print) {
            self.error("");
            var body = programBody(print);
            if (!body) return;
            self.busy(true);
            OctoPrint.postJson(API("artifact/program"), body)
                .done(function (resp) {
                    self.showSheet(resp);
                    K.notify({
                        title: gettext("KinComp"),
                        text: resp.printing
                            ? _.sprintf(gettext("Printing the artifact %(path)s. Let it cool down before you measure it."), {path: resp.path})
                            : _.sprintf(gettext("The artifact was added to the files as %(path)s."), {path: resp.path}),
                        type: "success"
                    });
                })
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };
        self.printArtifact = function () { makeProgram(true); };
        self.writeArtifact = function () { makeProgram(false); };

        self.loadSheet = function () {
            self.error("");
            self.busy(true);
            OctoPrint.get(API("artifact/sheet?path=" + encodeURIComponent(self.loadPath().trim())))
                .done(self.showSheet)
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };

        // readings -> {"<id>": [mm, ...]}; a field that is no number stops with its name
        self.readings = function () {
            var out = {};
            var bad = null;
            _.each(self.rows(), function (row) {
                var vals = [];
                _.each([row.r1(), row.r2(), row.r3()], function (text, k) {
                    if (String(text).trim() === "") return;
                    var v = num(text);
                    if (isNaN(v) || v <= 0) {
                        bad = bad || _.sprintf(gettext("Reading %(k)s of %(id)s is not a length in mm"), {k: k + 1, id: row.id});
                    } else {
                        vals.push(v);
                    }
                });
                if (vals.length) out[row.id] = vals;
            });
            if (bad) {
                self.error(bad);
                return null;
            }
            return out;
        };

        self.analyse = function () {
            self.error("");
            var readings = self.readings();
            if (!readings) return;
            if (_.isEmpty(readings)) {
                self.error(gettext("Type the readings first"));
                return;
            }
            self.busy(true);
            K.afterJob(OctoPrint.postJson(API("artifact/analyze"), {path: self.path(), readings: readings}),
                       K.loadRun)
                .done(self.showRun)
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };

        self.showRun = function (run) {
            self.run(run);
            var per = (run.diagnostics || {}).measurements || {};
            _.each(self.rows(), function (row) {
                var m = per[row.id] || {};
                row.residual(m.residual_um === null || m.residual_um === undefined ? "–"
                             : fmt(m.residual_um, 0) + " µm");
                row.leftOut(!!m.left_out || (m.readings_left_out || []).length > 0);
            });
            self.analysedRows(true);
            self.view("result");
        };

        self.trusted = ko.pureComputed(function () {
            var run = self.run();
            return !!(run && run.trusted);
        });
        self.applied = ko.pureComputed(function () {
            var run = self.run();
            return run ? run.applied : null;
        });

        self.valueRows = ko.pureComputed(function () {
            var run = self.run();
            if (!run) return [];
            var d = run.diagnostics, u = d.uncertainty || {};
            var rows = [];
            var add = function (label, key, sub, unit, digits) {
                var v = (d[key] || {})[sub], s = (u[key] || {})[sub];
                rows.push({
                    label: label, unit: unit,
                    value: v === null || v === undefined ? gettext("not separated") : fmt(v, digits),
                    sigma: s === null || s === undefined ? "–" : "± " + fmt(s, digits)
                });
            };
            _.each(["xy", "xz", "yz"], function (p) {
                add(_.sprintf(gettext("Squareness %(plane)s"), {plane: p.toUpperCase()}),
                    "squareness_um_per_m", p, "µm/m", 1);
            });
            _.each(["x-y", "x-z", "y-z"], function (p) {
                add(_.sprintf(gettext("Scale mismatch %(pair)s"), {pair: p.toUpperCase()}),
                    "scale_mismatch_ppm", p, "ppm", 1);
            });
            add(gettext("Line width (walls of the flat part)"), "line_width_mm", "vertical_walls", "mm", 3);
            add(gettext("Line width (45° walls)"), "line_width_mm", "slanted_walls", "mm", 3);
            return rows;
        });

        self.findings = ko.pureComputed(function () {
            var run = self.run();
            return _.map((run && run.findings) || [], function (f) {
                return {severity: f.severity, severityText: severityText(f.severity),
                        message: trMsg(f.message), advice: trMsg(f.advice)};
            });
        });

        // a printed-artifact run opened in the tab's history: shown here with its program's
        // drawing and its readings in the form (the tab's own result table is the ballbar's)
        self.openFromHistory = function (run) {
            if (!run || run.source !== "artifact" || (self.run() && self.run().id === run.id)) return;
            self.open(true);
            var path = (run.diagnostics || {}).program;
            var fill = function () {
                OctoPrint.get(API("runs/" + encodeURIComponent(run.id) + "/trace"))
                    .done(function (readings) {
                        if (typeof readings === "string") readings = JSON.parse(readings);
                        _.each(self.rows(), function (row) {
                            var vals = readings[row.id] || [];
                            row.r1(vals.length > 0 ? String(vals[0]) : "");
                            row.r2(vals.length > 1 ? String(vals[1]) : "");
                            row.r3(vals.length > 2 ? String(vals[2]) : "");
                        });
                    })
                    .always(function () { self.showRun(run); });
            };
            if (path && path !== self.path()) {
                OctoPrint.get(API("artifact/sheet?path=" + encodeURIComponent(path)))
                    .done(function (sheet) { self.showSheet(sheet); fill(); })
                    .fail(function () { self.rows([]); self.showRun(run); });
            } else {
                fill();
            }
        };
        if (self.tab && self.tab.run) self.tab.run.subscribe(self.openFromHistory);

        self.apply = function () {
            var run = self.run();
            if (!run) return;
            if (!run.trusted && !window.confirm(gettext("This result is not trusted (see its errors). Apply it anyway?"))) return;
            self.busy(true);
            OctoPrint.postJson(API("apply"), {run: run.id, enabled: true})
                .done(function () {
                    OctoPrint.get(API("runs/" + run.id)).done(self.run);
                    K.notify({title: gettext("KinComp"),
                              text: gettext("Parameters applied; compensation is on."),
                              type: "success"});
                })
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompArtifactViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "printerStateViewModel", "kinCompTabViewModel"],
        elements: ["#kincomp_artifact"]
    });
});
