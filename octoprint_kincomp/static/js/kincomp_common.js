/*
 * KinComp web UI, shared pieces (loaded first): the plugin's API address, number reading and
 * formatting, error texts, notifications, copying to the clipboard, the translation of the
 * core's messages and the server's notices, and the table rows of a ballbar result.
 *
 * Units as on the server: squareness um/m, scale ppm, backlash um, positions mm, feeds mm/min.
 * Every string goes through gettext(); server notifications arrive as English message ids
 * with parameters and are translated here.
 */
(function () {
    "use strict";

    var API = function (path) {
        return OctoPrint.getBlueprintUrl("kincomp") + path;
    };

    var num = function (value) {
        // a number from a text field ("1,5" accepted as 1.5); NaN when it is not one
        if (typeof value === "number") return value;
        var text = String(value === undefined || value === null ? "" : value).trim();
        if (!text.length) return NaN;
        text = text.replace(",", ".");
        return /^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(text) ? parseFloat(text) : NaN;
    };

    var fmt = function (value, digits) {
        if (value === null || value === undefined || isNaN(value)) return "–";
        return Number(value).toFixed(digits === undefined ? 2 : digits);
    };

    var reductionText = function (row) {
        // a compared row's reduction: "at noise level" when the before value is within the
        // noise floor (the server decides: simulator/closed_loop.py), else the per cent
        if (!row) return "";
        if (row.at_noise) return gettext("at noise level");
        if (row.compensated === false) return gettext("not compensated");
        return row.reduction_pct !== null && row.reduction_pct !== undefined
            ? fmt(row.reduction_pct, 1) + " %" : "";
    };

    // a stored ISO date as "2026-11-27 16:38" (one line in a table)
    var dateText = function (iso) {
        return iso ? String(iso).replace("T", " ").slice(0, 16) : "–";
    };

    // a run's source as stored (English, e.g. "live capture (XZ)"), in the user's language
    var sourceText = function (name) {
        var m = /^live capture \((.*)\)$/.exec(name || "");
        if (m) return _.sprintf(gettext("live capture (%(plane)s)"), {plane: m[1]});
        if (name === "typed summary") return gettext("typed summary");
        if (name === "printed artifact") return gettext("printed artifact");
        return name || "";
    };

    // what the history's figure columns show of a run summary (GET /runs): a ballbar
    // test's squareness (µm/m) and circularity (µm); a printed artifact's squareness per
    // plane it measured and its scale mismatches (ppm), and a word where a circle's figure
    // has no meaning for it
    var historyFigures = function (run) {
        if (run.source !== "artifact") {
            return {
                squareness: fmt(run.squareness_um_per_m, 1),
                circularity: fmt(run.circularity_um, 1),
                mismatch: ""
            };
        }
        var pick = function (values, keys, label) {
            return _.filter(_.map(keys, function (k) {
                var v = (values || {})[k];
                return v === null || v === undefined || isNaN(v) ? null : label(k) + " " + fmt(v, 1);
            }));
        };
        var planes = run.planes || ["XY", "XZ", "YZ"];
        var sq = pick(run.squareness_um_per_m, _.map(planes, function (p) {
            return String(p).toLowerCase();
        }), function (k) {
            return k.toUpperCase();
        });
        var mm = pick(run.scale_mismatch_ppm, ["x-y", "x-z", "y-z"], function (k) {
            return k.toUpperCase();
        });
        // a value a line (the cells keep the line breaks, kincomp.css): the history stays
        // as wide as a ballbar run's
        return {
            squareness: sq.length ? sq.join("\n") : gettext("not measured"),
            circularity: gettext("no circle (artifact)"),
            mismatch: mm.length
                ? _.sprintf(gettext("scale mismatch %(values)s ppm"), {values: mm.join("\n")}) : ""
        };
    };

    var errorText = function (jqXHR) {
        // the server's {"error": ...} message, or the HTTP status
        var response = jqXHR && (jqXHR.responseJSON || jqXHR.response || jqXHR.responseText);
        if (typeof response === "string") {
            try {
                response = JSON.parse(response);
            } catch (e) {
                return response;
            }
        }
        if (response && response.error) return response.error;
        return _.sprintf(gettext("Request failed (%(status)s)"), {
            status: jqXHR ? jqXHR.status : "?"
        });
    };

    var notify = function (options) {
        // text may carry server or user strings (commands, file names): never as HTML
        return new PNotify(_.extend({title_escape: true, text_escape: true}, options));
    };

    // copy text to the clipboard: the Clipboard API where the page may use it (https,
    // localhost), else a selected text area inside ``near`` (a modal dialog keeps the focus
    // inside itself) and the browser's copy command; calls done(ok)
    var copyText = function (text, near, done) {
        if (navigator.clipboard && window.isSecureContext) {
            navigator.clipboard.writeText(text).then(
                function () { done(true); },
                function () { done(false); });
            return;
        }
        var area = $("<textarea readonly></textarea>")
            .css({position: "fixed", top: 0, left: 0, width: "1px", height: "1px", opacity: 0})
            .val(text);
        $(near || "body").append(area);
        area[0].select();
        var ok = false;
        try {
            ok = document.execCommand("copy");
        } catch (e) {
            ok = false;
        }
        area.remove();
        done(ok);
    };

    // KinComp's version and homepage (README) from a /status response
    var about = function (status) {
        var eq = status.equivalents || {};
        return {version: status.version || "", homepage: (eq.about && eq.about.homepage) || "",
                firmwareHelp: (eq.about && eq.about.firmware_help) || ""};
    };

    // the manual's pages in docs/ (the settings page links them); the page names are the
    // files' names in docs/, the links go to the repository at the project's homepage
    // (titles translated when asked for: gettext is not there yet while this file loads)
    var DOCS = function () {
        return [
            ["user-guide", gettext("User guide")],
            ["calibration", gettext("Calibration and campaigns")],
            ["live-capture", gettext("Live capture and sensors")],
            ["command-line", gettext("Command line")],
            ["http-api", gettext("HTTP API")],
            ["firmware-export", gettext("Firmware export")],
            ["how-compensation-works", gettext("How compensation works")],
            ["trust-checks", gettext("What KinComp checks before it trusts a result")],
            ["motion-limits", gettext("Motion limits of the printer")],
            ["artifact", gettext("Calibration with a printed artifact")]
        ];
    };
    var docs = function (homepage) {
        if (!homepage) return [];
        return _.map(DOCS(), function (d) {
            return {title: d[1], href: homepage + "/blob/main/docs/" + d[0] + ".md"};
        });
    };

    // a Flot point symbol (Flot itself draws only circles without its symbol plugin)
    var drawCross = function (ctx, x, y, radius) {
        ctx.moveTo(x - radius, y - radius);
        ctx.lineTo(x + radius, y + radius);
        ctx.moveTo(x - radius, y + radius);
        ctx.lineTo(x + radius, y - radius);
    };

    // a message of KinComp's core: {text, template, params} (params may be such messages
    // too), translated here; a plain string as it is
    var trMsg = function (msg) {
        if (!msg || typeof msg !== "object") return msg;
        if (!msg.template) return msg.text;
        var params = _.mapValues(msg.params || {}, trMsg);
        try {
            return _.isEmpty(params) ? gettext(msg.template) : _.sprintf(gettext(msg.template), params);
        } catch (e) {
            return msg.text;
        }
    };

    var translateNotice = function (data) {
        var text = gettext(data.msgid);
        var params = _.mapValues(data.params || {}, trMsg);
        _.each(data.translate || [], function (key) {
            if (_.has(params, key)) params[key] = gettext(params[key]);
        });
        try {
            return _.sprintf(text, params);
        } catch (e) {
            return data.text;
        }
    };

    /* ---------------------------------------------------------------- settings pane */

    // the rows of a test's table; ``axes``: the plane's axes {a, b} ("X", "Y"), so that the
    // backlash sides are named as the proposal names them (+X, not +A)
    var rows = function (axes) {
        axes = axes || {a: "A", b: "B"};
        var side = function (sign, axis) {
            return _.sprintf(gettext("Backlash %(side)s"), {side: sign + axis});
        };
        return [
        ["squareness_um_per_m", gettext("Squareness"), "µm/m"],
        ["scale_mismatch_ppm", gettext("Scale mismatch"), "ppm"],
        ["servo_mismatch_ms", gettext("Servo mismatch"), "ms"],
        ["backlash_um.a_plus", side("+", axes.a), "µm"],
        ["backlash_um.a_minus", side("−", axes.a), "µm"],
        ["backlash_um.b_plus", side("+", axes.b), "µm"],
        ["backlash_um.b_minus", side("−", axes.b), "µm"],
        ["circularity_um.ccw", gettext("Circularity CCW"), "µm"],
        ["circularity_um.cw", gettext("Circularity CW"), "µm"],
        ["circularity_um.bidirectional", gettext("Circularity bidirectional G(b)"), "µm"],
        ["circularity_filtered_um.bidirectional", gettext("G(b) filtered (1°)"), "µm"],
        ["hysteresis_um", gettext("Hysteresis H"), "µm"]
        ];
    };

    var pick = function (obj, path) {
        _.each(path.split("."), function (part) {
            obj = obj === null || obj === undefined ? undefined : obj[part];
        });
        return obj;
    };

    // the table rows of a proposed parameter set (a run's "proposed"); ``servo``: with the
    // servo lags and pre-compensation
    var proposedRows = function (p, servo) {
        var bl = function (v) {
            if (_.isArray(v)) {
                return _.map(v, function (pt) {
                    return _.sprintf(gettext("%(um)s µm at %(at)s mm"), {um: fmt(pt.um, 1), at: fmt(pt.at_mm, 0)});
                }).join(", ");
            }
            return fmt(v, 1) + " µm";
        };
        var out = [
            {label: gettext("Squareness XY"), value: fmt(p.squareness_um_per_m.xy, 1) + " µm/m"},
            {label: gettext("Squareness XZ"), value: fmt(p.squareness_um_per_m.xz, 1) + " µm/m"},
            {label: gettext("Squareness YZ"), value: fmt(p.squareness_um_per_m.yz, 1) + " µm/m"},
            {label: gettext("Scale X"), value: fmt(p.scale_ppm.x, 1) + " ppm"},
            {label: gettext("Scale Y"), value: fmt(p.scale_ppm.y, 1) + " ppm"},
            {label: gettext("Scale Z"), value: fmt(p.scale_ppm.z, 1) + " ppm"},
            {label: gettext("Backlash X"), value: bl(p.backlash.x)},
            {label: gettext("Backlash Y"), value: bl(p.backlash.y)},
            {label: gettext("Backlash Z"), value: bl(p.backlash.z)}
        ];
        if (servo && p.servo_lag_ms) {
            _.each(["x", "y", "z"], function (a) {
                out.push({label: _.sprintf(gettext("Servo lag %(axis)s"), {axis: a.toUpperCase()}),
                          value: fmt(p.servo_lag_ms[a], 3) + " ms"});
            });
            out.push({label: gettext("Servo pre-compensation"),
                      value: p.servo_precomp ? gettext("on") : gettext("off")});
        }
        return out;
    };

    var NICE = [0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];

    /* ---------------------------------------------------------------- settings forms */

    // save a settings form through KinComp's API: ``vm`` has the observables errors,
    // formError, savedMessage and saving; ``collected`` is {errors (fields that are not
    // numbers), data}; ``fieldOf(path)`` gives the form's key of the field the server names
    // first in its message ("params.scale_ppm.x: ..."), or nothing
    // whether a save was refused because another printer profile's settings are in force
    // now than the page was loaded for (409 with "profile_changed": reload to go on)
    var profileChanged = function (jqXHR) {
        var response = jqXHR && jqXHR.responseJSON;
        return !!(jqXHR && jqXHR.status === 409 && response && response.profile_changed);
    };

    var saveSettings = function (vm, collected, fieldOf) {
        vm.savedMessage("");
        if (!_.isEmpty(collected.errors)) {
            vm.errors(collected.errors);
            vm.formError(gettext("Some values are not numbers; see the marked fields."));
            return $.Deferred().reject().promise();
        }
        vm.saving(true);
        return OctoPrint.postJson(API("settings"), collected.data)
            .done(function () {
                vm.errors({});
                vm.formError("");
                vm.savedMessage(gettext("Saved."));
            })
            .fail(function (jqXHR) {
                var msg = errorText(jqXHR);
                if (vm.staleProfile) vm.staleProfile(profileChanged(jqXHR));
                var path = msg.split(":")[0];
                var errs = {};
                var field = fieldOf(path);
                if (field) errs[field] = msg.slice(path.length + 1).trim();
                vm.errors(errs);
                // the field's own message stands next to it; here no internal key
                vm.formError(field ? gettext("a value is not accepted; see the marked field.") : msg);
            })
            .always(function () {
                vm.saving(false);
            });
    };

    // whether the logged-in user has KinComp's admin permission (a view model ``vm`` with
    // OctoPrint's loginState and access view models; re-evaluated on login and logout)
    var canAdmin = function (vm) {
        vm.loginState.currentUser();
        var perm = vm.access.permissions.PLUGIN_KINCOMP_ADMIN;
        return perm ? vm.loginState.hasPermission(perm) : false;
    };

    // what the user's Apply did, said beside "Applied on" for the run or campaign it applied
    // only (``shown``: the observable of the one the page shows). note(): its text;
    // note.said(id, resp, done): the apply answer ``resp`` in words, ``done`` when the
    // parameters are in force now (a print running: they wait for the next one)
    var appliedNote = function (shown) {
        var by = ko.observable({id: null, text: ""});
        var note = ko.pureComputed(function () {
            var s = shown();
            return s && s.id === by().id ? by().text : "";
        });
        note.said = function (id, resp, done) {
            var waiting = resp && resp.compensation && resp.compensation.pending_params_hash;
            by({id: id, text: waiting
                ? gettext("Parameters saved; a print is running, so they and compensation take effect from the next print on.")
                : done});
        };
        return note;
    };

    window.KinComp = {
        API: API,
        appliedNote: appliedNote,
        canAdmin: canAdmin,
        num: num,
        fmt: fmt,
        reductionText: reductionText,
        dateText: dateText,
        sourceText: sourceText,
        historyFigures: historyFigures,
        errorText: errorText,
        notify: notify,
        copyText: copyText,
        about: about,
        docs: docs,
        drawCross: drawCross,
        trMsg: trMsg,
        translateNotice: translateNotice,
        rows: rows,
        pick: pick,
        proposedRows: proposedRows,
        NICE: NICE,
        saveSettings: saveSettings,
        profileChanged: profileChanged
    };
})();
