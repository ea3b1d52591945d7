"""The print's line rate under each kind of load KinComp adds, on a real server (issue 37,
row 6), and under OctoPrint's own ``/api/version`` for comparison.

A real ``octoprint serve`` (``DevServer``: the virtual printer, throttle off, compensation on)
streams a long print of short moves (``tests/support/line_rate.py``: its ``Send:`` rate in
serial.log is the figure); each load runs in short phases alternated with quiet ones, each
loaded phase compared with its quiet neighbours (the machine is shared: its speed drifts),
the median ratio is the load's. Loads (4 clients each, every one on its own keep-alive
connection; a client waits as a ``202``'s or ``429``'s ``Retry-After`` says, as KinComp's
page does, and polls the job of a 202 until it is done):

* ``read /status``, ``read /runs``, ``read /campaigns``, ``read /sensor/status``,
  ``OctoPrint /api/version``: each client asks again as soon as it has its answer (a tight
  loop) - the last one is OctoPrint's own cheapest read, what any request costs;
* ``trace uploads`` (a 590 kB XY trace to ``/trace``), ``typed summaries`` (``/analyze``),
  ``artifact analyses`` (``/artifact/analyze``, caliper readings of KinComp's artifact),
  ``campaign joint analyses`` (``/campaigns/<id>/analyze``, each client its own campaign of
  three tests), ``dry runs`` (a read-only user's ``/dryrun`` of 15 MB files).

    PYTHONPATH=$PWD .venv/bin/python scripts/load_probe.py [--rounds 3] [--phase 4]
        [--only "read /status,dry runs"] [--json out.json]

Prints one line per load: requests, the answers' statuses, the phases' rates (lines/s,
quiet and loaded alternating), the ratios and their median, and whether it keeps 80 %.
The figures are in docs/reliability.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

from octoprint_kincomp.tools.devserver import USER_FLAGS, DevServer
from tests.support import line_rate as lr

BASE = "/plugin/kincomp"
SKEW = {"squareness_um_per_m": {"xy": 1500.0, "xz": 1200.0, "yz": -900.0}}
PRINT = "kc-probe-print.gcode"
BIG = [f"kc-probe-big-{i}.gcode" for i in range(3)]
SUMMARY = {
    "plane": "XY",
    "squareness_um_per_m": 120.0,
    "scale_mismatch_ppm": 40.0,
    "backlash_a_plus": 10.0,
    "backlash_a_minus": 12.0,
}


def _trace(spec=None, params_hash=None) -> bytes:
    from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
    from octoprint_kincomp.simulator.printer import simulate_program, volume_truth

    text = generate(TestSpec(**(spec or {})), params_hash=params_hash)
    spec, prog_hash = spec_from_program(text)
    return simulate_program(text, volume_truth(noise_um=0.5), spec, prog_hash).to_text().encode()


def _ok(code, body, what):
    if code != 200:
        raise RuntimeError(f"{what}: {code} {body}")
    return body


def _until_done(load, client, code, body, headers):
    """After an analysis request: polls its job (a 202) until it is done, as the page does
    (a 429 on the poll: asked again when it says); the wait before the next request."""
    load.count(code)
    if code != 202 or not (body and body.get("job")):
        return lr.retry_after(code, headers)
    job_id, wait = body["job"]["id"], lr.retry_after(code, headers)
    while not load.stopping:
        load.pause(wait)
        code, body, headers = client.request("GET", f"{BASE}/jobs/{job_id}")
        load.count(code)
        if code == 200 and body["job"]["state"] in ("done", "failed"):
            break
        if code not in (200, 429):
            break
        wait = lr.retry_after(code, headers, 1.0) or 1.0
    return 0.0


def read_load(name, path, key="admin"):
    def step(load, client, k):
        code, _, headers = client.request("GET", path)
        load.count(code)
        return lr.retry_after(code, headers)

    return lr.Load(name, step, key=key)


def setup_campaigns(srv, n):
    """``n`` campaigns (XY, XZ, YZ at 50 mm), every test measured: what a joint analysis
    takes."""
    client = lr.Client(srv)
    ids = []
    for _ in range(n):
        doc = _ok(*client.request("POST", f"{BASE}/campaign/plan", {"radius_xy": 50})[:2], "plan")
        for step in doc["steps"]:
            data = _trace(step["spec"], doc["params_hash"])
            code, body, _ = client.upload(
                f"{BASE}/campaigns/{doc['id']}/steps/{step['n']}/trace", step["name"] + ".csv", data
            )
            while code == 202:
                time.sleep(1)
                code, body, _ = client.request("GET", f"{BASE}/jobs/{body['job']['id']}")
                code = 202 if body["job"]["state"] not in ("done", "failed") else code
            _ok(code, body, "a campaign test")
        ids.append(doc["id"])
    client.close()
    return ids


def setup_artifact(srv):
    """KinComp's artifact program in the storage and readings of it (simulated)."""
    import numpy as np

    from octoprint_kincomp.calibration.artifact.program import read_measurements
    from octoprint_kincomp.core.params import Params
    from octoprint_kincomp.simulator.artifact import simulate_readings

    client = lr.Client(srv)
    out = _ok(
        *client.request("POST", f"{BASE}/artifact/program", {"planes": ["XY", "XZ"]})[:2],
        "artifact program",
    )
    with open(os.path.join(srv.basedir, "uploads", out["path"]), encoding="utf-8") as f:
        text = f.read()
    truth = Params.from_dict({"squareness_um_per_m": {"xy": 800.0, "xz": -500.0}})
    readings = simulate_readings(read_measurements(text), truth, rng=np.random.default_rng(4))
    client.close()
    return out["path"], readings


