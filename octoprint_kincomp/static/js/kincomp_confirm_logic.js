/*
 * KinComp web UI: what the user confirms before a result KinComp cannot tie to a program it
 * printed is applied (a run's ``needs_confirmation``: {confirm: [keys], stated: {key: value}},
 * decided by the analysis, calibration/ballbar/provenance.py). Each key becomes one sentence
 * the user ticks; Apply then sends ``confirm`` with the stated values, as POST /apply asks.
 *
 * No DOM here: the tab binds it (kincomp_tab.js); node's unit tests run it
 * (tests/js/confirm.test.js).
 */
(function (root) {
    "use strict";
    var K = root.KinComp = root.KinComp || {};
    var _ = root._;

    var fmt = function (v) {
        var n = Number(v);
        return isFinite(n) ? String(Math.round(n * 1000) / 1000) : String(v);
    };

    // one sentence per key the analysis asks to confirm (the data cannot check it)
    var SENTENCES = {
        plane: function (v) {
            return _.sprintf(gettext("The test ran in the %(plane)s plane."), {plane: String(v).toUpperCase()});
        },
        radius_mm: function (v) {
            return _.sprintf(gettext("Its circle had a radius of %(radius)s mm."), {radius: fmt(v)});
        },
        feed_mm_min: function (v) {
            return _.sprintf(gettext("It ran at a feed of %(feed)s mm/min, at 100 %% speed."), {feed: fmt(v)});
        },
        sensor: function () {
            return gettext("The sensor reads a longer bar as a larger value, at its true scale (checked against a known step).");
        },
        firmware_compensation: function () {
            return gettext("The firmware compensated nothing itself during the test (no skew, backlash or axis scale correction of its own).");
        }
    };

    // [{key, text}] for the run's needs_confirmation (empty when there is nothing to confirm)
    var rows = function (need) {
        if (!need || !_.isArray(need.confirm)) return [];
        var stated = need.stated || {};
        return _.map(need.confirm, function (key) {
            var say = SENTENCES[key];
            var text = say ? say(stated[key])
                : _.sprintf(gettext("%(what)s: %(value)s"), {what: key, value: String(stated[key])});
            return {key: key, text: text};
        });
    };

    // the ``confirm`` object of POST /apply once every row is ticked (``ticked``: {key: bool});
    // null while one is not
    var body = function (need, ticked) {
        var list = rows(need);
        if (!list.length) return null;
        var all = _.every(list, function (r) { return !!(ticked || {})[r.key]; });
        return all ? _.pick(need.stated || {}, need.confirm) : null;
    };

    K.Confirmation = {rows: rows, body: body};
})(window);
