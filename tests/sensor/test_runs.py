"""Run detection on one continuous stream (issue 15): runs, dwells and feed-in/feed-out are
found in the data itself, without constant speed and with host time stamps with jitter.
All streams are SIMULATED (KinComp's printer + ballbar simulator)."""

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.formats import parse_csv_trace
from octoprint_kincomp.calibration.ballbar.program import TestSpec
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.sensor.retime import retime
from octoprint_kincomp.sensor.run_detection import detect_runs
from octoprint_kincomp.sensor.sensor_error import SensorError
from octoprint_kincomp.sensor.stream import RawStream, parse_raw_stream, trace_from_stream
from octoprint_kincomp.simulator.demo import demo_truth
from octoprint_kincomp.simulator.printer import volume_truth

from .conftest import SimStream, same_result


def device_stream(t, r, meta=None):
    return RawStream(dict(meta or {"timing": "device clock"}), t - t[0], r, np.arange(len(t)) + 40)


def host_stream(t_host, r):
    return RawStream({"timing": "host arrival"}, t_host - t_host[0], r, np.arange(len(t_host)) + 40)


def ftdi_arrival(t, seed=3, latency_s=0.016):
    """Arrival times of lines sent at ``t`` through a USB-serial adapter: delivered in packets
    at its latency timer, plus 0-3 ms of host scheduling (always late, in bursts)."""
    rng = np.random.default_rng(seed)
    host = np.ceil(t / latency_s) * latency_s + rng.uniform(0.0, 0.003, len(t)) + 50.0
    return np.maximum.accumulate(host)


def test_runs_and_dwells_found_in_a_stream_with_junk_around(xy_stream):
    s = xy_stream
    det = detect_runs(s.t, s.r, s.spec)
    assert det.complete and [run.direction for run in det.runs] == ["ccw", "cw"]
    ccw, cw = det.runs
    # each run starts and ends still, at its dwell level, and the runs meet in the gap
    assert (
        abs(s.r[ccw.i0] - ccw.dwell_mm) < 0.01
        and abs(s.r[cw.i1 - 1] - s.r[s.last_run_sample - 1]) < 0.01
    )
    assert ccw.i1 == cw.i0 and ccw.t_out < s.t[ccw.i1] < cw.t_in
    assert s.first_run_sample - 800 <= ccw.i0 <= s.first_run_sample + 10  # junk left out
    assert s.last_run_sample - 10 <= cw.i1 <= s.last_run_sample + 510
    for run in det.runs:
        assert run.step_in_mm == pytest.approx(-1.0, abs=0.1)
        assert run.step_out_mm == pytest.approx(1.0, abs=0.1)


def test_trace_from_the_stream_analyses_like_the_offline_trace(xy_stream):
    s = xy_stream
    trace, det = trace_from_stream(device_stream(s.t, s.r), s.spec, "hash1")
    assert trace.meta["program_hash"] == "hash1" and trace.meta["plane"] == "XY"
    assert float(trace.meta["sample_rate_hz"]) == pytest.approx(500.0, rel=1e-6)
    again = parse_csv_trace(trace.to_text())  # a valid native trace file
    assert len(again.rows) == len(trace.rows)
    d = same_result(again, s.offline(), square=0.05, ppm=0.05, ms=0.001, um=0.01)
    assert d["squareness_um_per_m"] == pytest.approx(-3638.6, abs=5.0)


def test_vertical_plane_partial_arc(xz_stream):
    s = xz_stream
    det = detect_runs(s.t, s.r, s.spec)
    assert det.complete and [run.direction for run in det.runs] == ["ccw", "cw"]
    for run in det.runs:  # 2 s dwells: the cut keeps at least one dwell each side
        assert s.t[run.i1 - 1] - run.t_out > 2.0 and run.t_in - s.t[run.i0] > 1.5


@pytest.mark.slow
def test_vertical_plane_trace_analyses_like_the_offline_trace(xz_stream):
    s = xz_stream
    trace, det = trace_from_stream(device_stream(s.t, s.r), s.spec)
    same_result(trace, s.offline(), square=0.05, ppm=0.05, ms=0.001, um=0.01)


def test_no_constant_speed_assumed(xy_stream):
    """The same readings on a warped time axis (speed varying by +-40 %, the radial moves
    taking 3x longer) still give the same runs: only steps and still dwells are used."""
    s = xy_stream
    t = s.t - s.t[0]
    warped = t + 0.4 * np.sin(2 * np.pi * t / 9.0) * 9.0 / (2 * np.pi)
    assert np.all(np.diff(warped) > 0)
    a = detect_runs(s.t, s.r, s.spec)
    b = detect_runs(warped, s.r, s.spec)
    assert b.complete
    for ra, rb in zip(a.runs, b.runs):
        assert abs(ra.i0 - rb.i0) <= 300 and abs(ra.i1 - rb.i1) <= 300
    slow = np.repeat(np.arange(len(t)), 3)  # every sample 3x: all motion 3x slower
    assert detect_runs(np.arange(len(slow)) / 500.0, s.r[slow], s.spec).complete


