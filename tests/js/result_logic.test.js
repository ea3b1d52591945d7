// A ballbar result's opening (static/js/kincomp_result_logic.js): the verdict line with its
// reason and advice, the numbers that decide it per test, the servo mismatch that Apply does
// not compensate said so, and the parameters Apply sets, now -> after (issue 35).
"use strict";
const test = require("node:test");
const assert = require("node:assert/strict");
const {load} = require("./harness.js");

const plain = (value) => JSON.parse(JSON.stringify(value));
const R = () => load("kincomp_common.js", "kincomp_findings.js", "kincomp_result_logic.js").KinComp.Result;

const DIAG = {
    plane: "XY", axes: {a: "X", b: "Y"},
    squareness_um_per_m: -3637.99, scale_mismatch_ppm: -738.14, servo_mismatch_ms: 0.62027,
    backlash_um: {a_plus: 14.28, a_minus: 27.6, b_plus: 9.52, b_minus: 7.09},
    uncertainty: {squareness_um_per_m: 0.64, scale_mismatch_ppm: 0.9, servo_mismatch_ms: 0.0035,
                  backlash_um: {a_plus: 0.077, a_minus: 0.084, b_plus: 0.085, b_minus: 0.085}},
};
const NOW = {squareness_um_per_m: {xy: 0, xz: 0, yz: 0}, scale_ppm: {x: 0, y: 0, z: 0},
             backlash: {x: 0, y: 0, z: 0}, servo_lag_ms: {x: 0, y: 0, z: 0}, servo_precomp: false};
const AFTER = {squareness_um_per_m: {xy: -3637.99, xz: 0, yz: 0}, scale_ppm: {x: -369.07, y: 369.07, z: 0},
               backlash: {x: [{at_mm: 70, um: 27.6}, {at_mm: 150, um: 14.28}], y: 0, z: 0},
               servo_lag_ms: {x: 0.62, y: 0, z: 0}, servo_precomp: false};

test("the verdict: the server's decision, its reason and the worst finding's advice", () => {
    const r = R();
    const run = {
        verdict: {decision: "apply_with_care", reason: {text: "XY: it moved.", template: "%(p)s: it moved.", params: {p: "XY"}}},
        findings: [{severity: "warning", message: "XY: it moved.", advice: {text: "Repeat the test."}},
                   {severity: "info", message: "a note", advice: {text: "Nothing."}}],
    };
    const v = plain(r.verdictView(run));
    assert.equal(v.title, "Apply with care");
    assert.equal(v.css, "alert-warning");
    assert.equal(v.reason, "XY: it moved.");
    assert.equal(v.advice, "Repeat the test.");
    const ok = plain(r.verdictView({verdict: {decision: "apply", reason: null}, findings: []}));
    assert.equal(ok.title, "Apply");
    assert.ok(ok.reason.length > 0 && ok.advice === "");
    // a run stored before verdicts: from its trust
    assert.equal(r.verdictView({trusted: false, findings: []}).decision, "do_not_apply");
    assert.equal(r.verdictView(null), null);
});

test("the numbers that decide a test: per plane, with their sigma, backlash by axis and side", () => {
    const rows = plain(R().decisionRows([{diag: DIAG}]));
    assert.equal(rows.length, 1);
    const row = rows[0];
    assert.equal(row.title, "XY");
    assert.equal(row.squareness, "-3638.0 ± 0.6");
    assert.equal(row.mismatch, "-738.1 ± 0.9");
    assert.equal(row.mismatchAxes, "X−Y");
    assert.equal(row.backlash, "+X 14.3, −X 27.6, +Y 9.5, −Y 7.1");
    assert.equal(row.backlashSigma, "± 0.1");
    assert.equal(row.servo, "0.620 ± 0.004");
    // an XZ test without a sigma: its own axes, the values alone
    const xz = plain(R().decisionRows([{diag: {plane: "XZ", squareness_um_per_m: 800, backlash_um: {a_plus: 3}}}]))[0];
    assert.equal(xz.squareness, "800.0");
    assert.equal(xz.backlash, "+X 3.0");
    assert.equal(xz.mismatch, "–");
});

test("a campaign's tests: joint values in place, a second XY named by its feed and height", () => {
    const analysis = {diagnostics: {traces: [
        {plane: "XY", feed_mm_min: 1850, centre: [100, 100, 10], squareness_um_per_m: 1, joint: {squareness_um_per_m: 2}},
        {plane: "XZ", feed_mm_min: 200, centre: [100, 100, 60], squareness_um_per_m: 3},
        {plane: "XY", feed_mm_min: 3700, centre: [100, 100, 10], squareness_um_per_m: 4},
    ]}};
    const tests = R().campaignTests(analysis);
    assert.deepEqual(plain(tests.map((t) => t.title)), ["XY at 1850 mm/min, Z 10 mm", "XZ", "XY at 3700 mm/min, Z 10 mm"]);
    assert.equal(tests[0].diag.squareness_um_per_m, 2);
    assert.deepEqual(plain(R().campaignTests(null)), []);
});

test("a servo mismatch that Apply does not compensate is said so, with why", () => {
    const r = R();
    const note = r.servoNote(AFTER, 0.62027);
    assert.match(note, /0\.620 ms\) is not compensated/);
    assert.match(note, /second feed/);
    assert.match(r.servoNote(AFTER, 0.3, "XY ran at one feed only."), /XY ran at one feed only\.$/);
    assert.equal(r.servoNote(Object.assign({}, AFTER, {servo_precomp: true}), 0.62), null);
    assert.equal(r.servoNote(AFTER, null), null);
});

