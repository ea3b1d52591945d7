// The printed artifact's logic (static/js/kincomp_artifact_logic.js): the reading fields a
// program asks for, the readings read back, the verdict line, the values that decide a
// result and the parameters Apply sets (issue 35).
"use strict";
const test = require("node:test");
const assert = require("node:assert/strict");
const {load} = require("./harness.js");

const plain = (value) => JSON.parse(JSON.stringify(value));
const A = () => load("kincomp_common.js", "kincomp_artifact_logic.js").KinComp.Artifact;

const RUN = {
    verdict: {decision: "apply_with_care", reason: {text: "XZ1-out was left out.", template: "%(id)s was left out.", params: {id: "XZ1-out"}}},
    trusted: true,
    params_before: {squareness_um_per_m: {xy: -3000, xz: 0, yz: 0}, scale_ppm: {x: 0, y: 0, z: 0}},
    proposed: {squareness_um_per_m: {xy: -3640.2, xz: 812.5, yz: 0}, scale_ppm: {x: -450.4, y: 288.1, z: 162.3}},
    diagnostics: {
        squareness_um_per_m: {xy: -640.2, xz: 812.5, yz: null},
        scale_mismatch_ppm: {"x-y": -738.5, "x-z": -612.7, "y-z": 125.8},
        line_width_mm: {vertical_walls: 0.451, slanted_walls: 0.449},
        uncertainty: {
            squareness_um_per_m: {xy: 81.2, xz: 120.4, yz: null},
            scale_mismatch_ppm: {"x-y": 160.1, "x-z": 140.2, "y-z": 140.9},
            line_width_mm: {vertical_walls: 0.006, slanted_walls: 0.007},
        },
    },
};

test("a program asks for one reading per measurement (quick) or three (full)", () => {
    const a = A();
    assert.equal(a.fieldsFor({repeats: "1"}), 1);
    assert.equal(a.fieldsFor({repeats: "3"}), 3);
    assert.equal(a.fieldsFor({}), 3);  // a program written before the header said so
    assert.equal(a.fieldsFor({repeats: "9"}), 3);
    assert.deepEqual(plain(a.fieldTexts([146.51], 3)), ["146.51", "", ""]);
});

test("the readings: empty fields are not measured, a comma is a decimal point", () => {
    const got = A().readingsOf([
        {id: "A1-out", fields: ["147.45", " ", "147,46"]},
        {id: "A1-in", fields: ["", "", ""]},
    ]);
    assert.deepEqual(plain(got), {readings: {"A1-out": [147.45, 147.46]}});
});

test("a field that is no length names its measurement and reading", () => {
    const got = A().readingsOf([{id: "X1-out", fields: ["147.4", "abc"]}, {id: "Y1-in", fields: ["-1"]}]);
    assert.equal(got.error, "Reading 2 of X1-out is not a length in mm");
    assert.deepEqual(plain(got.field), {id: "X1-out", k: 2});  // (the form marks it)
});

test("the verdict line: decision and the reason in plain words", () => {
    const a = A();
    const v = a.verdictView(RUN);
    assert.equal(v.title, "Apply with care");
    assert.equal(v.css, "alert-warning");
    assert.equal(v.reason, "XZ1-out was left out.");
    const ok = a.verdictView({verdict: {decision: "apply", reason: null}});
    assert.equal(ok.title, "Apply");
    assert.ok(ok.reason.length > 10);
    const bad = a.verdictView({verdict: {decision: "do_not_apply", reason: "Swapped?"}});
    assert.equal(bad.css, "alert-error");
    assert.equal(bad.reason, "Swapped?");
    // a run stored before verdicts: from its trust
    assert.equal(a.verdictView({trusted: false}).decision, "do_not_apply");
    assert.equal(a.verdictView(null), null);
});

test("the values that decide it: squareness and mismatch with their sigma", () => {
    const rows = plain(A().valueRows(RUN));
    assert.deepEqual(rows.map((r) => r.label), [
        "Squareness XY", "Squareness XZ", "Squareness YZ",
        "Scale mismatch X-Y", "Scale mismatch X-Z", "Scale mismatch Y-Z",
    ]);
    assert.deepEqual([rows[0].value, rows[0].sigma, rows[0].unit], ["-640.2", "± 81.2", "µm/m"]);
    assert.deepEqual([rows[2].value, rows[2].sigma], ["not separated", "–"]);
    assert.equal(rows[3].unit, "ppm");
});

test("Apply's parameters: now and after, those that stay marked", () => {
    const rows = plain(A().applyRows(RUN));
    assert.deepEqual(rows.map((r) => [r.label, r.now, r.after, r.changes]), [
        ["Squareness XY", "-3000.0", "-3640.2", true],
        ["Squareness XZ", "0.0", "812.5", true],
        ["Squareness YZ", "0.0", "0.0", false],
        ["Scale X", "0.0", "-450.4", true],
        ["Scale Y", "0.0", "288.1", true],
        ["Scale Z", "0.0", "162.3", true],
    ]);
    assert.deepEqual(plain(A().applyRows({diagnostics: {}})), []);
});
