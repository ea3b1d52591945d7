"""Live capture through pyserial (issue 15): the virtual sensor on a real pseudo-terminal and
on a loopback socket, the states, the live view, and the faults (unplug, flood, garbage, no
data, a stream that never ends, open errors). Everything streamed is SIMULATED."""

import json
import os
import time

import pytest
import serial

from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.sensor import Capture, SensorConfig, SensorError, list_ports
from octoprint_kincomp.sensor.ports import open_error
from octoprint_kincomp.sensor.virtual import VirtualSensor
from octoprint_kincomp.simulator.demo import demo_truth
from octoprint_kincomp.simulator.printer import simulate_program

from .conftest import same_result

SPEC = TestSpec()
PROGRAM = generate(SPEC).splitlines()
SPEEDUP = 20.0


@pytest.fixture(scope="module")
def offline_trace():
    """The simulator's own trace of what the virtual sensor plays (same truth and seed)."""
    return simulate_program(generate(SPEC), demo_truth(), SPEC, "h1")


@pytest.fixture(scope="module")
def offline(offline_trace):
    """Its offline analysis."""
    return analyse(offline_trace)["diagnostics"]


@pytest.fixture
def sensors():
    started = []

    def make(**kw):
        kw.setdefault("speedup", SPEEDUP)
        vs = VirtualSensor(**kw)
        vs.start()
        started.append(vs)
        return vs

    yield make
    for vs in started:
        vs.stop()


@pytest.fixture
def captures():
    made = []

    def make(config, **kw):
        cap = Capture(config, **kw)
        made.append(cap)
        return cap

    yield make
    for cap in made:
        cap.close(wait_s=2.0)


def run_program(vs, cap, timeout=30.0, spec=SPEC, program=PROGRAM):
    cap.arm(spec, "h1")
    assert cap.wait(("armed",), 5) == "armed"
    played = vs.play(program, time.monotonic() + 0.1, spec=spec, program_hash="h1")
    cap.wait(("done", "failed"), timeout)
    return played


def test_capture_over_a_pty_equals_the_offline_analysis(sensors, captures, offline, offline_trace):
    vs = sensors(transport="pty", clock_start_us=(1 << 32) - 2_000_000)  # wraps in the test
    states = []
    cap = captures(
        SensorConfig(port=vs.url),
        listener=lambda kind, st: states.append(st["state"]) if kind == "state" else None,
    )
    cap.open()
    assert cap.wait(("preview",), 5) == "preview"
    deadline = time.time() + 10  # (awaited: a loaded machine took over 0.3 s to a reading)
    live = cap.live(seconds=5)
    while (live["reading_mm"] is None or len(live["t"]) <= 10) and time.time() < deadline:
        time.sleep(0.05)
        live = cap.live(seconds=5)
    assert live["reading_mm"] == pytest.approx(1.0, abs=0.01) and len(live["t"]) > 10
    assert 0.2 < live["noise_um"] < 1.0  # the virtual bar's 0.5 um
    json.dumps(cap.status())  # JSON-ready for the UI
    played = run_program(vs, cap)
    assert played.rows == offline_trace.rows  # the same stream as the offline fixture
    res = cap.result
    assert cap.state == "done" and res.ok, res.message
    assert states[:4] == ["preview", "armed", "capturing", "done"]
    assert [r["direction"] for r in res.runs] == ["ccw", "cw"]
    assert res.trace.meta["program_hash"] == "h1" and res.trace.meta["simulated"] == "true"
    assert res.trace.meta["source"].startswith("SIMULATED live capture")
    assert res.diagnostics["bad_lines"] == 0 and len(res.stream) > len(res.trace.rows)
    same_result(res.trace, offline, square=0.05, ppm=0.05, ms=0.001, um=0.02)
    assert cap.status()["port_open"]  # the live view goes on after the capture


def test_capture_over_a_socket_with_plain_readings(sensors, captures):
    """Plain readings in um, shorter = positive, host-timed, on a smaller, faster circle."""
    spec = TestSpec(radius_mm=50.0, feed_mm_min=3000.0, centre=(100.0, 100.0, 10.0))
    program = generate(spec).splitlines()
    offline = analyse(simulate_program(generate(spec), demo_truth(), spec))["diagnostics"]
    vs = sensors(transport="tcp", protocol="plain", units="um", longer_positive=False)
    cap = captures(
        SensorConfig(
            port=vs.url, protocol="plain", units="um", positive="shorter", sample_rate_hz=500.0
        )
    )
    cap.open()
    assert cap.wait(("preview",), 5) == "preview"
    run_program(vs, cap, spec=spec, program=program)
    res = cap.result
    assert res.ok, res.message
    assert res.trace.meta["timing"] == "host arrival"
    assert res.trace.meta["timing_method"] == "declared rate"
    assert res.trace.meta["radius_mm"] == "50"
    same_result(res.trace, offline, square=0.5, ppm=0.5, ms=0.005, um=0.1)


