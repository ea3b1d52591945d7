// The settings page's plain fields (static/js/kincomp_settings_form.js): shown from a
// settings document, read back into one, untouched numbers kept exact.
"use strict";
const test = require("node:test");
const assert = require("node:assert/strict");
const {load} = require("./harness.js");

// (objects made inside the scripts' context have its prototypes: compared as JSON)
const plain = (value) => JSON.parse(JSON.stringify(value));

const FIELDS = [
    {path: "enabled", kind: "bool", label: "Compensate moves"},
    {path: "mode", kind: "choice", label: "Mode"},
    {path: "chord_tol_mm", kind: "number", label: "Arc chord tolerance"},
    {path: "steps_per_mm", kind: "optional_number", label: "Steps per mm (X/Y)"},
    {path: "demo.enabled", kind: "bool", label: "Demo mode"},
    {path: "params.scale_ppm.x", kind: "number", label: "X"},
];
const STORED = {
    enabled: true,
    mode: "on_upload",
    chord_tol_mm: 0.0123456,
    steps_per_mm: null,
    demo: {enabled: false, live: true},
    params: {scale_ppm: {x: 30.8903127, y: 1}},
};

function form() {
    const w = load("kincomp_common.js", "kincomp_settings_form.js");
    const f = new w.KinComp.SettingsForm(FIELDS);
    f.show(JSON.parse(JSON.stringify(STORED)));
    return {w, f};
}

test("fields show the stored values, numbers with at most 3 decimals", () => {
    const {f} = form();
    assert.equal(f.value.enabled(), true);
    assert.equal(f.value.mode(), "on_upload");
    assert.equal(f.value.chord_tol_mm(), "0.012");
    assert.equal(f.value.steps_per_mm(), "");
    assert.equal(f.value["demo.enabled"](), false);
    assert.equal(f.value["params.scale_ppm.x"](), "30.89");
});

test("an untouched form gives the stored values back exactly", () => {
    const {w, f} = form();
    const errors = {};
    const doc = f.collect({params: JSON.parse(JSON.stringify(STORED.params))}, errors, w.KinComp.num);
    assert.deepEqual(plain(errors), {});
    assert.equal(doc.chord_tol_mm, 0.0123456);
    assert.equal(doc.params.scale_ppm.x, 30.8903127);
    assert.equal(doc.params.scale_ppm.y, 1);
    assert.equal(doc.steps_per_mm, null);
    assert.deepEqual(plain(doc.demo), {enabled: false});
    const stored = f.stored({params: JSON.parse(JSON.stringify(STORED.params))});
    assert.equal(JSON.stringify(doc), JSON.stringify(stored));
});

test("typed values are read, a text that is no number is named by its path", () => {
    const {w, f} = form();
    f.value.chord_tol_mm("0,02");
    f.value.steps_per_mm(" 160 ");
    f.value["params.scale_ppm.x"]("abc");
    f.value["demo.enabled"](true);
    const errors = {};
    const doc = f.collect({params: {}}, errors, w.KinComp.num);
    assert.equal(doc.chord_tol_mm, 0.02);
    assert.equal(doc.steps_per_mm, 160);
    assert.equal(doc.demo.enabled, true);
    assert.deepEqual(plain(Object.keys(errors)), ["params.scale_ppm.x"]);
    assert.deepEqual(plain(f.paths), ["chord_tol_mm", "steps_per_mm", "params.scale_ppm.x"]);
    assert.equal(f.label("chord_tol_mm"), "Arc chord tolerance");
    assert.equal(f.label("nothing"), null);
});
