/*
 * KinComp web UI: the settings page's plain fields, made from the server's declaration of
 * the settings (service/settings/schema.py, SETTINGS: path, kind, label, unit, help,
 * choices; the template renders the same list). No layout here: the values a form shows,
 * reading them back into a settings document, and which field a server error names.
 *
 * Kinds: "bool" (a checkbox), "choice" (a select), "number" (a text field), and
 * "optional_number" (a text field whose empty text means null). Numbers are shown with at
 * most 3 decimals; a field still showing that text stands for the stored value itself, so
 * that saving an untouched form changes nothing.
 */
(function (root) {
    "use strict";
    var K = root.KinComp = root.KinComp || {};
    var ko = root.ko, _ = root._;

    // a stored number as the form shows it (at most 3 decimals: 30.8903127 -> "30.89")
    var shown = function (v) {
        return String(Number(Number(v).toFixed(3)));
    };
    // the value a field's text stands for: the stored value while the text is what the form
    // showed of it, else the text
    var kept = function (text, stored) {
        return stored !== undefined && stored !== null && text === shown(stored) ? stored : text;
    };

    // the value at a dotted path ("demo.enabled") of a document; undefined where absent
    var getPath = function (doc, path) {
        return _.reduce(path.split("."), function (obj, key) {
            return obj === undefined || obj === null ? undefined : obj[key];
        }, doc);
    };
    // sets the value at a dotted path, making the objects on the way
    var setPath = function (doc, path, value) {
        var keys = path.split("."), obj = doc;
        _.each(keys.slice(0, -1), function (key) {
            if (obj[key] === undefined || obj[key] === null || typeof obj[key] !== "object") obj[key] = {};
            obj = obj[key];
        });
        obj[keys[keys.length - 1]] = value;
        return doc;
    };

    var isNumber = function (f) {
        return f.kind === "number" || f.kind === "optional_number";
    };

    /*
     * fields: the declaration's plain fields ([{path, kind, label, ...}], in page order).
     * value[path]: the observable the field is bound to (text for numbers).
     */
    K.SettingsForm = function (fields) {
        var self = this;
        self.fields = fields;
        self.value = {};
        _.each(fields, function (f) {
            self.value[f.path] = ko.observable(f.kind === "bool" ? false : "");
        });
        self.loaded = null;

        // shows the settings document ``s`` (as GET /status gives it)
        self.show = function (s) {
            self.loaded = s;
            _.each(fields, function (f) {
                var v = getPath(s, f.path);
                if (f.kind === "bool") self.value[f.path](!!v);
                else if (isNumber(f)) self.value[f.path](v === null || v === undefined ? "" : shown(v));
                else self.value[f.path](v === undefined || v === null ? "" : String(v));
            });
        };

        // the fields' values written into ``doc`` (a settings document, changed in place);
        // ``errors`` gets path -> message for a text that is not a number. ``read`` turns a
        // text into a number (NaN when it is not one: K.num)
        self.collect = function (doc, errors, read) {
            _.each(fields, function (f) {
                var raw = self.value[f.path]();
                var value = raw;
                if (f.kind === "bool") {
                    value = !!raw;
                } else if (isNumber(f)) {
                    var text = String(raw === undefined || raw === null ? "" : raw).trim();
                    if (f.kind === "optional_number" && text === "") {
                        value = null;
                    } else {
                        value = read(kept(text, getPath(self.loaded, f.path)));
                        if (isNaN(value)) errors[f.path] = gettext("Enter a number");
                    }
                }
                setPath(doc, f.path, value);
            });
            return doc;
        };

        // the stored values of the fields, as collect() writes them (to see what changed)
        self.stored = function (doc) {
            _.each(fields, function (f) {
                var v = getPath(self.loaded, f.path);
                if (f.kind === "bool") v = !!v;
                else if (v === undefined) v = null;
                setPath(doc, f.path, v);
            });
            return doc;
        };

        // the paths of the fields that show a server error ("params.scale_ppm.x: ...")
        self.paths = _.pluck(_.filter(fields, isNumber), "path");

        // the label of the field at ``path`` (translated), or null
        self.label = function (path) {
            var f = _.find(fields, function (x) { return x.path === path; });
            return f ? gettext(f.label) : null;
        };
    };

    K.shownNumber = shown;
    K.keptNumber = kept;
    K.getPath = getPath;
    K.setPath = setPath;
})(typeof window !== "undefined" ? window : globalThis);