def loads(srv, only=None):
    """The loads, in the order they run (reads first: the analyses add runs)."""
    trace = _trace()
    made = {}

    def analysis(name, request, clients=4):
        def step(load, client, k):
            return _until_done(load, client, *request(client, k))

        return lr.Load(name, step, clients=clients)

    def joint(client, k):
        if "campaigns" not in made:
            raise RuntimeError("no campaigns")
        return client.request("POST", f"{BASE}/campaigns/{made['campaigns'][k]}/analyze", {})

    def artifact(client, k):
        path, readings = made["artifact"]
        return client.request(
            "POST", f"{BASE}/artifact/analyze", {"path": path, "readings": readings}
        )

    def dryrun(load, client, k):
        code, _, headers = client.request("GET", f"{BASE}/dryrun?path={BIG[k % 3]}")
        load.count(code)
        return {200: 0.05}.get(code, lr.retry_after(code, headers))

    every = [
        read_load("read /status", f"{BASE}/status"),
        read_load("read /runs", f"{BASE}/runs"),
        read_load("read /campaigns", f"{BASE}/campaigns"),
        read_load("read /sensor/status", f"{BASE}/sensor/status"),
        read_load("OctoPrint /api/version", "/api/version"),
        analysis("trace uploads", lambda c, k: c.upload(f"{BASE}/trace", "probe.csv", trace)),
        analysis(
            "typed summaries",
            lambda c, k: c.request("POST", f"{BASE}/analyze", {"summary": SUMMARY}),
        ),
        analysis("artifact analyses", artifact),
        analysis("campaign joint analyses", joint),
        lr.Load("dry runs", dryrun, key="reader"),
    ]
    chosen = [ld for ld in every if only is None or ld.name in only]
    names = {ld.name for ld in chosen}
    if "campaign joint analyses" in names:
        made["campaigns"] = setup_campaigns(srv, 4)
    if "artifact analyses" in names:
        made["artifact"] = setup_artifact(srv)
    return chosen


def prepare_files(srv, print_lines):
    uploads = os.path.join(srv.basedir, "uploads")
    for name in BIG:  # ~15 MB each, straight into the storage (no upload analysis)
        lr.big_gcode(os.path.join(uploads, name), 300_000)
    lr.fast_print(os.path.join(uploads, PRINT), print_lines)