def test_unplugged_mid_test_fails_and_keeps_the_partial_data(sensors, captures):
    vs = sensors(transport="pty")
    cap = captures(SensorConfig(port=vs.url))
    cap.arm(SPEC, "h1")
    assert cap.wait(("armed",), 5) == "armed"
    vs.play(PROGRAM, time.monotonic(), spec=SPEC)
    assert cap.wait(("capturing",), 15) == "capturing"
    deadline = time.monotonic() + 15  # some data first (a loaded machine reads late)
    while cap.status()["samples"] <= 500 and time.monotonic() < deadline:
        time.sleep(0.05)
    vs.unplug()
    assert cap.wait(("failed",), 5) == "failed"
    res, st = cap.result, cap.status()
    assert not res.ok and res.trace is None and "disconnected" in res.message
    assert not st["port_open"] and st["message"] == res.message
    assert len(res.stream) > 500  # the partial data, for inspection
    assert "time_s,reading_mm,line" in res.stream.to_text()


def test_a_flood_is_bounded(sensors, captures):
    vs = sensors(transport="pty")  # 10,000 lines/s
    cap = captures(SensorConfig(port=vs.url))
    cap.arm(SPEC, max_samples=3000)
    assert cap.wait(("failed",), 10) == "failed"
    res = cap.result
    assert "more than 3000 samples" in res.message
    assert 3000 < len(res.stream) < 3000 + 10_000  # one read at most beyond the limit
    assert cap.status()["port_open"]
    fast = sensors(transport="pty", speedup=100.0)  # 50,000 lines/s: too many to parse
    cap = captures(SensorConfig(port=fast.url))
    cap.open()
    assert cap.wait(("failed",), 10) == "failed"
    assert "floods the port" in cap.status()["message"] and not cap.status()["port_open"]


def test_garbage_beyond_the_limit_fails(sensors, captures):
    vs = sensors(transport="tcp")
    cap = captures(SensorConfig(port=vs.url, max_bad_lines=20))
    cap.arm(SPEC)
    assert cap.wait(("armed",), 5) == "armed"
    time.sleep(0.3)
    for _ in range(3):
        vs.inject(b"\xff\xfe\x00\x9c junk\n" * 5 + b"hello world\n" * 5)
        time.sleep(0.05)
    assert cap.wait(("failed",), 5) == "failed"
    res = cap.result
    assert "too many bad lines" in res.message
    assert res.diagnostics["counts"]["unreadable"] >= 10
    assert res.diagnostics["counts"]["garbage"] >= 10
    assert not cap.status()["port_open"]


def test_no_data_times_out(captures):
    master, slave = os.openpty()
    try:
        cap = captures(SensorConfig(port=os.ttyname(slave), no_data_timeout_s=1.0))
        cap.arm(SPEC)
        assert cap.wait(("failed",), 5) == "failed"
        assert "no data from the sensor for 1 s" in cap.result.message
        assert cap.result.stream is None
    finally:
        os.close(master)
        os.close(slave)


def test_a_stream_that_never_ends_times_out(sensors, captures):
    vs = sensors(transport="pty")
    cap = captures(SensorConfig(port=vs.url))
    cap.arm(SPEC, max_duration_s=1.0)
    assert cap.wait(("failed",), 5) == "failed"
    assert "not seen within 1 s" in cap.result.message
    assert len(cap.result.stream) > 100


def test_stop_before_the_end_keeps_the_partial_data(sensors, captures):
    vs = sensors(transport="pty")
    cap = captures(SensorConfig(port=vs.url))
    cap.arm(SPEC)
    assert cap.wait(("armed",), 5) == "armed"
    vs.play(PROGRAM, time.monotonic(), spec=SPEC)
    assert cap.wait(("capturing",), 15) == "capturing"
    cap.stop()
    assert cap.wait(("failed",), 5) == "failed"
    assert "stopped before the end" in cap.result.message
    assert len(cap.result.stream) > 100
    cap.stop()  # nothing armed: no-op
    with pytest.raises(SensorError):  # a capture cannot be armed twice
        cap.arm(SPEC)
        cap.arm(SPEC)


def test_open_errors_are_clear(captures):
    cap = captures(SensorConfig(port="/dev/ttyKINCOMP-missing"))
    cap.arm(SPEC)
    assert cap.wait(("failed",), 5) == "failed"
    assert "does not exist" in cap.status()["message"] and not cap.result.ok
    master, slave = os.openpty()
    holder = serial.serial_for_url(os.ttyname(slave), exclusive=True)
    try:
        cap = captures(SensorConfig(port=os.ttyname(slave)))
        cap.open()
        assert cap.wait(("failed",), 5) == "failed"
        assert "busy" in cap.status()["message"]
    finally:
        holder.close()
        os.close(master)
        os.close(slave)
    denied = serial.SerialException(
        13, "could not open port /dev/ttyUSB9: [Errno 13] Permission denied: '/dev/ttyUSB9'"
    )
    assert "dialout" in open_error("/dev/ttyUSB9", denied).message
    for url, text in (("bogus://x", "not a serial port"), ("socket://127.0.0.1:1", "nothing")):
        cap = captures(SensorConfig(port=url))
        cap.open()
        assert cap.wait(("failed",), 5) == "failed"
        assert text in cap.status()["message"]