test("Apply's parameters: now -> after, only what changes unless all are asked for", () => {
    const r = R();
    const rows = plain(r.applyRows(NOW, AFTER));
    assert.deepEqual(rows.map((x) => x.label), ["Squareness XY", "Scale X", "Scale Y", "Backlash X"]);
    assert.deepEqual(rows[0], {label: "Squareness XY", unit: "µm/m", now: "0.0", after: "-3638.0", changes: true});
    assert.equal(rows[3].after, "27.6 at 70 mm, 14.3 at 150 mm");
    assert.equal(rows[3].now, "0.0");
    // no servo lag rows while pre-compensation stays off; its switch when it changes
    const all = plain(r.applyRows(NOW, AFTER, true));
    assert.equal(all.length, 9);
    assert.ok(!all.some((x) => x.label.startsWith("Servo")));
    const on = plain(r.applyRows(NOW, Object.assign({}, AFTER, {servo_precomp: true})));
    assert.deepEqual(on.slice(-2).map((x) => [x.label, x.now, x.after]),
                     [["Servo lag X", "0.000", "0.620"], ["Servo pre-compensation", "off", "on"]]);
    assert.deepEqual(plain(r.applyRows(NOW, null)), []);
});

test("a stored date is shown as a local date and time, not ISO text", () => {
    const t = R().when("2026-11-27T16:38:05");
    assert.match(t, /^2026-11-27 16:38$/);
    assert.equal(R().when(""), "");
});

test("a campaign test's pause: mount or unmount, also after OctoPrint's Restart", () => {
    const C = load("kincomp_common.js", "kincomp_findings.js", "kincomp_result_logic.js", "kincomp_campaign_draw.js").KinComp.campaign;
    // restarted from the top (no resume since): the mount pause, whatever was printed before
    assert.equal(C.pauseKind(0, 3), "mount");
    assert.equal(C.pauseKind(0, 97), "mount");
    assert.equal(C.pauseKind(1, 97), "unmount");
    // the page loaded during the print: by how far the file is printed
    assert.equal(C.pauseKind(null, 2), "mount");
    assert.equal(C.pauseKind(null, 96), "unmount");
});

test("a campaign's drawing: tests that meet on one spot share one label, not '34'", () => {
    const C = load("kincomp_common.js", "kincomp_findings.js", "kincomp_result_logic.js", "kincomp_campaign_draw.js").KinComp.campaign;
    const xy = (n, feed) => ({n: n, plane: "XY", centre: [100, 100, 10], radius_mm: 50, feed_mm_min: feed,
                              spec: {capture_deg: 360, overshoot_deg: 10}});
    const xz = {n: 2, plane: "XZ", centre: [100, 100, 38], radius_mm: 50, spec: {capture_deg: 220, start_deg: -20}};
    const yz = {n: 3, plane: "YZ", centre: [100, 100, 38], radius_mm: 50, spec: {capture_deg: 220, start_deg: -20}};
    const views = C.views([0, 200, 0, 200, 0, 200], [xy(1, 1850), xz, yz, xy(4, 3700)], null);
    const labels = (v) => JSON.parse(JSON.stringify(v.paths.map((p) => p.label).filter((l) => l)));
    // from the top: the XY circles (1 and 4) and the YZ line (3) meet at the top; XZ apart
    assert.deepEqual(labels(views[0]).sort(), ["1, 3, 4", "2"]);
    // every label stands alone: no two closer than a label's width
    for (const v of views) {
        const shown = v.paths.filter((p) => p.label);
        for (const a of shown) for (const b of shown) {
            if (a === b) continue;
            assert.ok(Math.hypot(a.lx - b.lx, a.ly - b.ly) > 200 * 0.04, JSON.stringify([a.label, b.label]));
        }
    }
});

test("a campaign's test in words, as the server words it, not its plan key ('xy-f3700')", () => {
    const C = load("kincomp_common.js", "kincomp_findings.js", "kincomp_result_logic.js", "kincomp_campaign_draw.js").KinComp.campaign;
    // (the server's step.test: as_dict(test_words(name)))
    assert.equal(C.testName({name: "xy", plane: "XY", test: {text: "XY"}}), "XY");
    const f = {text: "XY at 3700 mm/min", template: "%(plane)s at %(feed)s mm/min", params: {plane: "XY", feed: "3700"}};
    assert.equal(C.testName({name: "xy-f3700", plane: "XY", test: f}), "XY at 3700 mm/min");
    const z = {text: "XY at Z 110 mm", template: "%(plane)s at Z %(z)s mm", params: {plane: "XY", z: "110"}};
    assert.equal(C.testName({name: "xy-z110", plane: "XY", test: z}), "XY at Z 110 mm");
    assert.equal(C.testName({name: "xy-f3700", plane: "XY"}), "XY");  // (no words: its plane)
});

test("what Apply did is said for the run it applied only, and a running print is named", () => {
    const w = load("kincomp_common.js");
    const shown = w.ko.observable({id: "r1"});
    const note = w.KinComp.appliedNote(shown);
    assert.equal(note(), "");
    note.said("r1", {compensation: {}}, "Parameters applied; compensation is on.");
    assert.equal(note(), "Parameters applied; compensation is on.");
    shown({id: "r2"});
    assert.equal(note(), "");  // (another run on the page)
    note.said("r2", {compensation: {pending_params_hash: "abc"}}, "applied");
    assert.match(note(), /a print is running/);
});
