/*
 * KinComp web UI: what a ballbar result (a single test or a campaign's joint fit) opens with,
 * without layout (unit-tested in node: tests/js/result_logic.test.js): the verdict line (the
 * server's verdict, decided once in calibration/result.py: the UI does not rank findings),
 * the few numbers that decide it per plane (squareness, scale mismatch, backlash, servo
 * mismatch, each with its 1 sigma), whether the servo mismatch is compensated, and the
 * parameters Apply sets (now -> after). The tab (kincomp_tab.js) and campaign mode
 * (kincomp_campaign.js) bind them.
 *
 * Units as on the server: squareness um/m, scale and scale mismatch ppm, backlash um, servo
 * lag and mismatch ms, positions mm.
 */
(function () {
    "use strict";
    var K = window.KinComp;
    var R = {};

    var has = function (v) {
        return v !== null && v !== undefined && !(typeof v === "number" && isNaN(v));
    };

    // "12.3 ± 0.4" (no sigma: the value alone; no value: a dash)
    var withSigma = function (value, sigma, digits) {
        if (!has(value)) return "–";
        return K.fmt(value, digits) + (has(sigma) ? " ± " + K.fmt(sigma, digits) : "");
    };
    R.withSigma = withSigma;

    // the verdict line of a run (or a campaign's analysis): {decision, css, title, reason,
    // advice}; reason: why, in the user's language (the worst finding's message), advice:
    // what to do (that finding's advice), both from the server
    R.verdictView = function (run) {
        if (!run) return null;
        var v = run.verdict || {decision: run.trusted === false ? "do_not_apply" : "apply", reason: null};
        var views = {
            apply: {css: "alert-success", title: gettext("Apply"),
                    reason: gettext("the measurement passed every check; nothing needs a look first.")},
            apply_with_care: {css: "alert-warning", title: gettext("Apply with care"), reason: ""},
            do_not_apply: {css: "alert-error", title: gettext("Do not apply"), reason: ""}
        };
        var view = views[v.decision] || views.apply_with_care;
        var worst = v.decision === "apply" ? null : _.find(K.findingsOf(run), function (f) {
            return f.severity === (v.decision === "do_not_apply" ? "error" : "warning");
        });
        var advice = worst && worst.advice && (worst.advice.text || worst.advice.template)
            ? K.trMsg(worst.advice) : "";
        return {
            decision: v.decision,
            css: view.css,
            title: view.title,
            reason: v.reason ? K.trMsg(v.reason) : view.reason,
            advice: advice
        };
    };

    // the axes of a test's plane: {a, b} ("X", "Y" for XY)
    R.axesOf = function (diag) {
        if (diag && diag.axes && diag.axes.a) return diag.axes;
        var plane = String((diag && diag.plane) || "XY");
        return {a: plane.charAt(0), b: plane.charAt(1)};
    };

    // the backlash of a test as "+X 14.3, −X 27.6, +Y 9.5, −Y 7.1" (µm); the sides not
    // measured left out
    var backlashText = function (bl, sig, axes) {
        bl = bl || {};
        sig = sig || {};
        var parts = [];
        _.each([["a_plus", "+", "a"], ["a_minus", "−", "a"], ["b_plus", "+", "b"], ["b_minus", "−", "b"]], function (s) {
            if (!has(bl[s[0]])) return;
            parts.push(s[1] + axes[s[2]] + " " + K.fmt(bl[s[0]], 1));
        });
        var sigmas = _.filter(_.map(["a_plus", "a_minus", "b_plus", "b_minus"], function (k) {
            return sig[k];
        }), has);
        return {
            value: parts.length ? parts.join(", ") : "–",
            sigma: sigmas.length ? "± " + K.fmt(_.max(sigmas), 1) : ""
        };
    };

    /*
     * The numbers that decide a result, a row per test: ``tests`` is a list of
     * {diag, title}: diag a test's diagnostics (for a campaign's test its values from the
     * joint fit in their place: the caller merges them), title what the row is called.
     * Each row: plane, title, squareness, mismatch, backlash (texts with their 1 sigma) and
     * servo (the servo mismatch, ms).
     */
    R.decisionRows = function (tests) {
        return _.map(tests, function (t) {
            var d = t.diag || {}, u = d.uncertainty || {}, axes = R.axesOf(d);
            var bl = backlashText(d.backlash_um, u.backlash_um, axes);
            return {
                plane: d.plane || "",
                title: t.title || d.plane || "",
                squareness: withSigma(d.squareness_um_per_m, u.squareness_um_per_m, 1),
                mismatch: withSigma(d.scale_mismatch_ppm, u.scale_mismatch_ppm, 1),
                mismatchAxes: axes.a + "−" + axes.b,
                backlash: bl.value,
                backlashSigma: bl.sigma,
                servo: withSigma(d.servo_mismatch_ms, u.servo_mismatch_ms, 3)
            };
        });
    };

    // a campaign analysis' tests for decisionRows: each test's diagnostics with its values
    // from the joint fit, titled by plane, radius and feed (and height for a second XY)
    R.campaignTests = function (analysis) {
        var traces = (analysis && analysis.diagnostics && analysis.diagnostics.traces) || [];
        var planes = _.countBy(traces, "plane");
        return _.map(traces, function (t, i) {
            var d = _.extend({}, t, t.joint || {});
            var title = t.plane;
            if (planes[t.plane] > 1) {
                title = _.sprintf(gettext("%(plane)s at %(feed)s mm/min, Z %(z)s mm"), {
                    plane: t.plane, feed: K.fmt(t.feed_mm_min, 0),
                    z: t.centre ? K.fmt(t.centre[2], 0) : "–"
                });
            }
            return {diag: d, title: title, index: i};
        });
    };

    /*
     * Whether the servo mismatch a result measured is compensated by Apply: null when there
     * is nothing to say (no servo mismatch measured, or servo pre-compensation proposed);
     * else a sentence saying it is not, and why (``why``: the campaign's reason, translated;
     * a single test: one feed cannot decide it).
     */
    R.servoNote = function (proposed, servoMs, why) {
        if (!has(servoMs) || !proposed || proposed.servo_precomp) return null;
        return _.sprintf(gettext("The servo mismatch (%(ms)s ms) is not compensated: servo pre-compensation stays off. %(why)s"), {
            ms: K.fmt(servoMs, 3),
            why: why || gettext("One test at one feed cannot show that the lag grows with speed; a campaign with XY at a second feed decides it.")
        });
    };

    var backlashValue = function (v) {
        if (_.isArray(v)) {
            return _.map(v, function (pt) {
                return _.sprintf(gettext("%(um)s at %(at)s mm"), {um: K.fmt(pt.um, 1), at: K.fmt(pt.at_mm, 0)});
            }).join(", ");
        }
        return K.fmt(has(v) ? v : 0, 1);
    };
    var sameBacklash = function (a, b) {
        var flat = function (v) {
            if (_.isArray(v)) return _.map(v, function (pt) { return K.fmt(pt.at_mm, 1) + ":" + K.fmt(pt.um, 1); }).join(",");
            return K.fmt(has(v) ? v : 0, 1);
        };
        return flat(a) === flat(b);
    };

    /*
     * The parameters Apply sets: a row per parameter with its value now (the parameters
     * during the test) and after Apply (the proposal), {label, unit, now, after, changes};
     * ``all``: the rows that stay as they are too (else only those that change).
     */
    R.applyRows = function (now, after, all) {
        if (!after) return [];
        now = now || {};
        var rows = [];
        var num = function (doc, group, key) {
            var v = (doc[group] || {})[key];
            return has(v) ? v : 0;
        };
        var add = function (label, group, key, unit, digits) {
            var a = num(after, group, key), b = num(now, group, key);
            rows.push({label: label, unit: unit, now: K.fmt(b, digits), after: K.fmt(a, digits),
                       changes: K.fmt(a, digits) !== K.fmt(b, digits)});
        };
        _.each(["xy", "xz", "yz"], function (p) {
            add(_.sprintf(gettext("Squareness %(plane)s"), {plane: p.toUpperCase()}), "squareness_um_per_m", p, "µm/m", 1);
        });
        _.each(["x", "y", "z"], function (a) {
            add(_.sprintf(gettext("Scale %(axis)s"), {axis: a.toUpperCase()}), "scale_ppm", a, "ppm", 1);
        });
        _.each(["x", "y", "z"], function (a) {
            var va = (after.backlash || {})[a], vb = (now.backlash || {})[a];
            rows.push({label: _.sprintf(gettext("Backlash %(axis)s"), {axis: a.toUpperCase()}), unit: "µm",
                       now: backlashValue(vb), after: backlashValue(va), changes: !sameBacklash(va, vb)});
        });
        var precomp = !!after.servo_precomp, wasOn = !!now.servo_precomp;
        if (precomp || wasOn) {
            _.each(["x", "y", "z"], function (a) {
                add(_.sprintf(gettext("Servo lag %(axis)s"), {axis: a.toUpperCase()}), "servo_lag_ms", a, "ms", 3);
            });
        }
        if (precomp !== wasOn) {
            rows.push({label: gettext("Servo pre-compensation"), unit: "",
                       now: wasOn ? gettext("on") : gettext("off"), after: precomp ? gettext("on") : gettext("off"),
                       changes: true});
        }
        return all ? rows : _.filter(rows, "changes");
    };

    // a run's stored date as the user's local date and time ("2026-11-27 16:38"), not the
    // raw ISO text
    R.when = function (iso) {
        if (!iso) return "";
        var d = new Date(iso);
        if (isNaN(d.getTime())) return K.dateText(iso);
        var two = function (n) { return (n < 10 ? "0" : "") + n; };
        return d.getFullYear() + "-" + two(d.getMonth() + 1) + "-" + two(d.getDate()) + " " +
            two(d.getHours()) + ":" + two(d.getMinutes());
    };

    K.Result = R;
})();
