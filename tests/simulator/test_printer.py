"""The printer + ballbar simulator with real motion (issue 12). Everything here is SIMULATED."""

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.analysis import analyse, load_runs
from octoprint_kincomp.calibration.ballbar.formats import parse_csv_trace
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.core.params import Params, ParamsError
from octoprint_kincomp.firmware.planner import MotionSettings
from octoprint_kincomp.simulator.printer import Truth, _servo, planned, simulate_program

SMALL = TestSpec(plane="XY", centre=(60, 60, 5), radius_mm=30, feed_mm_min=1850)


def ramp_duration(trace, direction="ccw"):
    """Seconds the reading takes to fall from 90 % to 10 % of the feed-in."""
    rows = np.array([(t, r) for d, t, r in trace.rows if d == direction])
    t, r = rows[:, 0], rows[:, 1]
    hi = np.median(r[:50])
    return t[np.argmax(r < hi - 0.9)] - t[np.argmax(r < hi - 0.1)]


def test_default_simulator_accelerates_and_records_its_planner():
    slow = Truth(motion=MotionSettings(accel_mm_s2=300.0), sample_rate_hz=2000)
    const = Truth(motion=MotionSettings(constant_speed=True), sample_rate_hz=2000)
    a = simulate_program(generate(SMALL), slow)
    b = simulate_program(generate(SMALL), const)
    assert a.meta["motion"] == "planner" and a.meta["accel_mm_s2"] == "300"
    assert a.meta["junction_deviation_mm"] == "0.013"
    assert b.meta["motion"] == "constant_speed"
    v = 1850 / 60
    assert ramp_duration(b) == pytest.approx(0.8 / v, abs=2e-3)  # linear ramp at the feed
    assert ramp_duration(a) > 1.5 * ramp_duration(b)  # from rest at 300 mm/s^2
    # the whole program takes longer when the printer accelerates
    assert planned(generate(SMALL), slow).duration > planned(generate(SMALL), const).duration


def test_servo_lag_acts_on_the_planned_motion():
    """At steady speed the drive is v*T behind; first-order response checked against the
    closed form of a ramp input."""
    dt, T = 0.002, 0.004
    t = np.arange(0, 0.2, dt)
    u = np.where(t > 0.05, (t - 0.05) * 30.0, 0.0)
    y = _servo(u, dt, T)
    tau = np.clip(t - 0.05, 0, None)
    exact = 30.0 * (tau - T * (1 - np.exp(-tau / T)))
    assert np.allclose(y, exact, atol=1e-9)
    assert u[-1] - y[-1] == pytest.approx(30.0 * T, rel=1e-6)


def test_stepper_quantisation_and_bar_drift():
    truth = Truth(steps_per_mm={"x": 80.0, "y": 80.0}, sample_rate_hz=200)
    trace = simulate_program(generate(SMALL), truth)
    g, runs = load_runs(trace)
    dev = np.concatenate([r.dev for r in runs]) * 1e3
    # 80 steps/mm: positions on a 12.5 um grid, the radius off by up to half a step
    assert 3.0 < dev.max() - dev.min() < 12.5 * 1.5
    drift = Truth(bar_drift_um_per_min=3.0, noise_um=0.3, sample_rate_hz=250)
    d = analyse(simulate_program(generate(SMALL), drift))["diagnostics"]
    assert d["bar_drift_um_per_min"] == pytest.approx(3.0, abs=0.3)


