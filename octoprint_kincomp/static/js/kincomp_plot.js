/*
 * KinComp web UI: the classic ballbar polar plot (ISO 230-4), drawn with Flot: the radial
 * deviation magnified around the nominal circle (rings of 1 division, the scale chosen from
 * the largest deviation, in um per division), both directions (CCW blue, CW red) with the
 * fitted model, an earlier run faded behind, the fitted centre and a scale bar.
 */
(function () {
    "use strict";
    var K = window.KinComp;
    var NICE = K.NICE;
    var drawCross = K.drawCross;

    /* the legend's own box right after the plot ``target`` (made once) */
    K.legendBox = function (target) {
        var box = target.next(".kincomp-plot-legend");
        if (!box.length) {
            box = $("<div class='kincomp-plot-legend'></div>");
            target.after(box);
        }
        return box;
    };

    /* ``runs``: plot data of the server's analysis (first: the run shown, then one faded
     * run before it); returns the scale, um per division */
    K.drawPolar = function (target, runs) {
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
        var cr = runs[0].centre_removed_um;
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
            // below the plot, never over the traces (issue 35)
            legend: {container: K.legendBox(target), noColumns: 3}
        });
        target.find(".kincomp-scalebar").remove();
        target.append($("<div class='kincomp-scalebar'></div>").text(
            _.sprintf(gettext("%(um)s µm"), {um: perDiv})
        ));
        return perDiv;
    };
})();
