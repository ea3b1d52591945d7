// What the user confirms before applying a result KinComp cannot tie to a program it printed
// (static/js/kincomp_confirm_logic.js): one sentence per key the analysis asks for, and the
// /apply request's ``confirm`` only when every one is ticked.
"use strict";
const test = require("node:test");
const assert = require("node:assert/strict");
const {load} = require("./harness.js");

const C = () => load("kincomp_confirm_logic.js").KinComp.Confirmation;
const plain = (v) => JSON.parse(JSON.stringify(v));
const NEED = {
    confirm: ["plane", "radius_mm", "feed_mm_min", "sensor", "firmware_compensation"],
    stated: {plane: "XY", radius_mm: 100.0, feed_mm_min: 1850.0, sensor: "checked",
             firmware_compensation: "none", other: 1},
};

test("nothing to confirm: no rows, no confirm body", () => {
    const c = C();
    assert.deepEqual(plain(c.rows(null)), []);
    assert.deepEqual(plain(c.rows({confirm: [], stated: {}})), []);
    assert.equal(c.body(null, {}), null);
});

test("each key is one sentence in the user's words with the stated value", () => {
    const rows = plain(C().rows(NEED));
    assert.deepEqual(rows.map((r) => r.key), NEED.confirm);
    assert.match(rows[0].text, /XY plane/);
    assert.match(rows[1].text, /radius of 100 mm/);
    assert.match(rows[2].text, /feed of 1850 mm\/min/);
    assert.match(rows[3].text, /sensor/);
    assert.match(rows[4].text, /firmware compensated nothing/);
    for (const r of rows) assert.doesNotMatch(r.text, /_mm|_min|firmware_compensation/);
});

test("the confirm body only when every row is ticked, with exactly the asked keys", () => {
    const c = C();
    const ticked = {plane: true, radius_mm: true, feed_mm_min: true, sensor: true};
    assert.equal(c.body(NEED, ticked), null);
    ticked.firmware_compensation = true;
    assert.deepEqual(plain(c.body(NEED, ticked)), {
        plane: "XY", radius_mm: 100, feed_mm_min: 1850, sensor: "checked", firmware_compensation: "none",
    });
});

test("an unknown key is still shown (named), never dropped", () => {
    const rows = plain(C().rows({confirm: ["bar_length"], stated: {bar_length: 150}}));
    assert.equal(rows.length, 1);
    assert.match(rows[0].text, /bar_length: 150/);
});
