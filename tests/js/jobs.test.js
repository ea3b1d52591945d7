// An analysis's answer (static/js/kincomp_jobs.js): a 200 is its result; a 202 {job} is
// polled (GET /jobs/<id>) until the job is done, its result (the run id) then loaded as the
// route's 200 would bring it; a failed job fails like a 400; a 429 of a poll waits as told.
// For every route that may answer 202: /trace and /analyze, a campaign test's trace, a
// campaign's joint analysis, a printed artifact's readings.
"use strict";
const test = require("node:test");
const assert = require("node:assert/strict");
const {load} = require("./harness.js");

// a minimal jQuery-like Deferred: done/fail/always, resolve/reject, promise
function Deferred() {
    let state = "pending", args = [];
    const cbs = {done: [], fail: [], always: []};
    const settle = (s, a) => {
        if (state !== "pending") return;
        state = s;
        args = a;
        for (const f of cbs[s]) f(...a);
        for (const f of cbs.always) f(...a);
    };
    const d = {
        done(f) { if (state === "done") f(...args); else if (state === "pending") cbs.done.push(f); return d; },
        fail(f) { if (state === "fail") f(...args); else if (state === "pending") cbs.fail.push(f); return d; },
        always(f) { if (state !== "pending") f(...args); else cbs.always.push(f); return d; },
        resolve(...a) { settle("done", a); return d; },
        reject(...a) { settle("fail", a); return d; },
        promise() { return d; },
        state: () => state,
    };
    return d;
}

// an XMLHttpRequest-like answer object
const xhr = (status, headers = {}) => ({
    status,
    getResponseHeader: (name) => (name in headers ? String(headers[name]) : null),
});

// the page's means, faked: GET answers from ``routes`` (path -> list of [status, body,
// headers], one taken per request), timers run at once and are recorded
function env(routes) {
    const asked = [], waits = [];
    return {
        asked, waits, Deferred,
        get(path) {
            asked.push(path);
            const queue = routes[path];
            assert.ok(queue && queue.length, "unexpected GET " + path);
            const [status, body, headers] = queue.shift();
            const d = Deferred();
            if (status < 300) d.resolve(body, "success", xhr(status, headers));
            else d.reject(Object.assign(xhr(status, headers), {responseJSON: body}));
            return d;
        },
        later(fn, ms) { waits.push(ms); fn(); },
    };
}

const K = () => load("kincomp_common.js", "kincomp_jobs.js").KinComp;
const plain = (v) => JSON.parse(JSON.stringify(v));
const RUN = {id: "20261201-120000-abcdef", source: "upload"};
const JOB = (state, result, error) => ({job: {id: "j1", state, result: result || null, error: error || null}});

function outcome(d) {
    let got;
    d.done((v) => { got = {ok: plain(v)}; }).fail((e) => { got = {failed: e}; });
    return got;
}

test("a 200 is the result itself, nothing polled", () => {
    const k = K(), e = env({});
    const req = Deferred().resolve(RUN, "success", xhr(200));
    assert.deepEqual(outcome(k.afterJob(req, k.loadRun, {}, e)), {ok: RUN});
    assert.deepEqual(e.asked, []);
});

test("a 202 is polled once a second until done, then its run is loaded", () => {
    const k = K();
    const e = env({
        "jobs/j1": [[200, JOB("queued")], [200, JOB("running")], [200, JOB("done", RUN.id)]],
        ["runs/" + RUN.id]: [[200, RUN]],
    });
    const req = Deferred().resolve(JOB("queued"), "accepted", xhr(202, {"Retry-After": 1}));
    assert.deepEqual(outcome(k.afterJob(req, k.loadRun, {}, e)), {ok: RUN});
    assert.deepEqual(e.asked, ["jobs/j1", "jobs/j1", "jobs/j1", "runs/" + RUN.id]);
    assert.deepEqual(e.waits, [1000, 1000, 1000]);
});

test("an upload's answer (one array: body, status, request) is read the same", () => {
    const k = K();
    const e = env({"jobs/j1": [[200, JOB("done", RUN.id)]], ["runs/" + RUN.id]: [[200, RUN]]});
    const upload = Deferred().resolve([JOB("running"), "success", xhr(202)]);
    assert.deepEqual(outcome(k.afterJob(upload, k.loadRun, {}, e)), {ok: RUN});
    const done = Deferred().resolve([RUN, "success", xhr(200)]);
    assert.deepEqual(outcome(k.afterJob(done, k.loadRun, {}, env({}))), {ok: RUN});
    const refused = Deferred().reject([Object.assign(xhr(413), {response: '{"error": "too large"}'}), "error"]);
    const got = outcome(k.afterJob(refused, k.loadRun, {}, env({})));
    assert.equal(got.failed.status, 413);
    assert.equal(k.errorText(got.failed), "too large");
});

