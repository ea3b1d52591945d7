"""Live ballbar capture on a real OctoPrint server (issue 15): the virtual printer prints the
test program started from KinComp's API while KinComp's virtual ballbar streams on a real
pseudo-terminal, opened by the server through pyserial exactly as a USB sensor. The capture
is analysed and stored by itself and equals an offline analysis of the stored stream; an
unplugged sensor ends in a failed run with a message, the print going on; in demo mode the
whole calibrate -> apply -> re-test loop runs on the live path. Everything streamed is
SIMULATED."""

import json
import os
import time

import pytest

from octoprint_kincomp.calibration.ballbar.analysis import Provenance, analyse
from octoprint_kincomp.calibration.ballbar.formats import load_any
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.compensation import FirmwareCompensation
from octoprint_kincomp.sensor import parse_raw_stream, trace_from_stream
from octoprint_kincomp.sensor.virtual import VirtualSensor
from tests.support import assert_applies_cleanly
from tests.support.serverutil import settings

pytestmark = pytest.mark.slow

ZERO = {
    "squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}
PROGRAM = {"plane": "XY", "centre": [100, 100, 5], "radius": 40, "feed": 3000, "print": True}
SPEC = TestSpec(plane="XY", centre=(100.0, 100.0, 5.0), radius_mm=40.0, feed_mm_min=3000.0)
NO_SENSOR = {"enabled": False, "port": ""}


@pytest.fixture
def bar(request):
    """The virtual ballbar on a pseudo-terminal, 20 times real time unless the test gives
    another speed-up (indirect parameter)."""
    vs = VirtualSensor(speedup=getattr(request, "param", 20.0))
    vs.start()
    yield vs
    vs.stop()


@pytest.fixture
def clean(server):
    settings(server, enabled=False, params=ZERO, demo={"enabled": False}, sensor=NO_SENSOR)
    before = _last_run_id(server)
    yield before
    server.wait_print_done(timeout=300)
    settings(
        server, enabled=False, params=ZERO, demo={"enabled": False, "live": True}, sensor=NO_SENSOR
    )


def _last_run_id(server):
    st = server.request("GET", "/plugin/kincomp/sensor/status")[1]
    return (st.get("last_run") or {}).get("id")


def _live_run(server, previous, timeout=120.0):
    """The run of the next live capture (after the one with id ``previous``)."""
    deadline = time.time() + timeout
    while True:
        run_id = _last_run_id(server)
        if run_id and run_id != previous:
            code, run = server.request("GET", f"/plugin/kincomp/runs/{run_id}")
            assert code == 200, run
            return run
        assert time.time() < deadline, "no live capture was stored"
        time.sleep(0.3)


def _offline(server, run, program_hash):
    """An offline analysis of the run's stored raw stream, as an upload of its trace, with
    the test the printed program states (its header: the printer's planner settings from
    its M503 answer too, which the server planned it with) and the firmware's compensation
    the server recorded with the run (the live path knows it; a bare trace does not)."""
    code, raw = server.request("GET", f"/plugin/kincomp/runs/{run['id']}/raw")
    assert code == 200
    printed = os.path.join(server.basedir, "uploads", run["capture"]["program"])
    with open(printed, encoding="utf-8") as f:
        spec, _ = spec_from_program(f.read())
    assert spec.motion, "the program states the planner it was planned with"
    trace, _ = trace_from_stream(parse_raw_stream(raw), spec, program_hash)
    firmware = FirmwareCompensation.from_dict(run["diagnostics"]["firmware_compensation"])
    assert firmware.known
    trace.meta.setdefault("firmware_compensation", firmware.text())  # (as the server records)
    result = analyse(
        load_any(trace.to_text().encode(), "offline.csv"),
        current=Params.from_dict(run["params_before"]),
        origin=Provenance(confirmed="capture"),
    )
    return trace, json.loads(json.dumps(result["diagnostics"], default=float))


def test_the_printed_test_is_captured_analysed_and_stored(server, bar, clean):
    params = settings(server, sensor={"enabled": True, "port": bar.url})["params"]
    code, prog = server.request("POST", "/plugin/kincomp/program", PROGRAM)
    assert code == 200, prog
    assert prog["printing"] and prog["capture"] == {
        "armed": True,
        "source": "sensor",
        "port": bar.url,
    }
    # the printer receives the program; the bar measures it, at its own pace
    bar.play(
        generate(SPEC).splitlines(), time.monotonic(), spec=SPEC, program_hash=prog["program_hash"]
    )
    run = _live_run(server, clean)
    assert run["status"] == "ok" and run["source"] == "live" and run["simulated"]
    assert run["capture"]["sensor"]["timing"] == "device clock"
    assert run["capture"]["program"] == prog["path"]
    trace, diagnostics = _offline(server, run, prog["program_hash"])
    assert diagnostics == run["diagnostics"]  # the same stream gives the same result
    code, stored = server.request("GET", f"/plugin/kincomp/runs/{run['id']}/trace")
    ours = trace.to_text().splitlines()
    theirs = stored.splitlines()
    diff = [(a, b) for a, b in zip(theirs, ours) if a != b]
    assert not diff and len(theirs) == len(ours), (diff[:5], len(theirs), len(ours))
    assert run["diagnostics"]["squareness_um_per_m"] == pytest.approx(-3638, abs=60)
    code, runs = server.request("GET", "/plugin/kincomp/runs")
    assert runs["runs"][0]["id"] == run["id"] and runs["runs"][0]["has_raw"]
    assert server.request("GET", "/plugin/kincomp/status")[1]["settings"]["params"] == params
    server.wait_print_done(timeout=300)
    assert server.request("GET", "/api/job")[1]["state"] == "Operational"


@pytest.mark.parametrize("bar", [1.0], indirect=True)  # real time: the print goes on
def test_an_unplugged_sensor_fails_the_run_not_the_print(server, bar, clean):
    settings(server, sensor={"enabled": True, "port": bar.url})
    code, prog = server.request("POST", "/plugin/kincomp/program", PROGRAM)
    assert prog["capture"]["armed"], prog
    bar.play(generate(SPEC).splitlines(), time.monotonic(), spec=SPEC)
    deadline = time.time() + 60
    while server.request("GET", "/plugin/kincomp/sensor/status")[1]["state"] != "capturing":
        assert time.time() < deadline, "never capturing"
        time.sleep(0.1)
    bar.unplug()  # the pseudo-terminal closes under the server mid-test
    run = _live_run(server, clean)
    assert run["status"] == "failed" and "disconnected" in run["message"]
    assert run["capture"]["samples"] > 50
    code, raw = server.request("GET", f"/plugin/kincomp/runs/{run['id']}/raw")
    assert code == 200 and len(parse_raw_stream(raw)) == run["capture"]["samples"]
    code, st = server.request("GET", "/plugin/kincomp/sensor/status")
    assert st["last_run"]["status"] == "failed" and not st["port_open"]
    server.wait_print_done(timeout=300)  # the print itself finished
    code, job = server.request("GET", "/api/job")
    assert job["state"] == "Operational" and job["progress"]["completion"] == 100
    code, body = server.request("POST", "/plugin/kincomp/apply", {"run": run["id"]})
    assert code == 400


def test_the_printers_own_port_is_refused(server, clean):
    code, body = server.request(
        "POST", "/plugin/kincomp/settings", {"sensor": {"enabled": True, "port": "VIRTUAL"}}
    )
    assert (
        code == 400
        and body["error"].startswith("sensor.port")
        and "printer's own port" in body["error"]
    )
    code, body = server.request("POST", "/plugin/kincomp/settings", {"sensor": {"baudrate": -5}})
    assert code == 400 and body["error"].startswith("sensor.baudrate")
    st = server.request("GET", "/plugin/kincomp/status")[1]
    assert st["settings"]["sensor"]["port"] == "" and st["settings"]["sensor"]["baudrate"] == 115200


def test_demo_loop_on_the_live_path(server, clean):
    """Demo mode (live by default): print -> captured -> apply -> re-test, no file."""
    settings(server, demo={"enabled": True, "live": True})
    code, prog = server.request("POST", "/plugin/kincomp/program", PROGRAM)
    assert prog["capture"]["armed"] and prog["capture"]["source"] == "demo", prog
    before = _live_run(server, clean)
    assert before["status"] == "ok" and before["simulated"], before.get("message")
    assert before["capture"]["port"].startswith("/dev/")  # the virtual bar's pty
    _, diagnostics = _offline(server, before, prog["program_hash"])
    assert diagnostics == before["diagnostics"]
    assert before["diagnostics"]["squareness_um_per_m"] == pytest.approx(-3638, abs=60)
    server.wait_print_done(timeout=300)
    code, applied = server.request(
        "POST", "/plugin/kincomp/apply", {"run": before["id"], "enabled": True}
    )
    assert code == 200, applied
    code, prog = server.request("POST", "/plugin/kincomp/program", PROGRAM)
    after = _live_run(server, before["id"])
    assert after["status"] == "ok" and after["params_before_hash"] == applied["params_hash"]
    for run in (before, after):  # issue 34: a clean demo printer raises no warning
        assert_applies_cleanly(run)
    code, cmp = server.request(
        "GET", f"/plugin/kincomp/compare?before={before['id']}&after={after['id']}"
    )
    red = {r["key"]: r["reduction_pct"] for r in cmp["table"]}
    assert red["squareness_um_per_m"] > 90 and red["circularity_um.bidirectional"] > 80
    server.wait_print_done(timeout=300)
    # the fallback still has its simulated trace (simulated on a thread after the print's
    # end: a few seconds on a busy machine)
    deadline = time.monotonic() + 60
    while server.request("GET", "/plugin/kincomp/demo/trace")[0] != 200:
        assert time.monotonic() < deadline, "no simulated trace 60 s after the print"
        time.sleep(0.5)
