/*
 * KinComp web UI: the calibration tab (1: the test program on the bed drawing, 2: the
 * measurement, 3: the result with the ballbar polar plot, the table and the proposal, and
 * the history) and the server's notifications.
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var fmt = K.fmt;
    var errorText = K.errorText;
    var notify = K.notify;
    var about = K.about;
    var trMsg = K.trMsg;
    var translateNotice = K.translateNotice;
    var rows = K.rows;
    var pick = K.pick;

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
        // the printer profile whose calibration is in force (issue 28): its name, and
        // whether it has a calibration at all (without one compensation stays off)
        self.profileName = ko.observable("");
        self.profileId = ko.observable(null);  // sent with Apply: a stale page's is refused
        self.profileCalibrated = ko.observable(true);
        self.version = ko.observable("");
        self.homepage = ko.observable("");
        self.limits = ko.observable([0, 200, 0, 200, 0, 200]);
        self.outdatedFiles = ko.observableArray([]);
        self.statusLine = ko.observable("");  // the server's latest notice that needs no action

        self.canWrite = ko.pureComputed(function () {
            return K.canAdmin(self);
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
            // one message for a radius that is no length (not "does not fit" as well)
            var problem = isNaN(ca) || isNaN(cb)
                ? gettext("Enter the centre and the radius.")
                : !(r > 0) ? gettext("The radius must be a length above 0 mm.") : "";
            var fits = ok && ca - r >= a0 && ca + r <= a1 && cb - r >= b0 && cb + r <= b1;
            var pad = Math.max(a1 - a0, b1 - b0) * 0.05;
            return {
                viewBox: [a0 - pad, -(b1 + pad), a1 - a0 + 2 * pad, b1 - b0 + 2 * pad].join(" "),
                x: a0, y: -b1, w: a1 - a0, h: b1 - b0,
                cx: ok ? ca : 0, cy: ok ? -cb : 0, r: ok ? r : 0,
                dot: Math.max(a1 - a0, b1 - b0) / 100,
                fits: fits,
                problem: problem,
                caption: problem ? problem : ok
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

        // why "Print test program" is not offered (empty when it is)
        self.printHint = ko.pureComputed(function () {
            var ps = self.printerState;
            if (!self.canWrite()) return gettext("Printing tests needs KinComp's admin permission.");
            if (!ps.isOperational()) return gettext("Connect the printer first.");
            if (ps.isPrinting() || ps.isPaused()) return gettext("A print is running: wait until it has finished.");
            if (self.bed().problem) return self.bed().problem;
            if (!self.bed().fits) return gettext("The circle does not fit the bed: move the centre or use a smaller radius.");
            if (!(self.checkMounted() && self.checkHeight() && self.checkClear()))
                return gettext("Tick the checklist to print.");
            if (self.busy()) return gettext("Working…");
            return "";
        });

        // while a print runs the live ballbar is shown above the form (in view at 1400x900)
        self.liveFirst = ko.pureComputed(function () {
            return self.printerState.isPrinting() || self.printerState.isPaused();
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
        self.appliedNote = K.appliedNote(self.run);  // what the user's Apply did
        self.trMsg = trMsg;
        self.beforeRun = ko.observable(null);
        self.compareRows = ko.observableArray([]);
        self.runs = ko.observableArray([]);
        self.compareBefore = ko.observable("");
        self.compareAfter = ko.observable("");
        self.plotCaption = ko.observable("");

        self.fmt = fmt;
        self.findingsBox = new K.FindingsBox(self.run, function (force) {
            self.applyConfirmed(force);
        });
        self.K = K;  // (dateText, sourceText for the templates)

        // the result opens with the decision (kincomp_result_logic.js): the verdict, the
        // numbers that decide it, what Apply sets; the details below, collapsed
        var R = K.Result;
        self.verdict = ko.pureComputed(function () {
            return R.verdictView(self.run());
        });
        self.decisionRows = ko.pureComputed(function () {
            var run = self.run();
            if (!run || !run.diagnostics || run.source === "artifact") return [];
            var d = run.diagnostics;
            if (d.squareness_um_per_m === undefined || typeof d.squareness_um_per_m === "object") return [];
            return R.decisionRows([{diag: d}]);
        });
        self.servoNote = ko.pureComputed(function () {
            var run = self.run();
            if (!run || !run.diagnostics) return null;
            return R.servoNote(run.proposed, run.diagnostics.servo_mismatch_ms);
        });
        self.applyRows = ko.pureComputed(function () {
            var run = self.run();
            return run && run.proposed ? R.applyRows(run.params_before, run.proposed) : [];
        });
        self.detailsOpen = ko.observable(false);
        self.toggleDetails = function () {
            self.detailsOpen(!self.detailsOpen());
            if (self.detailsOpen()) self.plotLater();
        };
        // step 3 before anything is shown: the runs are still loading, or there are none
        self.runsLoaded = ko.observable(false);
        self.noResultText = ko.pureComputed(function () {
            if (!self.runsLoaded()) return gettext("Loading the last result…");
            return gettext("No analysis yet: upload a measurement first.");
        });

        self.tableRows = ko.pureComputed(function () {
            var run = self.run();
            if (!run) return [];
            var cmp = self.compareRows();
            var axes = R.axesOf(run.diagnostics);
            return _.map(rows(axes), function (row) {
                var c = _.findWhere(cmp, {key: row[0]});
                return {
                    label: row[1],
                    unit: row[2],
                    value: fmt(pick(run.diagnostics, row[0])),
                    before: c ? fmt(c.before) : "",
                    reduction: K.reductionText(c)
                };
            });
        });

        self.proposedRows = ko.pureComputed(function () {
            var run = self.run();
            return run && run.proposed ? K.proposedRows(run.proposed) : [];
        });

        // an error is shown next to what caused it (the step it happened in), not as a
        // pop-up, and is gone on the other steps
        self.errorStep = ko.observable("");
        self.fail = function (jqXHR) {
            self.errorStep(self.step());
            self.error(errorText(jqXHR));
        };
        self.errorIn = function (step) {
            return !!self.error() && self.errorStep() === step;
        };
        self.step.subscribe(function (step) {
            if (step !== self.errorStep()) self.error("");
        });

        self.refresh = function () {
            var perm = self.access.permissions.STATUS;
            if (!perm || !self.loginState.hasPermission(perm)) return;
            K.get(API("status")).done(function (status) {
                var profile = status.profile || {calibrated: true, name: ""};
                self.profileName(profile.name || "");
                self.profileId(profile.id || null);
                self.profileCalibrated(!!profile.calibrated);
                self.enabled(status.settings.enabled && !!profile.calibrated);
                self.demo(status.demo);
                if (status.settings_problem && !self.problemShown) {
                    self.problemShown = true;
                    notify({
                        title: gettext("KinComp settings invalid"),
                        text: _.sprintf(gettext("The stored KinComp settings are invalid (%(reason)s): compensation is off until you fix them in KinComp's settings. Nothing stored was changed."), {reason: status.settings_problem}),
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
                K.get(API("files")).done(function (resp) {
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

        self.feedNote = ko.observable("");  // the feed the program was written with, and why
        self.sendProgram = function (print) {
            self.error("");
            self.feedNote("");
            self.busy(true);
            return OctoPrint.postJson(API("program"), self.programRequest(print))
                .done(function (resp) {
                    self.programPath(resp.path);
                    self.printing(resp.printing);
                    // why a feed was lowered (the printer's motion limits, settings page):
                    // beside the buttons, not a pop-up (nothing for the user to act on)
                    self.feedNote(resp.spec && resp.spec.feed_mm_min !== num(self.feed())
                        ? _.sprintf(gettext("Feed lowered to %(feed)s mm/min: %(why)s."), {
                            feed: resp.spec.feed_mm_min,
                            why: _.map(resp.feed_lowered || [], trMsg).join("; ")
                        })
                        : "");
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

        // a printed artifact's run is shown in its own step (kincomp_artifact.js)
        self.showRun = function (run) {
            self.run(run);
            self.error("");
            self.step(run && run.source === "artifact" && (run.diagnostics || {}).program ? "artifact" : "result");
            self.plotLater();
        };

        self.analysed = function (run) {
            // after "Re-test", beforeRun holds the previous run: the new one is compared to it
            self.compareRows([]);
            self.showRun(run);
            self.loadRuns();
        };

        // an analysis's answer (a 202: polled until its run is stored, kincomp_jobs.js)
        self.analysing = function (request) {
            self.busy(true);
            self.error("");
            return K.afterJob(request, K.loadRun)
                .done(self.analysed)
                .fail(self.fail)
                .always(function () {
                    self.busy(false);
                });
        };

        self.uploadBlob = function (blob, name) {
            return self.analysing(OctoPrint.upload(API("trace"), blob, name)).always(function () {
                $("#kincomp_trace_file").val("");
            });
        };

        self.uploadTrace = function (data, event) {
            var file = event.target.files && event.target.files[0];
            if (file) self.uploadBlob(file, file.name);
        };

        self.useSimulated = function () {
            self.busy(true);
            K.get(API("demo/trace"), {dataType: "text"})
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
            self.analysing(OctoPrint.postJson(API("analyze"), {summary: summary}));
        };

        self.analyseArtifact = function () {
            self.analysing(OctoPrint.postJson(API("artifact/analyze"), {
                square: {plane: self.aPlane(), ac: num(self.aAC()), bd: num(self.aBD()), ad: num(self.aAD())}
            }));
        };

        // Apply is offered for a proposal not applied yet, once nothing prints (the test
        // that is still printing would go on with the old parameters); disabled: says why
        self.applyWhy = ko.pureComputed(function () {
            var run = self.run(), ps = self.printerState;
            if (!run || !run.proposed || run.applied) return "";
            if (!self.canWrite()) return gettext("Applying needs KinComp's admin permission.");
            if (ps.isPrinting() || ps.isPaused() || (ps.isPausing && ps.isPausing()))
                return gettext("A print is running: apply once it has finished.");
            var rows = self.confirmRows();
            if (rows.length && !_.every(rows, function (row) { return row.ticked(); }))
                return gettext("Confirm how the test ran first (below).");
            return "";
        });
        // what the user confirms first when the run is not tied to a program KinComp printed
        // (its needs_confirmation: kincomp_confirm_logic.js), one ticked box per statement
        self.confirmRows = ko.pureComputed(function () {
            var run = self.run();
            var need = run && !run.applied ? run.needs_confirmation : null;
            return _.map(K.Confirmation.rows(need), function (row) {
                return {key: row.key, text: row.text, ticked: ko.observable(false)};
            });
        });
        self.confirmBody = function () {
            var run = self.run(), ticked = {};
            _.each(self.confirmRows(), function (row) { ticked[row.key] = row.ticked(); });
            return K.Confirmation.body(run && run.needs_confirmation, ticked);
        };
        self.canApply = ko.pureComputed(function () {
            var run = self.run();
            return !!(run && run.proposed && !run.applied && !self.applyWhy());
        });

        // an untrusted run is applied only after the "apply anyway" step (kincomp_findings.js)
        self.applyRun = function () {
            self.findingsBox.apply();
        };
        self.applyConfirmed = function (force) {
            var run = self.run();
            if (!run || !self.canApply()) return;
            var body = {run: run.id, enabled: true, force: !!force};
            if (self.profileId()) body.expected_profile = self.profileId();
            var confirm = self.confirmBody();
            if (confirm) body.confirm = confirm;
            OctoPrint.postJson(API("apply"), body)
                .done(function (resp) {
                    self.paramsHash(resp.params_hash);
                    self.enabled(true);
                    K.get(API("runs/" + run.id)).done(function (fresh) {
                        self.run(fresh);
                    });
                    // said beside "Applied on", where the user looks (no pop-up)
                    self.appliedNote.said(run.id, resp, gettext("Parameters applied; compensation is on. Re-test to see the improvement."));
                    self.loadRuns();
                })
                .fail(self.fail);
        };

        self.retest = function () {
            // the next result is compared with this one
            self.beforeRun(self.run());
            self.step("program");
        };

        // ``restore``: after a reload of the page the newest single run is the result shown
        // (not "No analysis yet" while runs exist); the step stays where it was
        self.loadRuns = function (restore) {
            var perm = self.access.permissions.STATUS;
            if (!perm || !self.loginState.hasPermission(perm)) return;
            K.get(API("runs")).done(function (resp) {
                // a campaign's runs are grouped with their campaign (kincomp_campaign.js)
                var single = _.filter(resp.runs, function (r) {
                    return !r.campaign;
                });
                self.runs(
                    _.map(single, function (r) {
                        return _.extend({}, r, {figures: K.historyFigures(r)});
                    })
                );
                if (restore && !self.run() && single.length) {
                    K.get(API("runs/" + encodeURIComponent(single[0].id))).done(function (run) {
                        if (!self.run()) self.run(run);
                        self.plotLater();
                    }).always(function () {
                        self.runsLoaded(true);
                    });
                } else {
                    self.runsLoaded(true);
                }
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
            K.get(API("runs/" + summary.id)).done(function (run) {
                self.beforeRun(null);
                self.compareRows([]);
                self.showRun(run);
            }).fail(self.fail);
        };

        self.compare = function () {
            var a = self.compareBefore(), b = self.compareAfter();
            $.when(K.get(API("runs/" + a)), K.get(API("runs/" + b)),
                   K.get(API("compare?before=" + encodeURIComponent(a) + "&after=" + encodeURIComponent(b))))
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
            K.get(API("compare?before=" + encodeURIComponent(before.id) + "&after=" + encodeURIComponent(run.id)))
                .done(function (cmp) {
                    self.compareRows(cmp.table);
                    self.plotLater();
                });
        });

        /* the classic ballbar plot: deviation magnified around the nominal circle */
        self.plotLater = function () {
            window.setTimeout(self.plot, 50);
        };

        // a result without a circle (a printed artifact, typed numbers) has no plot: none is
        // shown, not the one drawn for the run before
        self.hasPlot = ko.pureComputed(function () {
            var run = self.run();
            return !!(run && run.plot);
        });

        self.plot = function () {
            var run = self.run();
            var target = $("#kincomp_plot");
            if (!run || !run.plot) {
                target.empty();
                self.plotCaption("");
                return;
            }
            if (!target.is(":visible")) return;
            target.height(target.width()); // equal scales: a circle stays a circle
            var runs = [run.plot];
            var before = self.beforeRun();
            if (before && before.plot && before.id !== run.id) runs.push(before.plot);
            var perDiv = K.drawPolar(target, runs);
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

        // the step the user was on survives a reload of the page (this browser's storage);
        // a test printing now is where the page opens (kincomp_campaign.js: a campaign's)
        var STEPS = ["program", "measure", "result", "campaign", "artifact", "history"];
        var stored = function () {
            try {
                return window.localStorage.getItem("kincomp.step");
            } catch (e) {
                return null;
            }
        };
        self.step.subscribe(function (step) {
            try {
                window.localStorage.setItem("kincomp.step", step);
            } catch (e) {
                // (storage refused: the step is not kept)
            }
        });
        self.restoreStep = function () {
            var saved = stored();
            if (_.contains(STEPS, saved)) self.step(saved);
            var ps = self.printerState;
            var path = ps.filepath ? ps.filepath() : "";
            if ((ps.isPrinting() || ps.isPaused()) && /(^|\/)ballbar_[^/]*\.gcode$/.test(path || "")) self.step("program");
        };

        self.onUserLoggedIn = function () {
            self.refresh();
            self.loadRuns(true);
        };
        self.onStartupComplete = function () {
            self.restoreStep();
            self.refresh();
            self.loadRuns(true);
        };
        self.compareRows.subscribe(function (table) {
            // a comparison (re-test, or two runs of the history) is read in the details
            if (table && table.length) self.detailsOpen(true);
        });
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
            if (data.type === "profile") {
                // another printer profile in force: its calibration, its history
                self.refresh();
                self.loadRuns();
            } else if (data.type === "notify" && data.severity === "status") {
                // for the record, nothing to act on: a line in the tab, not a pop-up
                self.statusLine(translateNotice(data));
            } else if (data.type === "notify") {
                notify({
                    title: gettext("KinComp"),
                    text: translateNotice(data),
                    type: data.severity === "warning" ? "notice" : data.severity,
                    hide: data.severity !== "error"
                });
            } else if (data.type === "demo_trace" && !data.campaign) {
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
        construct: KinCompTabViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "printerStateViewModel"],
        elements: ["#tab_plugin_kincomp"]
    });
});
