/*
 * KinComp web UI: the live ballbar sensor (issue 15).
 *
 * - the sensor's settings (Settings > KinComp, own section and Save button): port (detected
 *   ports offered, any pyserial URL accepted), baud rate, protocol, sign, units, pattern and
 *   scale, range, sample rate, and whether demo mode's virtual bar streams live;
 * - the live view in the Calibration tab (step 1): the current reading (mm, positive = bar
 *   longer), a short moving chart (Flot), the noise in µm, whether data arrives, the bar is
 *   steady and the reading in range, the capture's state and messages. A capture's result
 *   is shown by the tab like an uploaded trace's.
 *
 * The server pushes the state as plugin messages ("sensor" about twice a second while the
 * port is open, "sensor_run" when a capture was stored).
 */
$(function () {
    "use strict";
    var K = window.KinComp;
    var API = K.API;
    var num = K.num;
    var fmt = K.fmt;
    var errorText = K.errorText;
    var notify = K.notify;
    var trMsg = K.trMsg;

    var canAdmin = K.canAdmin;

    /* ------------------------------------------------------------ settings section */

    function KinCompSensorSettingsViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];

        self.enabled = ko.observable(false);
        self.port = ko.observable("");
        self.baudrate = ko.observable("115200");
        self.protocol = ko.observable("kincomp");
        self.positive = ko.observable("longer");
        self.units = ko.observable("mm");
        self.pattern = ko.observable("");
        self.scale = ko.observable("1");
        self.range = ko.observable("");
        self.rate = ko.observable("0");
        self.demoLive = ko.observable(true);
        self.demo = ko.observable(false);
        self.ports = ko.observableArray([]);
        self.printerPorts = ko.observableArray([]);
        self.errors = ko.observable({});
        self.formError = ko.observable("");
        self.savedMessage = ko.observable("");
        self.saving = ko.observable(false);
        self.loaded = null;
        self.bauds = [9600, 19200, 38400, 57600, 115200, 230400, 250000, 460800, 500000, 921600, 1000000, 2000000];

        self.canWrite = ko.pureComputed(function () {
            return canAdmin(self);
        });
        self.fieldError = function (key) {
            return self.errors()["sensor." + key] || "";
        };
        self.hostTimed = ko.pureComputed(function () {
            return self.protocol() !== "kincomp";
        });

        self.fromSettings = function (settings, demoOn) {
            var s = settings.sensor;
            self.loaded = {sensor: s, live: settings.demo.live};
            self.enabled(s.enabled);
            self.port(s.port);
            self.baudrate(String(s.baudrate));
            self.protocol(s.protocol);
            self.positive(s.positive);
            self.units(s.units);
            self.pattern(s.pattern);
            self.scale(String(s.scale));
            self.range(s.range);
            self.rate(String(s.sample_rate_hz));
            self.demoLive(settings.demo.live);
            self.demo(demoOn);
        };

        self.load = function () {
            K.get(API("status")).done(function (status) {
                self.fromSettings(status.settings, status.demo);
                self.errors({});
                self.formError("");
            });
            if (self.canWrite()) self.loadPorts();
        };

        self.loadPorts = function () {
            K.get(API("sensor/ports")).done(function (resp) {
                self.ports(_.map(resp.ports, function (p) {
                    return {device: p.device, label: p.description ? p.device + " – " + p.description : p.device};
                }));
                self.printerPorts(_.uniq(resp.printer_ports || []));  // (OctoPrint may list one twice)
            });
        };

        self.collect = function () {
            var errs = {};
            var number = function (key, text) {
                var v = num(text);
                if (isNaN(v)) errs["sensor." + key] = gettext("Enter a number");
                return v;
            };
            return {
                errors: errs,
                data: {
                    sensor: {
                        enabled: self.enabled(),
                        port: String(self.port() || "").trim(),
                        baudrate: number("baudrate", self.baudrate()),
                        protocol: self.protocol(),
                        positive: self.positive(),
                        units: self.units(),
                        pattern: self.pattern(),
                        scale: number("scale", self.scale()),
                        range: String(self.range() || "").trim(),
                        sample_rate_hz: number("sample_rate_hz", self.rate())
                    },
                    demo: {live: self.demoLive()}
                }
            };
        };

        self.changed = function () {
            if (!self.loaded) return false;
            var now = self.collect().data;
            return JSON.stringify(now.sensor) !== JSON.stringify(_.pick(self.loaded.sensor, _.keys(now.sensor))) ||
                now.demo.live !== self.loaded.live;
        };

        self.save = function () {
            self.savedMessage("");
            if (!self.loaded) return $.Deferred().reject().promise();
            // the server names the field first: "sensor.baudrate: ..."
            return K.saveSettings(self, self.collect(), function (path) {
                return path.indexOf("sensor.") === 0 ? path : undefined;
            }).done(function (resp) {
                self.fromSettings(resp.settings, self.demo());
            });
        };

        self.onSettingsShown = function () {
            self.savedMessage("");
            self.load();
        };

        self.onSettingsBeforeSave = function () {
            // OctoPrint's own Save button saves this section too (through KinComp's API)
            if (self.changed()) {
                self.save().fail(function () {
                    notify({title: gettext("KinComp sensor settings not saved"), text: self.formError(), type: "error", hide: false});
                });
            }
        };
    }

    /* --------------------------------------------------------------- live view */

    var STATES = function () {
        return {
            idle: gettext("Closed"),
            preview: gettext("Live view"),
            armed: gettext("Armed: waiting for the test to start"),
            capturing: gettext("Capturing the test…"),
            done: gettext("Test captured"),
            failed: gettext("Failed")
        };
    };

    function KinCompSensorLiveViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.access = parameters[1];
        self.tab = parameters[2];

        self.status = ko.observable({state: "idle", check: {}});
        self.chart = {t: [], mm: []};
        self.busy = ko.observable(false);
        self.error = ko.observable("");
        self.runMessage = ko.observable("");
        self.runFailed = ko.observable(false);

        self.canWrite = ko.pureComputed(function () {
            return canAdmin(self);
        });
        self.configured = ko.pureComputed(function () {
            return !!self.status().configured;
        });
        self.state = ko.pureComputed(function () {
            return self.status().state || "idle";
        });
        self.stateText = ko.pureComputed(function () {
            return STATES()[self.state()] || self.state();
        });
        self.isOpen = ko.pureComputed(function () {
            return !!self.status().port_open;
        });
        self.capturing = ko.pureComputed(function () {
            return !!self.status().armed;
        });
        self.sourceText = ko.pureComputed(function () {
            var st = self.status();
            if (st.source === "demo") return gettext("Virtual ballbar of demo mode (SIMULATED), streamed through a pseudo-terminal");
            if (st.source === "sensor") return _.sprintf(gettext("Sensor on %(port)s (%(protocol)s)"), {port: st.port, protocol: st.protocol});
            return "";
        });
        self.reading = ko.pureComputed(function () {
            var v = self.status().reading_mm;
            return v === null || v === undefined ? "–" : (v >= 0 ? "+" : "") + fmt(v, 4);
        });
        self.noise = ko.pureComputed(function () {
            return fmt(self.status().noise_um, 2);
        });
        self.message = ko.pureComputed(function () {
            var st = self.status();
            return st.message ? trMsg(st.message_i18n || st.message) : "";
        });
        self.progress = ko.pureComputed(function () {
            var st = self.status();
            if (!st.armed) return "";
            return _.sprintf(gettext("Armed for %(path)s: %(n)s samples recorded, runs found %(runs)s of 2."),
                {path: st.armed.path, n: st.samples || 0, runs: st.runs_found || 0}) +
                (st.armed.stopping ? " " + gettext("The program has ended: waiting for the end in the data.") : "");
        });
        // the checks before a test: [label, ok (true/false/null), detail]
        self.checks = ko.pureComputed(function () {
            var c = self.status().check || {};
            var rng = c.range_mm;
            return [
                {id: "data", label: gettext("Data arrives"), ok: self.isOpen() ? !!c.data : null, detail: ""},
                {id: "steady", label: gettext("Bar steady (seated in its cups)"), ok: c.steady === undefined ? null : c.steady,
                    detail: c.steady_max_um ? _.sprintf(gettext("noise at most %(um)s µm"), {um: c.steady_max_um}) : ""},
                {id: "range", label: gettext("Reading in the sensor's range"), ok: c.in_range === undefined ? null : c.in_range,
                    detail: rng ? _.sprintf(gettext("%(lo)s…%(hi)s mm, margin %(m)s mm"), {lo: fmt(rng[0], 2), hi: fmt(rng[1], 2), m: fmt(c.margin_mm, 2)})
                        : gettext("range unknown (set it in the settings or the sensor's header)")}
            ];
        });
        self.checkIcon = function (ok) {
            return ok === true ? "fas fa-check text-success" : ok === false ? "fas fa-times text-error" : "fas fa-question muted";
        };

        self.update = function (status, chart) {
            self.status(status || {state: "idle", check: {}});
            // a new capture under way: the last one's "captured and analysed" is gone
            if (self.status().armed) {
                self.runMessage("");
                self.runFailed(false);
            }
            if (chart) self.chart = chart;
            self.draw();
        };

        self.refresh = function () {
            var perm = self.access.permissions.STATUS;
            if (!perm || !self.loginState.hasPermission(perm)) return;
            K.get(API("sensor/live")).done(function (resp) {
                self.update(resp, resp.chart);
            });
        };

        self.post = function (what, body) {
            self.busy(true);
            self.error("");
            return OctoPrint.postJson(API("sensor/" + what), body || {})
                .done(function (status) {
                    self.update(status, what === "close" ? {t: [], mm: []} : null);
                })
                .fail(function (jqXHR) {
                    self.error(errorText(jqXHR));
                })
                .always(function () {
                    self.busy(false);
                });
        };
        self.open = function () {
            self.post("open");
        };
        self.close = function () {
            self.post("close");
        };
        self.stop = function () {
            self.post("stop");
        };
        self.armLast = function () {
            self.post("arm", {path: self.tab.programPath()});
        };
        self.canArm = ko.pureComputed(function () {
            return self.canWrite() && self.configured() && !self.capturing() && !!self.tab.programPath() && !self.busy();
        });

        /* the moving chart: the last seconds of readings, newest at 0 */
        self.draw = function () {
            var target = $("#kincomp_sensor_chart");
            if (!target.is(":visible") || !target.width()) return;
            var data = _.zip(self.chart.t || [], self.chart.mm || []);
            var span = data.length ? Math.max(1, -data[0][0]) : 10;
            $.plot(target, [{data: data, color: "#1f5fbf", lines: {lineWidth: 1.2}, shadowSize: 0}], {
                xaxis: {min: -span, max: 0,
                    tickFormatter: function (v) { return v.toFixed(span < 5 ? 1 : 0) + " s"; }},
                yaxis: {tickFormatter: function (v) { return v.toFixed(3); }, labelWidth: 50},
                grid: {borderWidth: 1, borderColor: "#cccccc", hoverable: false}
            });
        };

        self.runDone = function (run) {
            self.tab.loadRuns();
            if (run.campaign || run.test_of) return; // a campaign's test: campaign mode shows it
            if (run.status !== "ok") {
                self.runFailed(true);
                self.runMessage(_.sprintf(gettext("The capture failed: %(reason)s. The data so far is kept in the History."),
                    {reason: trMsg(run.message_i18n || run.message)}));
                return;
            }
            self.runFailed(false);
            self.runMessage(gettext("Test captured and analysed: see 3. Result."));
            K.get(API("runs/" + encodeURIComponent(run.id))).done(function (full) {
                self.tab.printing(false);
                self.tab.analysed(full);
            });
        };

        self.onDataUpdaterPluginMessage = function (plugin, data) {
            if (plugin !== "kincomp" || !data) return;
            if (data.type === "sensor") {
                self.update(data.status, data.chart);
            } else if (data.type === "sensor_run" && data.run) {
                self.runDone(data.run);
            }
        };

        self.onTabChange = function (current) {
            if (current === "#tab_plugin_kincomp") {
                self.refresh();
                window.setTimeout(self.draw, 50);
            }
        };
        self.onStartupComplete = self.refresh;
        self.onUserLoggedIn = self.refresh;
        self.tab.step.subscribe(function () {
            window.setTimeout(self.draw, 50);
        });
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompSensorSettingsViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel"],
        elements: ["#kincomp_sensor_settings"]
    });
    OCTOPRINT_VIEWMODELS.push({
        construct: KinCompSensorLiveViewModel,
        dependencies: ["loginStateViewModel", "accessViewModel", "kinCompTabViewModel"],
        elements: ["#kincomp_sensor_live"]
    });
});
