"""The whole calibration loop in demo mode on a real server, on the fallback path (demo's
live capture off; the live path is tests/e2e/test_live_capture.py): print the ballbar
program, fetch the SIMULATED trace, analyse, apply, re-test with compensation on."""

import time

import pytest

from tests.support.serverutil import settings, status

pytestmark = pytest.mark.slow

ZERO = {
    "squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}
PROGRAM = {"plane": "XY", "centre": [100, 100, 5], "radius": 60, "feed": 1850, "print": True}


def _ballbar_run(server):
    """Print the program, wait for the simulated trace, upload it; returns the run."""
    code, prog = server.request("POST", "/plugin/kincomp/program", PROGRAM)
    assert code == 200, prog
    assert prog["printing"] and prog["path"].startswith("kincomp/")
    server.wait_print_done(timeout=900)
    deadline = time.time() + 120
    while True:
        code, trace = server.request("GET", "/plugin/kincomp/demo/trace")
        if code == 200 and prog["program_hash"] in trace:
            break
        assert time.time() < deadline, (code, trace)
        time.sleep(0.5)
    assert "SIMULATED" in trace
    code, run = server.upload("/plugin/kincomp/trace", "simulated_trace.csv", trace.encode())
    assert code == 200, run
    assert run["simulated"] is True
    return run


def test_demo_calibrate_apply_retest(server):
    settings(server, enabled=False, params=ZERO, demo={"enabled": True, "live": False})
    try:
        assert status(server)["demo"] is True
        before = _ballbar_run(server)
        diag = before["diagnostics"]
        # the demo printer's hidden errors are the paper's Table 1 Ultimaker
        assert diag["squareness_um_per_m"] == pytest.approx(-3638, abs=60)
        code, applied = server.request(
            "POST", "/plugin/kincomp/apply", {"run": before["id"], "enabled": True}
        )
        assert code == 200, applied
        st = status(server)
        assert st["settings"]["enabled"] is True
        assert st["settings"]["params"]["squareness_um_per_m"] == pytest.approx(
            before["proposed"]["squareness_um_per_m"]
        )
        assert st["params_hash"] == applied["params_hash"]
        # re-test: the program is now compensated on the way out
        after = _ballbar_run(server)
        assert after["params_before_hash"] == applied["params_hash"]
        code, cmp = server.request(
            "GET", f"/plugin/kincomp/compare?before={before['id']}&after={after['id']}"
        )
        assert code == 200
        red = {r["key"]: r["reduction_pct"] for r in cmp["table"]}
        assert red["squareness_um_per_m"] > 90
        assert red["circularity_um.bidirectional"] > 90
        for side in ("a_plus", "a_minus", "b_plus", "b_minus"):
            assert red[f"backlash_um.{side}"] > 80
        code, runs = server.request("GET", "/plugin/kincomp/runs")
        ids = [r["id"] for r in runs["runs"]]
        assert before["id"] in ids and after["id"] in ids
        code, again = server.request("GET", f"/plugin/kincomp/runs/{before['id']}")
        assert code == 200 and again["applied"]
    finally:
        settings(server, demo={"enabled": False, "live": True}, params=ZERO, enabled=False)
