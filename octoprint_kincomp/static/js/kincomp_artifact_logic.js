/*
 * KinComp web UI: the printed artifact's logic without layout (unit-tested in node:
 * tests/js/artifact_logic.test.js): the readings typed into the form, the result's verdict
 * line, the values that decide it and the parameters Apply sets. The panel
 * (kincomp_artifact.js) binds them.
 *
 * Units as on the server: readings mm, squareness um/m, scale and scale mismatch ppm.
 */
(function () {
    "use strict";
    var K = window.KinComp;
    var A = {};

    // how many reading fields a measurement gets: as often as the program asks for each to
    // be read (its header's "repeats": 1 for the quick artifact, 3 for the full one)
    A.fieldsFor = function (info) {
        var n = parseInt((info || {}).repeats, 10);
        return n >= 1 && n <= 3 ? n : 3;
    };

    // the form's rows -> {"<id>": [mm, ...]}, or {error} naming the first field that is no
    // length; rows: [{id, fields: [text, ...]}], empty fields not measured
    A.readingsOf = function (rows) {
        var out = {};
        var error = null, field = null;
        _.each(rows, function (row) {
            var vals = [];
            _.each(row.fields, function (text, k) {
                if (String(text === undefined || text === null ? "" : text).trim() === "") return;
                var v = K.num(text);
                if (isNaN(v) || v <= 0) {
                    if (!error) {
                        error = _.sprintf(gettext("Reading %(k)s of %(id)s is not a length in mm"), {k: k + 1, id: row.id});
                        field = {id: row.id, k: k + 1};
                    }
                } else {
                    vals.push(v);
                }
            });
            if (vals.length) out[row.id] = vals;
        });
        return error ? {error: error, field: field} : {readings: out};
    };

    // the fields of a row filled with ``values`` (mm; as many as it has fields)
    A.fieldTexts = function (values, count) {
        return _.map(_.range(count), function (k) {
            return values && values.length > k ? String(values[k]) : "";
        });
    };

    // the verdict line of a run: {decision, css, title, reason} (the result document's
    // verdict: decided by the server from the findings; reason in the user's language)
    A.verdictView = function (run) {
        if (!run) return null;
        var v = run.verdict || {decision: run.trusted === false ? "do_not_apply" : "apply", reason: null};
        var views = {
            apply: {css: "alert-success", title: gettext("Apply"),
                    reason: gettext("The readings agree with each other and with the model; nothing needs a look first.")},
            apply_with_care: {css: "alert-warning", title: gettext("Apply with care"), reason: ""},
            do_not_apply: {css: "alert-error", title: gettext("Do not apply"), reason: ""}
        };
        var view = views[v.decision] || views.apply_with_care;
        return {
            decision: v.decision,
            css: view.css,
            title: view.title,
            reason: v.reason ? K.trMsg(v.reason) : view.reason
        };
    };

    var value = function (d, key, sub) {
        var v = (d[key] || {})[sub];
        return v === null || v === undefined ? null : v;
    };

    // the values that decide a result: squareness per plane (um/m) and the scale mismatch
    // per pair of axes (ppm), each with its 1 sigma; not separated: said so
    A.valueRows = function (run) {
        if (!run) return [];
        var d = run.diagnostics || {}, u = d.uncertainty || {};
        var rows = [];
        var add = function (label, key, sub, unit, digits) {
            var v = value(d, key, sub), s = value(u, key, sub);
            rows.push({
                label: label, unit: unit, key: key + "." + sub,
                value: v === null ? gettext("not separated") : K.fmt(v, digits),
                sigma: s === null ? "–" : "± " + K.fmt(s, digits)
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
        return rows;
    };

    // the line widths the fit found (mm): details below the decision
    A.widthRows = function (run) {
        if (!run) return [];
        var d = run.diagnostics || {}, u = d.uncertainty || {};
        return _.map([["vertical_walls", gettext("Line width (walls of the flat part)")],
                      ["slanted_walls", gettext("Line width (45° walls)")]], function (w) {
            var v = value(d, "line_width_mm", w[0]), s = value(u, "line_width_mm", w[0]);
            return {label: w[1], unit: "mm",
                    value: v === null ? "–" : K.fmt(v, 3), sigma: s === null ? "–" : "± " + K.fmt(s, 3)};
        });
    };

    // the parameters Apply sets: squareness (um/m) and scale (ppm) of each axis as they are
    // now (the parameters during the test) and as Apply sets them (the proposal); rows
    // that stay as they are say so
    A.applyRows = function (run) {
        if (!run || !run.proposed) return [];
        var after = run.proposed, now = run.params_before || {};
        var rows = [];
        var add = function (label, group, key, unit) {
            var a = (after[group] || {})[key], b = (now[group] || {})[key];
            a = a === undefined || a === null ? 0 : a;
            b = b === undefined || b === null ? 0 : b;
            rows.push({label: label, unit: unit, now: K.fmt(b, 1), after: K.fmt(a, 1),
                       changes: Math.abs(a - b) >= 0.05});
        };
        _.each(["xy", "xz", "yz"], function (p) {
            add(_.sprintf(gettext("Squareness %(plane)s"), {plane: p.toUpperCase()}), "squareness_um_per_m", p, "µm/m");
        });
        _.each(["x", "y", "z"], function (a) {
            add(_.sprintf(gettext("Scale %(axis)s"), {axis: a.toUpperCase()}), "scale_ppm", a, "ppm");
        });
        return rows;
    };

    K.Artifact = A;
})();
