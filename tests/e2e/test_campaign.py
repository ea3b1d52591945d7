"""A campaign over the real server's HTTP API with measured files uploaded (no demo mode): the
plan on the printer profile's volume, every test's trace uploaded through OctoPrint's upload
handling (a vertical test's trace is over a megabyte), wrong files refused naming the file,
the permissions, the joint analysis and ONE apply (issue 12). And a demo campaign measured by
the live capture of the virtual bar, through the virtual printer's mount pauses (issue 15)."""

import time

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth
from tests.support import assert_applies_cleanly
from tests.support.serverutil import settings, status

pytestmark = pytest.mark.slow

ZERO = {
    "squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}
BASE = "/plugin/kincomp"


def _reset_params(server):
    """The whole parameter set back to none (a campaign's proposal also sets servo lags,
    servo pre-compensation and the backlash fraction, which a partial update keeps)."""
    code, resp = server.request(
        "POST", f"{BASE}/apply", {"params": Params().to_dict(), "enabled": False, "apply_now": True}
    )
    assert code == 200, resp


def _trace(doc, n):
    """Test n's trace as a ballbar on the paper-like printer would record it (SIMULATED)."""
    step = doc["steps"][n - 1]
    text = generate(TestSpec(**step["spec"]), params_hash=doc["params_hash"])
    spec, prog_hash = spec_from_program(text)
    return simulate_program(text, volume_truth(noise_um=0.5), spec, prog_hash).to_text()


def test_a_campaign_of_uploaded_traces_over_the_api(server):
    settings(server, enabled=False, params=ZERO, demo={"enabled": False})
    try:
        code, resp = server.request("POST", f"{BASE}/campaign/plan", {"radius_xy": "50"})
        assert code == 400 and "radius_xy" in resp["error"]
        for user in ("viewer", "settingsonly"):  # no KinComp admin permission
            code, resp = server.request(
                "POST", f"{BASE}/campaign/plan", {"radius_xy": 50}, key=user
            )
            assert code == 403
        code, doc = server.request("POST", f"{BASE}/campaign/plan", {"radius_xy": 50})
        assert code == 200, doc
        cid = doc["id"]
        assert [s["name"] for s in doc["steps"]] == ["xy", "xz", "yz"]
        # the default profile's Z moves at 200 mm/min at most: the vertical tests too
        assert doc["steps"][1]["feed_mm_min"] == 200.0
        code, listed = server.request("GET", f"{BASE}/campaigns", key="settingsonly")
        assert code == 200 and listed["campaigns"][0]["id"] == cid
        traces = {n: _trace(doc, n) for n in (1, 2, 3)}
        assert len(traces[2]) > 1_000_000  # beyond OctoPrint's default body size
        code, resp = server.upload(
            f"{BASE}/campaigns/{cid}/steps/3/trace", "xy.csv", traces[1].encode()
        )
        assert code == 400 and resp["error"].startswith(
            "xy.csv: it is the trace of test XY, not of test 3 (YZ)"
        )
        for n, name in ((1, "xy.csv"), (2, "xz.csv")):
            code, resp = server.upload(
                f"{BASE}/campaigns/{cid}/steps/{n}/trace", name, traces[n].encode()
            )
            assert code == 200, resp
        assert resp["campaign"]["measured"] == 2 and resp["run"]["filename"] == "xz.csv"
        code, resp = server.request("POST", f"{BASE}/campaigns/{cid}/analyze", {})
        assert code == 400 and "test 3 (YZ" in resp["error"]
        # the parameters changed mid-campaign: it cannot go on
        settings(server, enabled=True, params=dict(ZERO, scale_ppm={"x": 100.0}))
        code, resp = server.upload(
            f"{BASE}/campaigns/{cid}/steps/3/trace", "yz.csv", traces[3].encode()
        )
        assert code == 409 and "parameters in force changed" in resp["error"]
        settings(server, enabled=False, params=ZERO)
        code, resp = server.upload(
            f"{BASE}/campaigns/{cid}/steps/3/trace", "yz.csv", traces[3].encode()
        )
        assert code == 200, resp
        code, done = server.request("POST", f"{BASE}/campaigns/{cid}/analyze", {})
        assert code == 200, done
        proposed = done["analysis"]["proposed"]
        assert proposed["squareness_um_per_m"]["yz"] == pytest.approx(-500, abs=10)
        code, resp = server.request("POST", f"{BASE}/campaigns/{cid}/apply", {"enabled": "yes"})
        assert code == 400 and "enabled" in resp["error"]
        code, applied = server.request("POST", f"{BASE}/campaigns/{cid}/apply", {"enabled": True})
        assert code == 200, applied
        st = status(server)
        assert st["settings"]["enabled"] is True and st["params_hash"] == applied["params_hash"]
        assert st["settings"]["params"]["squareness_um_per_m"] == pytest.approx(
            proposed["squareness_um_per_m"]
        )
        code, runs = server.request("GET", f"{BASE}/runs")
        mine = [r for r in runs["runs"] if r["campaign"] == cid]
        assert sorted(r["campaign_step"] or "joint" for r in mine) == ["joint", "xy", "xz", "yz"]
    finally:
        _reset_params(server)


def _wait(what, condition, timeout=180.0):
    deadline = time.time() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.3)