test("a failed job fails as its 400 would, with the job's error", () => {
    const k = K();
    const e = env({"jobs/j1": [[200, JOB("failed", null, "t.csv: not a trace")]]});
    const req = Deferred().resolve(JOB("queued"), "accepted", xhr(202));
    const got = outcome(k.afterJob(req, k.loadRun, {}, e));
    assert.equal(got.failed.status, 400);
    assert.equal(k.errorText(got.failed), "t.csv: not a trace");
});

test("a poll refused with 429 (reads rationed during a print) waits as told and goes on", () => {
    const k = K();
    const e = env({
        "jobs/j1": [[429, {error: "ask again"}, {"Retry-After": 3}], [200, JOB("done", RUN.id)]],
        ["runs/" + RUN.id]: [[200, RUN]],
    });
    const req = Deferred().resolve(JOB("queued"), "accepted", xhr(202));
    assert.deepEqual(outcome(k.afterJob(req, k.loadRun, {}, e)), {ok: RUN});
    assert.deepEqual(e.waits, [1000, 3000]);
    const gone = env({"jobs/j1": [[404, {error: "No such job"}]]});
    const got = outcome(k.afterJob(Deferred().resolve(JOB("queued"), "", xhr(202)), k.loadRun, {}, gone));
    assert.equal(got.failed.status, 404);
});

test("a campaign test's 202 ends with {campaign, run}, a joint analysis's with the campaign", () => {
    const k = K();
    const CAMPAIGN = {id: "c1", measured: 1};
    const e = env({
        "jobs/j1": [[200, JOB("done", RUN.id)], [200, JOB("done", "joint-run")]],
        "campaigns/c1": [[200, CAMPAIGN], [200, CAMPAIGN]],
        ["runs/" + RUN.id]: [[200, RUN]],
    });
    const step = k.afterJob(Deferred().resolve(JOB("queued"), "", xhr(202)), k.loadCampaignStep("c1"), {}, e);
    assert.deepEqual(outcome(step), {ok: {campaign: CAMPAIGN, run: RUN}});
    const joint = k.afterJob(Deferred().resolve(JOB("queued"), "", xhr(202)), k.loadCampaign("c1"), {}, e);
    assert.deepEqual(outcome(joint), {ok: CAMPAIGN});
    // a 200 of either is taken as it is
    const body = {campaign: CAMPAIGN, run: RUN};
    assert.deepEqual(outcome(k.afterJob(Deferred().resolve(body, "", xhr(200)), k.loadCampaignStep("c1"), {}, e)), {ok: body});
});

test("the job's progress is told at each poll", () => {
    const k = K();
    const e = env({"jobs/j1": [[200, {job: {id: "j1", state: "running", progress: 0.5}}], [200, JOB("done", RUN.id)]],
                   ["runs/" + RUN.id]: [[200, RUN]]});
    const seen = [];
    k.afterJob(Deferred().resolve(JOB("queued"), "", xhr(202)), k.loadRun, {progress: (j) => seen.push(j.state)}, e);
    assert.deepEqual(seen, ["queued", "running", "done"]);
});

// issue 35: a reload while a print runs asks for several things at once; the rationed
// server answers some with 429, which left the campaign panel empty ("Ask again in 2 s")
test("a rationed read is asked again as its Retry-After says, then answers as the request", () => {
    const kc = K();
    const e = env({"campaigns/c1": [
        [429, {error: "busy"}, {"Retry-After": 2}],
        [429, {error: "busy"}, {"Retry-After": 1}],
        [200, {id: "c1"}],
    ]});
    let got = null;
    kc.retrying(() => e.get("campaigns/c1"), e).done((body, status, x) => { got = [body, status, x.status]; });
    assert.deepEqual(got, [{id: "c1"}, "success", 200]);
    assert.deepEqual(e.waits, [2000, 1000]);
});

test("a read that fails otherwise, or stays rationed past its tries, fails as the request", () => {
    const kc = K();
    const e = env({"runs/x": [[404, {error: "no such run"}]],
                   "runs/y": [[429, {}, {"Retry-After": 1}], [429, {}, {"Retry-After": 1}]]});
    let failed = null;
    kc.retrying(() => e.get("runs/x"), e).fail((x) => { failed = x.status; });
    assert.equal(failed, 404);
    assert.deepEqual(e.waits, []);
    kc.retrying(() => e.get("runs/y"), e, 1).fail((x) => { failed = x.status; });
    assert.equal(failed, 429);
    assert.deepEqual(e.waits, [1000]);
});

test("K.get hands OctoPrint.get its options (the demo's trace is read as text)", () => {
    const win = load("kincomp_common.js", "kincomp_jobs.js");
    const seen = [];
    win.OctoPrint = {get: (url, opts) => { seen.push([url, opts]); const d = Deferred(); d.resolve("t,x\n", "success", xhr(200)); return d; }};
    win.$ = {Deferred};
    let got = null;
    win.KinComp.get("/plugin/kincomp/demo/trace", {dataType: "text"}).done((text) => { got = text; });
    assert.deepEqual(seen, [["/plugin/kincomp/demo/trace", {dataType: "text"}]]);
    assert.equal(got, "t,x\n");
});