def history(srv, runs):
    """A history of ``runs`` typed summaries (what /runs and the analyses read)."""
    client = lr.Client(srv)
    for _ in range(runs):
        code, body, _ = client.request("POST", f"{BASE}/analyze", {"summary": SUMMARY})
        while code == 202:
            time.sleep(1)
            code, body, _ = client.request("GET", f"{BASE}/jobs/{body['job']['id']}")
            code = 202 if body["job"]["state"] not in ("done", "failed") else code
        _ok(code, body, "a typed summary")
    client.close()


def drain(srv, timeout=600.0):
    """Waits until no KinComp job is queued or running (a load's jobs left over must not be
    the next load's), cancelling what is left after ``timeout`` seconds."""
    client = lr.Client(srv)
    deadline = time.time() + timeout
    try:
        while True:
            code, body, headers = client.request("GET", f"{BASE}/status")
            if code == 200:
                active = [j for j in body["jobs"] if j["state"] in ("queued", "running")]
                if not active:
                    return
                if time.time() > deadline:
                    for job in active:
                        client.request("POST", f"{BASE}/jobs/{job['id']}/cancel", {})
                    deadline = time.time() + 60
            time.sleep(lr.retry_after(code, headers) or 2.0)
    finally:
        client.close()


def measure(srv, load, log, rounds, phase_s):
    drain(srv)
    if lr.job_state(srv) != "Printing":
        lr.cancel_print(srv)
        lr.start_print(srv, PRINT)
        time.sleep(3.0)
    rates, ratios, median = lr.alternate(srv, load, log, rounds=rounds, phase_s=phase_s)
    assert lr.job_state(srv) == "Printing", "the print ended during the measurement"
    return {
        "load": load.name,
        "requests": load.requests(),
        "codes": {str(c): n for c, n in sorted(load.codes.items())},
        "server_errors": load.server_errors(),
        "rates": [round(r) for r in rates],
        "ratios": [round(r, 3) for r in ratios],
        "median": round(median, 3),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--phase", type=float, default=4.0, help="seconds a phase")
    ap.add_argument("--only", help="comma-separated load names")
    ap.add_argument("--runs", type=int, default=20, help="runs in the history before")
    ap.add_argument("--print-lines", type=int, default=3_000_000)
    ap.add_argument("--json", help="write the figures here too")
    ap.add_argument("--basedir", help="the server's basedir (default: a temporary one)")
    args = ap.parse_args(argv)
    only = set(args.only.split(",")) if args.only else None
    base = args.basedir or tempfile.mkdtemp(prefix="kc-load-probe-")
    srv = DevServer(
        os.path.join(base, "op"),
        kincomp={"enabled": False},
        throttle=0.0,
        users=tuple(USER_FLAGS),
    )
    srv.start()
    results = []
    try:
        srv.connect()
        prepare_files(srv, args.print_lines)
        # compensation on from the start: a campaign is measured with the parameters in force
        _ok(
            *srv.request(
                "POST", f"{BASE}/settings", {"enabled": True, "params": SKEW, "apply_now": True}
            ),
            "settings",
        )
        history(srv, args.runs)
        chosen = loads(srv, only)
        log = lr.SendLog(srv)
        for load in chosen:
            res = measure(srv, load, log, args.rounds, args.phase)
            results.append(res)
            print(
                f"{res['load']:26s} {res['requests']:6d} req {res['codes']}  "
                f"rates {res['rates']}  ratios {res['ratios']}  median {res['median']:.0%}  "
                f"{'ok' if res['median'] >= 0.8 else 'BELOW 80 %'}",
                flush=True,
            )
    finally:
        try:
            lr.cancel_print(srv)
        except Exception:
            pass
        srv.stop()
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"when": time.strftime("%Y-%m-%d %H:%M"), "results": results}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