def test_a_demo_campaign_measured_by_the_live_virtual_bar(server):
    """Demo mode's live path (the default) on the real server's virtual printer: each test's
    print arms the capture of the virtual bar (a pseudo-terminal read through pyserial); the
    bar plays nothing while the printer waits at the mount pause, the test once it goes on,
    and the capture becomes the test's measurement by itself, once (SIMULATED)."""
    settings(server, enabled=False, params=ZERO, demo={"enabled": True, "live": True})
    try:
        code, doc = server.request(
            "POST", f"{BASE}/campaign/plan", {"radius_xy": 50, "radius_vertical": 20}
        )
        assert code == 200, doc
        cid = doc["id"]
        for step in doc["steps"]:
            n = step["n"]
            code, resp = server.request(
                "POST", f"{BASE}/campaigns/{cid}/steps/{n}/program", {"print": True}
            )
            assert code == 200 and resp["capture"]["armed"], resp
            assert resp["capture"]["source"] == "demo"
            server.wait_state("Paused", timeout=120)  # the M0 to mount the bar

            def armed():
                st = server.request("GET", f"{BASE}/sensor/status")[1]
                return st if st["state"] == "armed" and st.get("armed") else None

            st = _wait(f"test {n} armed", armed)
            assert st["armed"]["plane"] == step["plane"], st
            server.request("POST", "/api/job", {"command": "pause", "action": "resume"})

            def measured():
                return server.request("GET", f"{BASE}/campaigns/{cid}")[1]["steps"][n - 1]["run"]

            run_id = _wait(f"test {n} measured", measured)
            server.wait_state("Paused", timeout=120)  # the M0 to unmount it
            server.request("POST", "/api/job", {"command": "pause", "action": "resume"})
            server.wait_print_done()
            code, run = server.request("GET", f"{BASE}/runs/{run_id}")
            assert run["source"] == "live" and run["capture"]["source"] == "demo", run
            assert run["simulated"] and run["campaign_step"] == step["name"]
        code, runs = server.request("GET", f"{BASE}/runs")
        mine = [r for r in runs["runs"] if r["campaign"] == cid]
        assert sorted(r["campaign_step"] for r in mine) == ["xy", "xz", "yz"]  # once each
        code, done = server.request("POST", f"{BASE}/campaigns/{cid}/analyze", {})
        assert code == 200, done
        assert done["analysis"]["proposed"]["squareness_um_per_m"] == pytest.approx(
            {"xy": -3638.6, "xz": 800.0, "yz": -500.0}, abs=20
        )
        # issue 34: the clean demo printer's campaign raises no warning
        assert_applies_cleanly(done["analysis"])
    finally:
        settings(server, demo={"enabled": False})
        _reset_params(server)