def test_loop_url_and_an_opener_that_hangs_never_block_the_caller(captures):
    def slow_opener(port, baudrate):
        time.sleep(1.0)
        ser = serial.serial_for_url("loop://", timeout=0.1)
        ser.write(b"KINCOMP-BALLBAR 1\n" + b"".join(b"%d,0.25\n" % (k * 1000) for k in range(50)))
        return ser

    cap = captures(
        SensorConfig(port="loop://"), opener=slow_opener, listener=lambda kind, st: 1 / 0
    )  # a listener's bug is contained
    t0 = time.monotonic()
    cap.open()
    cap.arm(SPEC)
    cap.status()
    cap.live()
    cap.stop()
    assert time.monotonic() - t0 < 0.2
    assert cap.wait(("preview",), 5) == "preview"
    time.sleep(0.3)
    assert cap.status()["reading_mm"] == 0.25


def test_list_ports():
    ports = list_ports()
    assert isinstance(ports, list)
    assert all(set(p) == {"device", "description", "hwid"} for p in ports)


@pytest.mark.slow
@pytest.mark.alone  # (the host times the readings: another test's load makes them jitter)
def test_real_time_plain_readings_timed_by_the_host(sensors, captures):
    """In real time (a short test, about 15 s): plain readings through a pty, times from
    their arrival on the host, the rate fitted; the analysis still equals the offline one."""
    spec = TestSpec(radius_mm=50.0, feed_mm_min=3700.0)
    program = generate(spec)
    offline = analyse(simulate_program(program, demo_truth(), spec, "h1"))["diagnostics"]
    vs = sensors(transport="pty", protocol="plain", speedup=1.0)
    cap = captures(SensorConfig(port=vs.url, protocol="plain"))
    cap.open()
    assert cap.wait(("preview",), 5) == "preview"
    run_program(vs, cap, timeout=120.0, spec=spec, program=program.splitlines())
    res = cap.result
    assert res.ok, res.message
    assert res.trace.meta["timing_method"] == "fitted rate"
    assert float(res.trace.meta["timing_rate_hz"]) == pytest.approx(500.0, rel=2e-3)
    same_result(res.trace, offline, square=1.0, ppm=1.0, ms=0.01, um=0.2)


def test_waiting_while_armed_keeps_only_the_last_seconds(sensors, captures):
    vs = sensors(transport="pty")
    cap = captures(SensorConfig(port=vs.url), pre_keep_s=2.0, tick_s=0.1)
    cap.arm(SPEC)
    # 40 s of device time before the program starts: 20,000 samples streamed (awaited: a
    # loaded machine streams them later)
    start = vs._k
    deadline = time.monotonic() + 60.0
    while vs._k - start < 20_000:
        assert time.monotonic() < deadline, "the virtual bar did not stream"
        time.sleep(0.05)
    # kept: 2 dwells + 1 s (3 s, trimmed at 4.5 s) plus what came since the last trim, of
    # the 20,000 (checked until a trim: under load a read holds more, never the whole wait)
    while True:
        st = cap.status()
        assert st["state"] == "armed", st
        if 500 < st["samples"] <= 4000:
            break
        assert time.monotonic() < deadline, st
        time.sleep(0.02)
    vs.play(PROGRAM, time.monotonic(), spec=SPEC)
    assert cap.wait(("done", "failed"), 20) == "done", cap.result.message


def test_arm_again_after_a_failure(captures):
    calls = []

    def flaky_opener(port, baudrate):
        calls.append(port)
        if len(calls) == 1:
            raise SensorError("first open fails", "port")
        ser = serial.serial_for_url("loop://", timeout=0.1)
        ser.write(b"KINCOMP-BALLBAR 1\n0,0.5\n")
        return ser

    cap = captures(SensorConfig(port="loop://", no_data_timeout_s=1.0), opener=flaky_opener)
    cap.arm(SPEC)
    assert cap.wait(("failed",), 5) == "failed" and cap.result.message == "first open fails"
    for _ in range(2):  # again at once, while the failed thread may still be ending
        cap.arm(SPEC)
        assert cap.wait(("armed",), 5) == "armed"
        assert cap.wait(("failed",), 5) == "failed"  # loop:// sends nothing more
        assert "no data" in cap.result.message
    assert len(calls) == 2  # the port stayed open after the capture-level failure
