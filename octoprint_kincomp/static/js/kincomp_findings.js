/*
 * KinComp web UI: a result's findings (what the analysis checked and saw), worst first, with
 * the advice in plain words, and the "apply anyway" step for a result that is not trusted.
 * Used by the Calibration tab's result and the campaign's joint result
 * (templates/kincomp_findings.jinja2, bound "with" a FindingsBox).
 */
(function () {
    "use strict";
    var K = window.KinComp;

    // the findings of a run in the API's order (worst first: the server decides the order);
    // a run stored before findings existed: its notes
    K.findingsOf = function (run) {
        if (!run) return [];
        if (run.findings) return run.findings;
        return _.map(run.notes_i18n || run.notes || [], function (n) {
            return {code: "note", severity: "info", message: n, advice: {text: ""}, evidence: {}};
        });
    };

    // false only when the run says so (an error finding); older runs are trusted
    K.untrusted = function (run) {
        return !!run && run.trusted === false;
    };

    /*
     * runObs: an observable (or computed) of the run shown; apply(force): applies it;
     * skipInfo: leave out the info findings (a view that shows the notes on its own).
     * The view's Apply button calls box.apply(): a trusted run is applied at once, an
     * untrusted one first shows the confirmation with its "Apply anyway" button.
     */
    K.FindingsBox = function (runObs, apply, skipInfo) {
        var self = this;
        self.trMsg = K.trMsg;
        self.items = ko.pureComputed(function () {
            return _.filter(K.findingsOf(runObs()), function (f) {
                return !(skipInfo && f.severity === "info");
            });
        });
        self.untrusted = ko.pureComputed(function () {
            return K.untrusted(runObs());
        });
        self.confirming = ko.observable(false);
        runObs.subscribe(function () {
            self.confirming(false);
        });
        self.label = function (severity) {
            return {error: gettext("Error"), warning: gettext("Warning"), info: gettext("Note")}[severity] || severity;
        };
        self.css = function (severity) {
            return "kincomp-finding kincomp-finding-" + severity + (severity === "error" ? " alert alert-error" : severity === "warning" ? " alert" : "");
        };
        self.labelCss = function (severity) {
            return severity === "error" ? "label label-important" : severity === "warning" ? "label label-warning" : "label";
        };
        self.hasAdvice = function (f) {
            return !!(f.advice && (f.advice.text || f.advice.template));
        };
        self.apply = function () {
            if (self.untrusted() && !self.confirming()) {
                self.confirming(true);
                return;
            }
            var force = self.untrusted();
            self.confirming(false);
            apply(force);
        };
        self.cancel = function () {
            self.confirming(false);
        };
    };
})();
