/*
 * KinComp web UI: the printed artifact of the calibration tab (calibrate with calipers,
 * issues 27 and 35). Print KinComp's artifact (quick: 12 readings, or full), only add it to
 * the files, or slice it yourself (its STL); measure it in a form beside its drawing (the
 * server's SVG top view, every measurement numbered; as many fields per measurement as the
 * program asks readings for, mm; in demo mode SIMULATED readings can be filled in), then the
 * result: its verdict first, the squareness (um/m) and scale mismatch (ppm) with their 1-sigma
 * uncertainties, the parameters Apply sets, then the findings. The run is stored in the
 * history like a ballbar run. The logic without layout is kincomp_artifact_logic.js. Every
 * string goes through gettext.
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var fmt = K.fmt;
    var A = K.Artifact;

    function KinCompArtifactViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.printerState = parameters[2];
        self.tab = parameters[3];

        self.fmt = fmt;
        self.K = K;  // (the template: K.Result.when)
        self.trMsg = K.trMsg;
        // shown as the tab's "Printed artifact" step
        self.open = ko.pureComputed(function () {
            return !!(self.tab && self.tab.step() === "artifact");
        });
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
        self.mode = ko.observable("quick");
        self.bedClear = ko.observable(false);
        self.loadPath = ko.observable("");

        self.path = ko.observable("");
        self.drawing = ko.observable("");
        self.rows = ko.observableArray([]);
        self.analysedRows = ko.observable(false);
        self.run = ko.observable(null);
        self.sheetNote = ko.observable("");  // what the last "Print" or "Add" did
        self.appliedNote = K.appliedNote(self.run);  // what the user's Apply did
        // the readings in the form were filled in by demo mode's simulation (until edited)
        self.simulatedReadings = ko.observable(false);
        self.filling = false;

        // demo mode is on (the tab knows: its status)
        self.demo = ko.pureComputed(function () {
            return !!(self.tab && self.tab.demo && self.tab.demo());
        });
        self.stlUrl = ko.pureComputed(function () {
            return self.path() ? API("artifact/stl?path=" + encodeURIComponent(self.path())) : "#";
        });

        self.canWrite = ko.pureComputed(function () {
            return K.canAdmin(self);
        });

        self.fail = function (jqXHR) {
            self.error(K.errorText(jqXHR));
        };

        var kindText = function (kind) {
            return kind === "outside" ? gettext("outside") : gettext("inside");
        };

        var edited = function () {
            if (!self.filling) self.simulatedReadings(false);
        };

        // the numbered measurements and the drawing of a program (POST /artifact/program or
        // GET /artifact/sheet); as many reading fields as the program asks readings for
        self.showSheet = function (sheet) {
            var count = A.fieldsFor(sheet.info);
            self.sheetNote("");
            self.formError("");
            self.path(sheet.path);
            self.loadPath(sheet.path);
            self.drawing(sheet.svg);
            self.analysedRows(false);
            self.simulatedReadings(false);
            self.rows(_.map(sheet.measurements, function (m) {
                var fields = _.map(_.range(count), function (k) {
                    var text = ko.observable("");
                    text.subscribe(edited);
                    return {k: k + 1, text: text};
                });
                return {
                    n: m.n, id: m.id, kind: m.kind, kindText: kindText(m.kind),
                    nominal: m.nominal_mm, hint: K.trMsg(m.hint_i18n) || m.hint, fields: fields,
                    residual: ko.observable(""), leftOut: ko.observable(false),
                    bad: ko.observable(false)  // the reading the form's error names
                };
            }));
            self.view("measure");
        };

        // the form's fields filled with readings {"<id>": [mm, ...]} (missing ids: empty)
        self.fillReadings = function (readings) {
            self.filling = true;
            try {
                _.each(self.rows(), function (row) {
                    var texts = A.fieldTexts(readings[row.id] || [], row.fields.length);
                    _.each(row.fields, function (f, k) { f.text(texts[k]); });
                });
            } finally {
                self.filling = false;
            }
        };

        // demo mode: SIMULATED readings of this program (GET /artifact/simulated)
        self.fillSimulated = function () {
            self.error("");
            self.busy(true);
            K.get(API("artifact/simulated?path=" + encodeURIComponent(self.path())))
                .done(function (resp) {
                    self.fillReadings(resp.readings || {});
                    self.simulatedReadings(true);
                })
                .fail(self.fail)
                .always(function () { self.busy(false); });
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
                mode: self.mode(), print: print
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

        // writes the artifact (and prints it); ``stl``: then downloads its STL to slice
        var makeProgram = function (print, stl) {
            self.error("");
            var body = programBody(print);
            if (!body) return;
            self.busy(true);
            OctoPrint.postJson(API("artifact/program"), body)
                .done(function (resp) {
                    self.showSheet(resp);
                    if (stl) window.location.href = self.stlUrl();
                    // said above the measuring sheet it opens (no pop-up)
                    self.sheetNote(resp.printing
                        ? _.sprintf(gettext("Printing the artifact %(path)s. Let it cool down before you measure it."), {path: resp.path})
                        : stl
                            ? _.sprintf(gettext("The artifact's measuring sheet was added to the files as %(path)s; its STL is downloading. Measure the part you print from it with this sheet."), {path: resp.path})
                            : _.sprintf(gettext("The artifact was added to the files as %(path)s."), {path: resp.path}));
                })
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };
        self.printArtifact = function () { makeProgram(true, false); };
        self.writeArtifact = function () { makeProgram(false, false); };
        self.sliceArtifact = function () { makeProgram(false, true); };

        self.loadSheet = function () {
            self.error("");
            self.busy(true);
            K.get(API("artifact/sheet?path=" + encodeURIComponent(self.loadPath().trim())))
                .done(self.showSheet)
                .fail(self.fail)
                .always(function () { self.busy(false); });
        };

        // the measuring form's error: beside its Analyse button, the row it names marked and
        // its field focused (the form is up to 36 rows long: the top of the page is far)
        self.formError = ko.observable("");

        // readings -> {"<id>": [mm, ...]}; a field that is no number stops with its name
        self.readings = function () {
            var got = A.readingsOf(_.map(self.rows(), function (row) {
                return {id: row.id, fields: _.map(row.fields, function (f) { return f.text(); })};
            }));
            if (got.error) {
                self.formError(got.error);
                var row = _.findWhere(self.rows(), {id: got.field.id});
                if (row) {
                    row.bad(true);
                    var input = document.getElementById("kincomp_artifact_r_" + row.id + "_" + got.field.k);
                    if (input) input.focus();
                }
                return null;
            }
            return got.readings;
        };

        self.analyse = function () {
            self.error("");
            self.formError("");
            _.each(self.rows(), function (row) { row.bad(false); });
            var readings = self.readings();
            if (!readings) return;
            if (_.isEmpty(readings)) {
                self.formError(gettext("Type the readings first"));
                return;
            }
            self.busy(true);
            K.afterJob(OctoPrint.postJson(API("artifact/analyze"), {path: self.path(), readings: readings,
                                                                    simulated: self.simulatedReadings()}),
                       K.loadRun)
                .done(self.showRun)
                .fail(function (jqXHR) { self.formError(K.errorText(jqXHR)); })
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

        self.applied = ko.pureComputed(function () {
            var run = self.run();
            return run ? run.applied : null;
        });
        self.simulatedRun = ko.pureComputed(function () {
            var run = self.run();
            return !!(run && run.simulated);
        });
        self.verdict = ko.pureComputed(function () { return A.verdictView(self.run()); });
        self.valueRows = ko.pureComputed(function () { return A.valueRows(self.run()); });
        self.widthRows = ko.pureComputed(function () { return A.widthRows(self.run()); });
        self.applyRows = ko.pureComputed(function () { return A.applyRows(self.run()); });
        // the findings, worst first, and the "apply anyway" step of an untrusted result
        self.findingsBox = new K.FindingsBox(self.run, function (force) {
            self.applyConfirmed(force);
        });

        // a printed-artifact run opened in the tab's history: shown here with its program's
        // drawing and its readings in the form (the tab's own result table is the ballbar's)
        self.openFromHistory = function (run) {
            if (!run || run.source !== "artifact" || (self.run() && self.run().id === run.id)) return;
            var path = (run.diagnostics || {}).program;
            var fill = function () {
                K.get(API("runs/" + encodeURIComponent(run.id) + "/trace"))
                    .done(function (readings) {
                        if (typeof readings === "string") readings = JSON.parse(readings);
                        self.fillReadings(readings);
                        self.simulatedReadings(!!run.simulated);
                    })
                    .always(function () { self.showRun(run); });
            };
            if (path && path !== self.path()) {
                K.get(API("artifact/sheet?path=" + encodeURIComponent(path)))
                    .done(function (sheet) { self.showSheet(sheet); fill(); })
                    .fail(function () { self.rows([]); self.showRun(run); });
            } else {
                fill();
            }
        };
        if (self.tab && self.tab.run) self.tab.run.subscribe(self.openFromHistory);

        // an untrusted run is applied only after the "apply anyway" step (kincomp_findings.js)
        self.apply = function () {
            if (self.run()) self.findingsBox.apply();
        };
        self.applyConfirmed = function (force) {
            var run = self.run();
            if (!run) return;
            self.busy(true);
            OctoPrint.postJson(API("apply"), {run: run.id, enabled: true, force: !!force})
                .done(function (resp) {
                    K.get(API("runs/" + run.id)).done(self.run);
                    // said beside "Applied on" (no pop-up)
                    self.appliedNote.said(run.id, resp, gettext("Parameters applied; compensation is on."));
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