def test_a_stall_in_the_arc_is_not_an_end(xy_stream):
    s = xy_stream
    k = (s.first_run_sample + s.last_run_sample) // 3  # in the ccw arc
    r = np.concatenate([s.r[:k], np.full(1500, s.r[k]), s.r[k:]])  # host queue starved 3 s
    det = detect_runs(np.arange(len(r)) / 500.0, r, s.spec)
    assert det.complete and len(det.runs) == 2


@pytest.mark.parametrize("latency_s", [0.001, 0.016])
def test_host_time_stamps_with_jitter(xy_stream, latency_s):
    s = xy_stream
    host = ftdi_arrival(s.t, latency_s=latency_s)
    assert detect_runs(host, s.r, s.spec).complete  # even before re-timing
    trace, _ = trace_from_stream(host_stream(host, s.r), s.spec)
    assert trace.meta["timing"] == "host arrival"
    assert float(trace.meta["timing_rate_hz"]) == pytest.approx(500.0, rel=1e-4)
    assert float(trace.meta["timing_jitter_ms"]) <= latency_s * 1e3 + 3.5
    if latency_s > 0.01:  # the worse case analysed (the analysis takes a few seconds)
        same_result(trace, s.offline(), square=0.2, ppm=0.2, ms=0.005, um=0.1)


def test_retime_recovers_the_device_times():
    t = np.arange(20000) / 250.0
    host = ftdi_arrival(t)
    out, info = retime(np.arange(len(t)), host)
    err = out - t
    assert np.ptp(err) < 0.5e-3  # a constant offset is all that is left
    assert info["timing_method"] == "fitted rate" and 10.0 < info["timing_jitter_ms"] < 20.0
    fast = ftdi_arrival(t / 10.0)  # arrival 10x compressed, declared rate trusted
    out, info = retime(np.arange(len(t)), fast, rate_hz=250.0)
    assert np.allclose(np.diff(out), 1 / 250.0) and info["timing_method"] == "declared rate"


def test_retime_follows_a_device_that_paused():
    t = np.arange(10000) / 500.0
    t[5000:] += 1.0  # the device stopped sending for 1 s
    out, info = retime(np.arange(len(t)), ftdi_arrival(t))
    assert "not steady" in info["timing_method"]
    assert np.all(np.diff(out) >= 0)
    away = np.r_[0:4700, 5300:10000]
    assert np.ptp((out - t)[away]) < 0.02


def test_inverted_sign_and_wrong_units_get_a_hint(xy_stream):
    s = xy_stream
    with pytest.raises(SensorError, match="inverted"):
        trace_from_stream(device_stream(s.t, -s.r), s.spec)
    with pytest.raises(SensorError, match="1000 times .* check the units setting"):
        trace_from_stream(device_stream(s.t, s.r * 1000.0), s.spec)


def test_incomplete_streams_say_what_is_missing(xy_stream):
    s = xy_stream
    mid = (s.first_run_sample + s.last_run_sample) // 2 + 3000  # inside the cw arc
    det = detect_runs(s.t[:mid], s.r[:mid], s.spec)
    assert det.started and not det.complete and len(det.runs) == 1
    assert "1 of 2 runs" in det.reason
    end = s.last_run_sample - 400  # in the final dwell, not long enough yet
    det = detect_runs(s.t[:end], s.r[:end], s.spec)
    assert len(det.runs) == 2 and not det.complete and "waiting" in det.reason
    with pytest.raises(SensorError, match="1 of 2 runs"):
        trace_from_stream(device_stream(s.t[:mid], s.r[:mid]), s.spec)
    flat = np.random.default_rng(1).normal(0, 1e-3, 5000)
    det = detect_runs(np.arange(5000) / 500.0, flat, s.spec)
    assert not det.started and "no step" in det.reason


def test_armed_too_late_or_bumped_bar_is_not_a_run(xy_stream):
    s = xy_stream
    det = detect_runs(s.t, s.r, s.spec)
    ccw_in = int(np.searchsorted(s.t, det.runs[0].t_in))
    late = slice(ccw_in - 100, None)  # armed 0.2 s before the feed-in: no still dwell seen
    det_late = detect_runs(s.t[late], s.r[late], s.spec)
    assert not det_late.complete and "1 of 2 runs" in det_late.reason
    assert det_late.runs[0].t_in == pytest.approx(det.runs[1].t_in)  # only cw qualifies
    fs = 500
    still = np.full(3 * fs, 1.0)
    bump = np.concatenate([still, np.full(fs, 0.0), still])  # 1 mm for 1 s: no arc
    det = detect_runs(np.arange(len(bump)) / fs, bump, TestSpec())
    assert det.started and not det.runs


def test_single_direction_program(xy_stream):
    s = xy_stream
    det = detect_runs(s.t, s.r, TestSpec(directions=("ccw",)))
    assert det.complete and [r.direction for r in det.runs] == ["ccw"]