def test_truth_file_motion_keys():
    t = Truth.from_dict(
        {
            "errors": {},
            "accel_mm_s2": 800,
            "square_corner_velocity_mm_s": 5,
            "max_feed_mm_min": {"z": 600},
            "steps_per_mm": {"z": 400},
            "bar_drift_um_per_min": 0.5,
        }
    )
    assert t.motion.accel_mm_s2 == 800 and t.motion.square_corner_velocity_mm_s == 5
    assert t.motion.max_feed_mm_min["z"] == 600 and t.motion.max_feed_mm_min["x"] > 600
    assert t.steps_per_mm == {"z": 400.0} and t.bar_drift_um_per_min == 0.5
    assert Truth.from_dict({"errors": {}, "motion": "constant_speed"}).motion.constant_speed
    for bad, field in (
        ({"accel_mm_s2": 0}, "accel_mm_s2"),
        ({"steps_per_mm": {"w": 80}}, "steps_per_mm.w"),
        ({"junction_deviation_mm": "x"}, "junction_deviation_mm"),
    ):
        with pytest.raises(ParamsError, match=field):
            Truth.from_dict(dict({"errors": {}}, **bad))


def test_old_constant_speed_traces_stay_readable():
    """A trace written before the planner (no motion keys, no new program keys) is analysed
    as before: its ramps show constant speed, and it says so."""
    truth = Truth(
        errors=Params.from_dict({"squareness_um_per_m": {"xy": 200}}),
        servo_lag_ms={"x": 0.5},
        noise_um=0.3,
        motion=MotionSettings(constant_speed=True),
        sample_rate_hz=250,
    )
    trace = parse_csv_trace(simulate_program(generate(SMALL), truth).to_text())
    for key in list(trace.meta):
        if key in MotionSettings.KEYS or key in (
            "chord_error_um",
            "lift_mm",
            "travel_feed_mm_min",
            "mount_pause",
            "params_hash",
        ):
            del trace.meta[key]
    out = analyse(trace)
    d = out["diagnostics"]
    assert d["squareness_um_per_m"] == pytest.approx(200, abs=5)
    assert d["servo_mismatch_ms"] == pytest.approx(0.5, abs=0.02)
    assert d["fit"]["motion"]["motion"] == "constant_speed"
    assert any("constant speed" in n for n in out["notes"])


def test_angle_output_of_a_compensated_run(tmp_path):
    """simulate --angle maps a compensated program back to the nominal circle; native and
    angle traces of that re-test agree on the (near zero) residuals."""
    import json

    from octoprint_kincomp.calibration.ballbar.formats import AngleTrace
    from octoprint_kincomp.calibration.ballbar.program import body_hash
    from octoprint_kincomp.cli import main
    from octoprint_kincomp.simulator.closed_loop import compensate_text
    from octoprint_kincomp.simulator.printer import simulate_angle_trace, volume_truth

    truth = volume_truth(noise_um=0.3, sample_rate_hz=250)
    first = analyse(simulate_program(generate(SMALL), truth))
    params = Params.from_dict(first["parameters"])
    sent = compensate_text(generate(SMALL), params)
    native = analyse(simulate_program(sent, truth, SMALL, body_hash(SMALL)), current=params)
    angle = analyse(
        simulate_angle_trace(sent, truth, SMALL, body_hash(SMALL), compensated_with=params),
        current=params,
    )
    for d in (native["diagnostics"], angle["diagnostics"]):
        assert abs(d["squareness_um_per_m"]) < 5 and abs(d["scale_mismatch_ppm"]) < 5
        assert max(abs(v) for v in d["backlash_um"].values()) < 1.0
    prog, tr, out = tmp_path / "p.gcode", tmp_path / "t.json", tmp_path / "a.csv"
    prog.write_text(generate(SMALL))
    tr.write_text(
        json.dumps(
            {
                "errors": {"squareness_um_per_m": {"xy": 300}},
                "accel_mm_s2": 800,
                "sample_rate_hz": 100,
            }
        )
    )
    assert main(["simulate", str(prog), "--truth", str(tr), "--angle", "-o", str(out)]) == 0
    trace = parse_csv_trace(out.read_text())
    assert isinstance(trace, AngleTrace) and trace.meta["accel_mm_s2"] == "800"
    assert analyse(trace)["diagnostics"]["squareness_um_per_m"] == pytest.approx(300, abs=6)
