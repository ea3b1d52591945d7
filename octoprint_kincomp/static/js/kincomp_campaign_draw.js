/*
 * KinComp web UI, campaign mode's drawings and tables (KinComp.campaign; loaded before
 * kincomp_campaign.js): the machine volume from three sides (top XY, front XZ, side YZ) with
 * every planned test projected on it (SVG y points down: heights are drawn negated), and the
 * result's tables: per test the rows of the paper's Table 2 (before, after, reduction; or the
 * measured value with its 1-sigma uncertainty from the joint fit), and the jointly fitted
 * values. Units as on the server: mm, um/m, ppm, um, ms.
 */
(function () {
    "use strict";
    var K = window.KinComp;
    var fmt = K.fmt;

    var PLANE_AXES = {XY: [0, 1], XZ: [0, 2], YZ: [1, 2]};

    // the points (mm, x y z) the test's arm end sweeps: overshoots and both directions
    var sweep = function (step) {
        var s = step.spec || {};
        var r = step.radius_mm, c = step.centre;
        var ab = PLANE_AXES[step.plane];
        var over = s.overshoot_deg || 0;
        var a0 = (s.start_deg || 0) - over;
        var a1 = (s.start_deg || 0) + (s.capture_deg || 360) + over;
        var pts = [];
        for (var d = a0; d <= a1 + 1e-9; d += Math.max(1, (a1 - a0) / 90)) {
            var t = (d * Math.PI) / 180;
            var p = c.slice();
            p[ab[0]] += r * Math.cos(t);
            p[ab[1]] += r * Math.sin(t);
            pts.push(p);
        }
        return pts;
    };

    // the volume seen along one axis, with every test projected on it; ``currentN``: the
    // test to print next (drawn bold)
    var view = function (plane, caption, volume, steps, currentN) {
        var ab = PLANE_AXES[plane];
        var a0 = volume[2 * ab[0]], a1 = volume[2 * ab[0] + 1];
        var b0 = volume[2 * ab[1]], b1 = volume[2 * ab[1] + 1];
        var span = Math.max(a1 - a0, b1 - b0);
        var pad = span * 0.06;
        // tests whose labels fall on one spot share one label ("3, 4", not "34")
        var labelled = []; // the paths that carry a label
        var paths = _.map(steps, function (step) {
            var xy = _.map(sweep(step), function (p) {
                return [p[ab[0]], -p[ab[1]]];
            });
            var top = _.min(xy, function (q) {
                return q[1];
            });
            var path = {
                points: _.map(xy, function (q) {
                    return q[0].toFixed(2) + "," + q[1].toFixed(2);
                }).join(" "),
                cls: "kincomp-campaign-path kincomp-campaign-" + step.plane.toLowerCase() +
                    (step.n === currentN ? " kincomp-campaign-current" : "") +
                    (step.run ? " kincomp-campaign-done" : ""),
                lx: top[0],
                ly: top[1] - span * 0.015,
                label: String(step.n)
            };
            var near = _.find(labelled, function (other) {
                return Math.abs(other.lx - path.lx) < span * 0.06 && Math.abs(other.ly - path.ly) < span * 0.06;
            });
            if (near) {
                near.label += ", " + step.n;
                path.label = "";
            } else {
                labelled.push(path);
            }
            return path;
        });
        return {
            viewBox: [a0 - pad, -(b1 + pad), a1 - a0 + 2 * pad, b1 - b0 + 2 * pad].join(" "),
            x: a0, y: -b1, w: a1 - a0, h: b1 - b0,
            font: (span / 16).toFixed(1),
            paths: paths,
            caption: caption
        };
    };

    var views = function (volume, steps, currentN) {
        return _.map([["XY", gettext("Top (XY)")], ["XZ", gettext("Front (XZ)")],
                      ["YZ", gettext("Side (YZ)")]], function (v) {
            return view(v[0], v[1], volume, steps, currentN);
        });
    };

    var withSigma = function (value, sigma, digits) {
        if (value === null || value === undefined) return "–";
        return fmt(value, digits) + (sigma !== null && sigma !== undefined ? " ± " + fmt(sigma, digits) : "");
    };

    // per test of an analysed campaign (the server's "analysis"): title, plot data (and the
    // plot of the campaign it re-tests) and the Table-2 rows
    var planes = function (a) {
        var traces = a.diagnostics.traces || [];
        return _.map(a.comparison || [], function (cmp, i) {
            var t = traces[i] || {};
            var labels = K.rows(K.Result.axesOf(t));
            var sig = (t.joint || {}).uncertainty || {};
            var compared = _.some(cmp.rows, function (r) {
                return r.before !== null && r.before !== undefined;
            });
            var rows = _.map(cmp.rows, function (r) {
                var l = _.find(labels, function (x) {
                    return x[0] === r.key;
                });
                return {
                    label: l ? l[1] : r.error,
                    unit: l ? l[2] : r.unit,
                    before: fmt(r.before),
                    after: compared ? fmt(r.after) : withSigma(r.after, K.pick(sig, r.key), 2),
                    reduction: K.reductionText(r)
                };
            });
            var other = {XY: ["Z", 2], XZ: ["Y", 1], YZ: ["X", 0]}[t.plane] || ["Z", 2];
            return {
                index: i,
                step: cmp.step,
                compared: compared,
                rows: rows,
                plot: a.plots && a.plots[i],
                before: cmp.before_plot,
                title: _.sprintf(gettext("%(n)s. %(plane)s, R %(r)s mm, %(feed)s mm/min, at %(axis)s = %(h)s mm"), {
                    n: i + 1, plane: t.plane, r: t.radius_mm, feed: t.feed_mm_min,
                    axis: other[0], h: t.centre ? fmt(t.centre[other[1]], 0) : "–"
                })
            };
        });
    };

    // the jointly fitted values of an analysed campaign with their 1-sigma uncertainties
    var jointRows = function (a) {
        var c = a.diagnostics.campaign;
        var u = c.uncertainty || {};
        var out = [];
        _.each(c.squareness_um_per_m || {}, function (v, k) {
            out.push({label: _.sprintf(gettext("Squareness %(plane)s"), {plane: k.toUpperCase()}),
                      value: withSigma(v, (u.squareness_um_per_m || {})[k], 1) + " µm/m"});
        });
        _.each(c.scale_mismatch_ppm || {}, function (v, k) {
            out.push({label: _.sprintf(gettext("Scale mismatch %(axes)s"), {axes: k.toUpperCase()}),
                      value: withSigma(v, (u.scale_mismatch_ppm || {})[k], 1) + " ppm"});
        });
        _.each(c.servo_lag_ms || {}, function (v, k) {
            out.push({label: _.sprintf(gettext("Servo lag %(axis)s"), {axis: k.toUpperCase()}),
                      value: withSigma(v, (u.servo_lag_ms || {})[k], 3) + " ms"});
        });
        if (c.fit) {
            out.push({label: gettext("Fit residual (rms)"), value: _.map(c.fit.rms_um, function (v) {
                return fmt(v, 2);
            }).join(" / ") + " µm"});
        }
        return out;
    };

    // which pause a campaign test's program waits at: "mount" (before its runs) or
    // "unmount" (after them). ``resumes``: how often the print went on since it (re)started
    // (OctoPrint's Restart starts it again from the top: 0), null when not known (the page
    // was loaded during the print): then by how far the file is printed (the mount pause is
    // near its start, the unmount pause near its end)
    var pauseKind = function (resumes, pct) {
        if (resumes !== null && resumes !== undefined) return resumes > 0 ? "unmount" : "mount";
        return (pct || 0) < 50 ? "mount" : "unmount";
    };

    // a test of the campaign in words, as the server words it (``step.test``:
    // calibration/ballbar/campaign.test_words; the plan's names "xy-f3700" are keys, not shown)
    var testName = function (step) {
        return K.trMsg(step.test) || step.plane;
    };

    K.campaign = {views: views, planes: planes, jointRows: jointRows, pauseKind: pauseKind, testName: testName};
})();