def test_raw_stream_round_trip(xy_stream):
    s = xy_stream
    raw = host_stream(ftdi_arrival(s.t[:2000]), s.r[:2000])
    raw.meta["sensor_name"] = "bar\x07 one"
    back = parse_raw_stream(raw.to_text())
    assert back.meta["sensor_name"] == "bar  one" and back.host_timed
    assert np.allclose(back.t, raw.t, atol=1e-6) and np.allclose(back.mm, raw.mm, atol=1e-7)
    assert list(back.line) == list(raw.line)


@pytest.mark.parametrize("noise_mm,every", [(0.02, 1), (0.05, 1), (0.0, 25), (0.0, 50)])
def test_noisy_or_slow_sensors(xy_stream, noise_mm, every):
    """A noisy bar (20-50 um) or a slow one (20 Hz, 10 Hz): the runs are still found."""
    s = xy_stream
    r = s.r + np.random.default_rng(2).normal(0, noise_mm, len(s.r)) if noise_mm else s.r
    det = detect_runs(s.t[::every], r[::every], s.spec)
    assert det.complete and [run.direction for run in det.runs] == ["ccw", "cw"]


def test_slow_vertical_test_with_short_dwells():
    """At a slow feed (F200: a 1 mm feed-in takes 0.3 s, the step window L is 1.2 s) the
    default 1 s dwells are shorter than the windows around the steps: both runs are still
    found (the CW run was lost once, the gap between the runs seemed not still)."""

    spec = TestSpec(plane="XZ", centre=(110, 110, 60), radius_mm=40, feed_mm_min=200)
    s = SimStream(spec, volume_truth(noise_um=0.5))
    det = detect_runs(s.t, s.r, spec)
    assert det.complete, det.reason
    assert [run.direction for run in det.runs] == ["ccw", "cw"]
    ccw, cw = det.runs
    assert ccw.i1 == cw.i0 and ccw.t_out < s.t[ccw.i1] < cw.t_in


def test_fast_test_without_planner_settings_analyses_like_the_offline_trace():
    """A live stream records no planner settings: the analysis estimates them from the
    ramps. At 3700 mm/min the timing between the ramps fits only within 1 % of the true
    acceleration; a grid over acceleration and junction deviation stepped over that valley
    and mapped the run at constant speed (squareness 17 um/m and scale mismatch 29 ppm
    off). The ramp shapes find it."""

    spec = TestSpec(radius_mm=50, feed_mm_min=3700, centre=(110, 110, 10))
    s = SimStream(spec, volume_truth(noise_um=0.5))
    trace, _ = trace_from_stream(device_stream(s.t, s.r), spec)
    assert "accel_mm_s2" not in trace.meta  # nothing to go by but the data
    d = same_result(trace, s.offline(), square=8.0, ppm=3.0, ms=0.02, um=1.0)
    assert d["fit"]["motion"]["motion"] == "planner"


@pytest.mark.xfail(
    strict=True,
    reason="known regression, open: since the per-firmware planner met trust checks round 2 "
    "(merge 1d7aafc) the acceleration estimated from the ramps of a live stream without "
    "planner settings is 1583.6 mm/s^2 for a true 1500 (5.6 %); the result still equals the "
    "offline analysis (the test above)",
)
def test_the_acceleration_estimated_from_a_fast_live_stream_is_the_printers():
    spec = TestSpec(radius_mm=50, feed_mm_min=3700, centre=(110, 110, 10))
    s = SimStream(spec, volume_truth(noise_um=0.5))
    trace, _ = trace_from_stream(device_stream(s.t, s.r), spec)
    d = analyse(trace)["diagnostics"]
    assert d["fit"]["motion"]["accel_mm_s2"] == pytest.approx(1500, rel=0.05)


def test_fast_re_test_with_take_ups_is_not_mapped_at_constant_speed():
    """The re-test of a demo campaign: the program goes out compensated (backlash take-ups
    stop the head at every reversal, servo lead on), streamed live without planner settings.
    The timing between the ramps then fits only in a narrow valley of junction deviation, and
    the estimate once fell back to constant speed: 9.6 um rms, the joint fit refused the test.
    The ramp shapes alone show the speed-up."""

    truth = demo_truth()
    p = Params.from_dict(
        dict(
            truth.errors.to_dict(), servo_precomp=True, servo_lag_ms={"x": 0.62, "y": 0.0, "z": 0.0}
        )
    )
    spec = TestSpec(radius_mm=50, feed_mm_min=3700, centre=(100, 100, 10), params_hash=p.hash())
    s = SimStream(spec, truth, params=p)
    trace, _ = trace_from_stream(device_stream(s.t, s.r), spec)
    d = analyse(trace, current=p)["diagnostics"]
    assert d["fit"]["motion"]["motion"] == "planner"
    assert d["fit"]["rms_um"] < 1.5
    assert abs(d["squareness_um_per_m"]) < 5.0 and abs(d["servo_mismatch_ms"]) < 0.1
