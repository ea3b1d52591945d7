/*
 * KinComp web UI: campaign mode of the calibration tab (one calibration round over the whole
 * volume) and the campaigns in its history.
 *
 * Plan: the options (radii mm, feed mm/min, heights mm) are planned by the server on the
 * printer profile's volume (a dry run) and drawn from three sides (top XY, front XZ, side
 * YZ; SVG y points down, so heights are drawn negated). Tests: one after another; each
 * program pauses (M0) to mount the bar and to unmount it, the wizard shows the test, its
 * print progress and the pause; the measurement is a live sensor's capture (in demo mode the
 * virtual bar's, demo.live), taken by the server by itself, or uploaded (or, in demo mode
 * without the live path, the SIMULATED trace is collected as soon as it is ready). Result: per test its polar plot and the
 * paper's Table 2 (before: the same test of the campaign it re-tests), the joint fit, ONE
 * proposed parameter set and ONE Apply. Units as on the server: um/m, ppm, um, ms, mm. The
 * drawings and the result's tables are made by kincomp_campaign_draw.js (KinComp.campaign).
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var fmt = K.fmt;
    var trMsg = K.trMsg;

    function KinCompCampaignViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.printerState = parameters[2];
        self.tab = parameters[3];

        self.fmt = fmt;
        self.trMsg = trMsg;
        self.K = K;  // (the templates: K.Result.when)
        self.error = ko.observable("");
        self.busy = ko.observable(false);
        self.busyText = ko.observable("");
        self.campaign = ko.observable(null);
        self.appliedNote = K.appliedNote(self.campaign);  // what the user's Apply did
        self.planning = ko.observable(true);
        self.preview = ko.observable(null);
        self.campaigns = ko.observableArray([]);
        self.checked = ko.observable(false);

        // plan options
        self.radiusXY = ko.observable("100");
        self.radiusV = ko.observable("50");
        self.feed = ko.observable("1850");
        self.xyHeight = ko.observable("10");
        self.useSecondHeight = ko.observable(false);
        self.secondHeight = ko.observable("60");
        self.useSecondFeed = ko.observable(false);
        self.secondFeed = ko.observable("3700");
        self.touched = false;

        self.canWrite = ko.pureComputed(function () {
            return K.canAdmin(self);
        });

        self.view = ko.pureComputed(function () {
            var c = self.campaign();
            if (!c || self.planning()) return "plan";
            return c.analysis ? "result" : "steps";
        });

        self.options = function () {
            var o = {
                radius_xy: num(self.radiusXY()),
                radius_vertical: num(self.radiusV()),
                feed: num(self.feed()),
                xy_height: num(self.xyHeight()),
                second_height: self.useSecondHeight() ? num(self.secondHeight()) : null,
                second_feed: self.useSecondFeed() ? num(self.secondFeed()) : null
            };
            // a field that is not a number goes as text: the server names it
            _.each([["radius_xy", self.radiusXY], ["radius_vertical", self.radiusV],
                    ["feed", self.feed], ["xy_height", self.xyHeight]], function (f) {
                if (isNaN(o[f[0]])) o[f[0]] = f[1]();
            });
            return o;
        };

        /* ------------------------------------------------------------ failures and busy */
        // shown in the campaign's view (no pop-up), gone once the user moves to another step
        self.fail = function (jqXHR) {
            self.error(K.errorText(jqXHR));
        };

        self.working = function (text, request) {
            self.busy(true);
            self.busyText(text);
            self.error("");
            return request.always(function () {
                self.busy(false);
            });
        };

        /* --------------------------------------------------------------------- planning */
        self.planError = ko.observable("");
        var asked = 0; // only the answer to the latest options counts
        self.refreshPreview = _.debounce(function () {
            if (!self.canWrite() || self.view() !== "plan") return;
            var mine = ++asked;
            OctoPrint.postJson(API("campaign/plan"), _.extend(self.options(), {dry_run: true}))
                .done(function (plan) {
                    if (mine !== asked) return;
                    self.preview(plan);
                    self.planError("");
                })
                .fail(function (jqXHR) {
                    if (mine !== asked) return;
                    self.preview(null);
                    self.planError(K.errorText(jqXHR));
                });
        }, 300);
        _.each(["radiusXY", "radiusV", "feed", "xyHeight", "useSecondHeight", "secondHeight",
                "useSecondFeed", "secondFeed"], function (name) {
            self[name].subscribe(function () {
                self.touched = true;
                self.refreshPreview();
            });
        });

        self.defaultsFromProfile = function (limits) {
            // the largest standard XY radius that fits the bed (ISO 230-4: 100 mm)
            var half = Math.min(limits[1] - limits[0], limits[3] - limits[2]) / 2 - 5;
            var r = _.find([100, 50, 25], function (v) {
                return v <= half;
            }) || Math.max(5, Math.floor(half));
            self.radiusXY(String(r));
            self.radiusV(String(Math.min(50, r)));
            self.secondHeight(String(Math.round(Math.min(limits[5] / 2, 100))));
            self.touched = false;
        };

        self.canStart = ko.pureComputed(function () {
            return self.canWrite() && !self.busy() && self.preview() !== null;
        });

        self.start = function () {
            self.working(gettext("Planning…"),
                OctoPrint.postJson(API("campaign/plan"), self.options())
                    .done(function (c) {
                        self.show(c);
                        self.loadCampaigns();
                    })
                    .fail(self.fail));
        };

        self.backToCampaign = function () {
            self.planning(false);
        };

        self.newCampaign = function () {
            self.planning(true);
            self.lastMeasured("");
            self.refreshPreview();
        };

        self.retest = function () {
            var c = self.campaign();
            self.working(gettext("Planning…"),
                OctoPrint.postJson(API("campaign/plan"), {retest_of: c.id})
                    .done(function (fresh) {
                        self.show(fresh);
                        self.loadCampaigns();
                    })
                    .fail(self.fail));
        };

        /* the drawing: the campaign's tests, or the plan's while planning */
        self.drawing = ko.pureComputed(function () {
            var plan = self.view() === "plan" ? self.preview() : self.campaign();
            var limits = self.tab.limits() || [0, 200, 0, 200, 0, 200];
            var steps = plan ? plan.steps : [];
            var volume = plan ? plan.volume : limits;
            var cur = self.current();
            return {
                steps: steps,
                views: K.campaign.views(volume, steps, cur ? cur.n : null)
            };
        });

        self.planNote = ko.pureComputed(function () {
            if (self.view() === "plan" && self.planError()) return self.planError();
            var plan = self.view() === "plan" ? self.preview() : self.campaign();
            if (!plan) return "";
            var capped = _.filter(plan.steps, function (s) {
                return s.requested_feed_mm_min && s.requested_feed_mm_min !== s.feed_mm_min;
            });
            var text = _.sprintf(gettext("%(n)s tests on the %(x)s × %(y)s × %(z)s mm volume; the numbers are the order."), {
                n: plan.steps.length,
                x: plan.volume[1] - plan.volume[0],
                y: plan.volume[3] - plan.volume[2],
                z: plan.volume[5] - plan.volume[4]
            });
            if (capped.length) {
                text += " " + _.sprintf(gettext("Feed capped to the axes' max feed in: %(tests)s."), {
                    tests: _.pluck(capped, "name").join(", ")
                });
            }
            return text;
        });

        self.centreText = function (step) {
            return _.map(step.centre, function (v) {
                return fmt(v, 0);
            }).join(", ");
        };

        /* ------------------------------------------------------------ the tests in turn */
        self.show = function (c) {
            self.campaign(c);
            self.planning(false);
            self.error("");
            self.checked(false);
            if (c && c.analysis) self.plotLater();
        };

        self.current = ko.pureComputed(function () {
            var c = self.campaign();
            if (!c || c.next_step === null) return null;
            return _.findWhere(c.steps, {n: c.next_step});
        });

        self.donePct = ko.pureComputed(function () {
            var c = self.campaign();
            return c ? Math.round((100 * c.measured) / c.steps.length) : 0;
        });

        self.progressText = ko.pureComputed(function () {
            var c = self.campaign();
            if (!c) return "";
            return _.sprintf(gettext("%(done)s of %(n)s tests measured."), {done: c.measured, n: c.steps.length});
        });

        self.stepTitle = function (step) {
            return _.sprintf(gettext("Test %(n)s of %(total)s: %(plane)s, radius %(r)s mm, %(feed)s mm/min"), {
                n: step.n, total: self.campaign().steps.length, plane: step.plane,
                r: step.radius_mm, feed: step.feed_mm_min
            });
        };

        self.stepWhere = function (step) {
            var how = step.plane === "XY"
                ? gettext("Pivot (centre ball) at %(c)s mm; the bar lies flat.")
                : gettext("Pivot at %(c)s mm; the bar stands upright in the %(plane)s plane.");
            return _.sprintf(how, {c: self.centreText(step), plane: step.plane}) + " " +
                gettext("The program moves there and pauses: mount the bar, continue; it pauses again at the end: unmount it, continue.");
        };

        // the campaign's test whose program is printing or paused now (None: none is)
        self.jobStep = ko.pureComputed(function () {
            var c = self.campaign();
            var ps = self.printerState;
            if (!c || !(ps.isPrinting() || ps.isPaused())) return null;
            var path = ps.filepath ? ps.filepath() : null;
            return _.find(c.steps, function (s) {
                return s.path && s.path === path;
            }) || null;
        });
        var onJob = function (step) {
            var job = self.jobStep();
            return job !== null && job.n === step.n;
        };

        self.printPct = ko.pureComputed(function () {
            var p = self.printerState.progress();
            return p ? Math.round(p) : 0;
        });
        self.printText = ko.pureComputed(function () {
            return _.sprintf(gettext("Printing the test: %(pct)s %%"), {pct: self.printPct()});
        });
        // how often the test's print went on since it started (null: not known, e.g. after
        // a reload of the page): tells the mount pause from the unmount pause, also after
        // OctoPrint's Restart of the test (it starts from the top again)
        self.resumes = ko.observable(null);
        self.onEventPrintStarted = function () {
            self.resumes(0);
        };
        self.onEventPrintResumed = function () {
            if (self.resumes() !== null) self.resumes(self.resumes() + 1);
        };
        self.pauseText = function (step) {
            return K.campaign.pauseKind(self.resumes(), self.printPct()) === "mount"
                ? _.sprintf(gettext("Paused: mount the bar for %(plane)s now (pivot at %(c)s mm), then continue."), {plane: step.plane, c: self.centreText(step)})
                : gettext("Paused: the test is done; unmount the bar, then continue.");
        };

        /* One state machine decides what the current test's buttons offer (phase) and,
         * whenever printing it is not offered, why (printBlock):
         *   ready      -> printing   ("Print this test": its program is printing or paused)
         *   printing   -> measuring  (the print ended done; its capture is awaited)
         *              -> ready      (the print failed or was cancelled: print it again)
         *   measuring  -> (next test) when its measurement arrives
         *              -> missed     (the capture failed or was refused: print it again)
         * printed-before (a print was started earlier, e.g. before a reload of the page,
         * with nothing awaited now) may print again. */
        self.awaiting = ko.observable(null); // {n, id}: the test whose capture is awaited
        self.missed = ko.observable(null); // {n, id}: its capture failed or was refused
        self.lastMeasured = ko.observable(""); // what the last test measured, in the panel
        self.requested = ko.observable(null); // {n, id}: "Print" clicked, no answer yet
        var mark = function (step) {
            var c = self.campaign();
            return step && c ? {n: step.n, id: c.id} : null;
        };
        var marks = function (m, step) {
            var c = self.campaign();
            return !!(m && step && c && m.n === step.n && m.id === c.id);
        };

        self.phase = ko.pureComputed(function () {
            var step = self.current();
            if (!step) return "none";
            var job = self.jobStep();
            if (job && job.n === step.n) return self.printerState.isPaused() ? "paused" : "printing";
            if (marks(self.requested(), step)) return "starting";
            if (marks(self.awaiting(), step)) return "measuring";
            if (marks(self.missed(), step)) return "missed";
            return step.printed ? "printed" : "ready";
        });

        // null: printing is offered; else the reason it is not (always said)
        self.printBlock = ko.pureComputed(function () {
            var c = self.campaign(), ps = self.printerState, phase = self.phase();
            if (!c || phase === "none") return gettext("All tests of this campaign are measured.");
            if (c.params_changed) return gettext("The parameters in force changed since this campaign began: start a new campaign (the button below).");
            if (!self.canWrite()) return gettext("You may not print tests: that needs KinComp's admin permission.");
            if (phase === "starting") return gettext("Starting the print…");
            if (phase === "printing" || phase === "paused") return gettext("This test is printing now.");
            if (phase === "measuring") return gettext("The test is printed; its measurement (the live capture) is being taken. The next test follows as soon as it is in.");
            if (self.busy()) return self.busyText();
            if (!ps.isOperational()) return gettext("Connect the printer first.");
            if (ps.isPrinting() || ps.isPaused() || (ps.isBusy && ps.isBusy()))
                return gettext("The printer is busy with another job: wait until it has finished (or cancel it).");
            if (!self.checked()) return gettext("Tick the box to print.");
            return null;
        });

        self.canPrint = ko.pureComputed(function () {
            return self.printBlock() === null;
        });
        self.printHint = ko.pureComputed(function () {
            return self.printBlock() || "";
        });
        self.printLabel = ko.pureComputed(function () {
            var phase = self.phase();
            return phase === "printed" || phase === "missed"
                ? gettext("Print this test again") : gettext("Print this test");
        });

        // the job of the current test ends: done -> its capture is awaited (when one was
        // armed), else the test may be printed again
        var lastJob = null;
        self.jobStep.subscribe(function (job) {
            if (job) {
                lastJob = mark(job);
                self.requested(null);
            }
        });
        self.jobEnded = function (done) {
            // (a print so short that the printer state never showed it: the one requested)
            var ended = lastJob || self.requested();
            lastJob = null;
            self.requested(null);
            if (!ended) return;
            self.awaiting(done && self.captureArmed ? ended : null);
            self.reload();
        };
        self.captureArmed = false;

        self.stepState = function (step) {
            if (step.run) {
                var s = step.summary;
                return s ? _.sprintf(gettext("measured ✓ (squareness %(sq)s µm/m)"), {sq: fmt(s.squareness_um_per_m, 1)}) : gettext("measured ✓");
            }
            if (onJob(step)) return self.printerState.isPaused() ? gettext("paused") : gettext("printing");
            if (step.printed) return gettext("printed: waiting for its measurement");
            return step.path ? gettext("program written") : gettext("planned");
        };

        self.printStep = function (step) {
            var c = self.campaign();
            if (!self.canPrint()) return; // (one click: the button is disabled from here on)
            self.requested(mark(step));
            self.missed(null);
            self.awaiting(null);
            self.working(gettext("Writing the program…"),
                OctoPrint.postJson(API("campaigns/" + c.id + "/steps/" + step.n + "/program"), {print: true})
                    .done(function (resp) {
                        // a live capture is armed (the demo's virtual bar, a sensor), or
                        // demo mode collects its simulated trace: the measurement comes
                        // by itself after the print
                        self.captureArmed = !!resp.capture || !!self.tab.demo();
                        self.campaign(resp.campaign);
                        self.checked(false);
                        if (!resp.printing) self.requested(null);
                    })
                    .fail(function (jqXHR) {
                        self.requested(null);
                        self.fail(jqXHR);
                    }));
        };

        self.resume = function () {
            OctoPrint.job.resume().fail(self.fail);
        };

        // a test of campaign ``c`` by its plan name ("xy-f3700"), in words
        self.testNameOf = function (c, name) {
            var step = c && _.findWhere(c.steps || [], {name: name});
            return step ? K.campaign.testName(step) : name;
        };

        self.measured = function (resp) {
            self.awaiting(null);
            self.missed(null);
            self.show(resp.campaign);
            var d = resp.run && resp.run.diagnostics;
            // said in the panel, under the progress (a pop-up only for what needs the user)
            self.lastMeasured(d ? _.sprintf(gettext("Test %(name)s measured: squareness %(sq)s µm/m, circularity %(c)s µm."), {
                name: self.testNameOf(resp.campaign, resp.run.campaign_step),
                sq: fmt(d.squareness_um_per_m, 1),
                c: fmt(d.circularity_um && d.circularity_um.bidirectional, 1)
            }) : "");
            self.loadCampaigns();
        };

        self.traceUrl = function (summary) {
            return API("runs/" + encodeURIComponent(summary.id) + "/trace");
        };

        self.uploadTrace = function (data, event) {
            var file = event.target.files && event.target.files[0];
            var c = self.campaign(), step = self.current();
            if (!file || !c || !step) return;
            // (a 202: its job polled until the run is stored, then shown: kincomp_jobs.js)
            self.working(gettext("Analysing the test…"),
                K.afterJob(OctoPrint.upload(API("campaigns/" + c.id + "/steps/" + step.n + "/trace"), file, file.name),
                           K.loadCampaignStep(c.id))
                    .done(self.measured)
                    .fail(self.fail)
                    .always(function () {
                        $("#kincomp_campaign_trace_file").val("");
                    }));
        };

        self.collect = function (n) {
            var c = self.campaign();
            return self.working(gettext("Analysing the test…"),
                K.afterJob(OctoPrint.postJson(API("campaigns/" + c.id + "/steps/" + n + "/trace"), {demo: true}),
                           K.loadCampaignStep(c.id))
                    .done(self.measured)
                    .fail(self.fail));
        };

        self.useSimulated = function (step) {
            self.collect(step.n);
        };

        self.analyse = function () {
            var c = self.campaign();
            self.working(gettext("Fitting all tests together…"),
                K.afterJob(OctoPrint.postJson(API("campaigns/" + c.id + "/analyze"), {}), K.loadCampaign(c.id))
                    .done(function (fresh) {
                        self.show(fresh);
                        self.loadCampaigns();
                    })
                    .fail(self.fail));
        };

        // Apply is offered once nothing prints (a print under way would keep the old
        // parameters until its end); a disabled Apply says why
        self.applyWhy = ko.pureComputed(function () {
            var c = self.campaign(), ps = self.printerState;
            if (!c || !c.analysis) return "";
            if (c.applied) return "";
            if (!self.canWrite()) return gettext("Applying needs KinComp's admin permission.");
            if (ps.isPrinting() || ps.isPaused() || (ps.isPausing && ps.isPausing()))
                return gettext("A print is running: apply once it has finished.");
            if (self.busy()) return self.busyText();
            return "";
        });
        self.canApply = ko.pureComputed(function () {
            var c = self.campaign();
            return !!(c && c.analysis && !c.applied && !self.applyWhy());
        });

        // an untrusted joint result is applied only after "apply anyway" (kincomp_findings.js)
        self.apply = function () {
            self.findingsBox.apply();
        };
        self.applyConfirmed = function (force) {
            var c = self.campaign();
            var body = {enabled: true, force: !!force};
            if (self.tab.profileId()) body.expected_profile = self.tab.profileId();  // (a stale page: 409)
            self.working(gettext("Applying…"),
                OctoPrint.postJson(API("campaigns/" + c.id + "/apply"), body)
                    .done(function (resp) {
                        self.tab.paramsHash(resp.params_hash);
                        self.tab.enabled(true);
                        // said beside "Applied on" (no pop-up)
                        self.appliedNote.said(c.id, resp, gettext("Parameters applied; compensation is on. Re-test the campaign to see the improvement in every plane."));
                        self.reload();
                    })
                    .fail(self.fail));
        };

        /* ------------------------------------------------------------------- the result */
        self.analysis = ko.pureComputed(function () {
            var c = self.campaign();
            return c && c.analysis ? c.analysis : null;
        });

        self.findingsBox = new K.FindingsBox(self.analysis, function (force) {
            self.applyConfirmed(force);
        }, true);

        // the result opens with the decision (kincomp_result_logic.js); the details below
        var R = K.Result;
        self.campaignTitle = ko.pureComputed(function () {
            var c = self.campaign();
            return c ? _.sprintf(gettext("Campaign of %(date)s"), {date: R.when(c.created)}) : "";
        });
        self.verdict = ko.pureComputed(function () {
            return R.verdictView(self.analysis());
        });
        self.decisionRows = ko.pureComputed(function () {
            return R.decisionRows(R.campaignTests(self.analysis()));
        });
        self.applyRows = ko.pureComputed(function () {
            var a = self.analysis();
            return a && a.proposed ? R.applyRows(a.params_before, a.proposed) : [];
        });
        // the servo decision in words; a servo mismatch left uncompensated says so
        self.servoText = ko.pureComputed(function () {
            var a = self.analysis();
            if (!a) return "";
            var sp = a.diagnostics.campaign.servo_precomp || {};
            var why = trMsg(sp.reason_i18n || sp.reason) || "";
            var ms = _.find(_.values(a.diagnostics.campaign.servo_mismatch_ms || {}), function (v) {
                return v !== null && v !== undefined;
            });
            return R.servoNote(a.proposed, ms, why) || why;
        });
        self.detailsOpen = ko.observable(false);
        self.toggleDetails = function () {
            self.detailsOpen(!self.detailsOpen());
            if (self.detailsOpen()) self.plotLater();
        };

        self.planes = ko.pureComputed(function () {
            return self.analysis() ? K.campaign.planes(self.analysis()) : [];
        });

        self.jointRows = ko.pureComputed(function () {
            return self.analysis() ? K.campaign.jointRows(self.analysis()) : [];
        });

        // the notes, without the servo decision (shown on its own)
        self.notes = ko.pureComputed(function () {
            var a = self.analysis();
            if (!a) return [];
            var reason = a.diagnostics.campaign.servo_precomp.reason;
            return _.filter(a.notes_i18n || [], function (n) {
                return n.text !== reason;
            });
        });

        self.proposedRows = ko.pureComputed(function () {
            var a = self.analysis();
            return a && a.proposed ? K.proposedRows(a.proposed, true) : [];
        });

        self.plotLater = function () {
            window.setTimeout(self.plot, 50);
        };

        self.plot = function () {
            _.each(self.planes(), function (p) {
                var target = $("#kincomp_campaign_plot_" + p.index);
                if (!p.plot || !target.is(":visible")) return;
                target.height(target.width());
                var runs = [p.plot];
                if (p.before) runs.push(p.before);
                var perDiv = K.drawPolar(target, runs);
                var axes = p.plot.axes || {a: "A", b: "B"};
                target.parent().find(".kincomp-legend").text(
                    _.sprintf(gettext("%(um)s µm per ring; angle from +%(a)s toward +%(b)s."), {um: perDiv, a: axes.a, b: axes.b}) +
                    (p.plot.simulated ? " " + gettext("SIMULATED data.") : "")
                );
            });
        };

        /* ------------------------------------------------------------------ the history */
        self.stateText = function (c) {
            var started = _.some(c.steps || [], function (s) {
                return s.printed || s.run;
            });
            if (c.state === "measuring" && !c.measured && !started)
                return gettext("not run (no test printed)");
            return {
                measuring: _.sprintf(gettext("measuring (%(done)s of %(n)s)"), {done: c.measured, n: c.steps.length}),
                measured: gettext("measured, not analysed"),
                analysed: gettext("analysed"),
                applied: gettext("applied")
            }[c.state] || c.state;
        };

        self.loadCampaigns = function () {
            var perm = self.access.permissions.STATUS;
            if (!perm || !self.loginState.hasPermission(perm)) return $.Deferred().reject();
            return K.get(API("campaigns")).done(function (resp) {
                self.campaigns(resp.campaigns);
            });
        };

        self.deleteHint = function (c) {
            return _.sprintf(gettext("Delete the campaign of %(date)s (the runs of its tests stay in the history)"), {date: K.Result.when(c.created)});
        };

        // deleting asks first (OctoPrint's confirmation dialog); the server refuses a
        // campaign whose test is being measured and says why
        self.remove = function (summary) {
            showConfirmationDialog({
                title: gettext("Delete the campaign?"),
                message: _.sprintf(gettext("The campaign of %(date)s (%(state)s) will be deleted: its plan and progress are gone, a re-test of it has nothing to compare with. The runs of its tests and its joint result stay in the history."),
                    {date: _.escape(K.Result.when(summary.created)), state: _.escape(self.stateText(summary))}),
                question: gettext("Delete this campaign?"),
                proceed: gettext("Delete"),
                dialogClass: "kincomp-campaign-delete-dialog",
                onproceed: function () {
                    OctoPrint.delete(API("campaigns/" + summary.id)).done(function () {
                        var c = self.campaign();
                        if (c && c.id === summary.id) {
                            self.campaign(null);
                            self.planning(true);
                        }
                        self.error("");
                        self.loadCampaigns();
                    }).fail(self.fail);
                }
            });
        };

        self.open = function (summary) {
            K.get(API("campaigns/" + summary.id)).done(function (c) {
                self.show(c);
                self.tab.step("campaign");
            }).fail(self.fail);
        };

        self.reload = function () {
            var c = self.campaign();
            if (!c || !c.stored) return;
            K.get(API("campaigns/" + c.id)).done(self.show);
        };

        // the newest campaign is where the user left off (after a reload of the page)
        self.resumeLatest = function () {
            var req = self.loadCampaigns();
            req.done(function () {
                var latest = self.campaigns()[0];
                if (!latest || self.campaign()) return;
                K.get(API("campaigns/" + latest.id)).done(function (c) {
                    self.show(c);
                    // a test of it printing or paused now: the page opens on the campaign
                    if (self.jobStep()) self.tab.step("campaign");
                });
            });
        };

        /* ------------------------------------------------------------- OctoPrint's calls */
        self.tab.step.subscribe(function (step) {
            self.error("");
            if (step === "campaign") {
                if (!self.touched && self.tab.limits()) self.defaultsFromProfile(self.tab.limits());
                if (self.view() === "plan") self.refreshPreview();
                else self.reload();
                self.plotLater();
            } else if (step === "history") {
                self.loadCampaigns();
            }
        });
        self.view.subscribe(function (v) {
            if (v === "result") self.plotLater();
        });

        self.onTabChange = function (current) {
            if (current === "#tab_plugin_kincomp") self.plotLater();
        };

        self.onStartupComplete = function () {
            self.resumeLatest();
        };
        self.onUserLoggedIn = self.onStartupComplete;

        self.onEventPrintDone = function () {
            self.jobEnded(true);
            self.reload();
        };
        self.onEventPrintFailed = function () {
            self.resumes(null);
            self.jobEnded(false);
        };
        self.onEventPrintCancelled = self.onEventPrintFailed;
        self.onEventSettingsUpdated = function () {
            self.reload();
        };
        self.onEventPluginKincompParamsApplied = self.onEventSettingsUpdated;

        // a live capture of a test that is not its measurement (failed, or refused by the
        // campaign): the test stays unmeasured, the campaign says why
        self.captureMissed = function (c, run) {
            var name = run.test_of.campaign_step;
            var text = run.status !== "ok"
                ? _.sprintf(gettext("The live capture of test %(name)s failed: %(reason)s. The test stays unmeasured: print it again, or give its trace. The data so far is kept in the History."), {
                    name: self.testNameOf(c, name), reason: trMsg(run.message_i18n || run.message)})
                : _.sprintf(gettext("The live capture of test %(name)s was not taken as its measurement (the notice says why); it is kept in the History as a single run."), {name: self.testNameOf(c, name)});
            var step = _.findWhere(c.steps, {name: name});
            self.awaiting(null);
            if (step) self.missed({n: step.n, id: c.id});
            K.get(API("campaigns/" + c.id)).done(function (fresh) {
                self.show(fresh);
                self.error(text);
            });
        };

        // a test's trace arrives: the live sensor's capture (the demo's virtual bar in demo
        // mode), already taken by the campaign (sensor_run), or demo mode's simulated trace
        // without the live path (demo_trace)
        self.onDataUpdaterPluginMessage = function (plugin, data) {
            if (plugin !== "kincomp" || !data) return;
            var c = self.campaign();
            if (data.type === "sensor_run" && data.run && data.run.campaign) {
                if (!c || c.id !== data.run.campaign) return;
                $.when(K.get(API("campaigns/" + c.id)),
                       K.get(API("runs/" + encodeURIComponent(data.run.id))))
                    .done(function (fresh, run) {
                        self.measured({campaign: fresh[0], run: run[0]});
                    });
            } else if (data.type === "sensor_run" && data.run && data.run.test_of) {
                if (c && c.id === data.run.test_of.campaign) self.captureMissed(c, data.run);
            } else if (data.type === "demo_trace" && data.campaign) {
                if (!c || c.id !== data.campaign || !self.canWrite()) return;
                var step = _.findWhere(c.steps, {name: data.campaign_step});
                if (step && !step.run) self.collect(step.n);
            }
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompCampaignViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "printerStateViewModel", "kinCompTabViewModel"],
        elements: ["#kincomp_campaign", "#kincomp_campaign_history"]
    });
});
