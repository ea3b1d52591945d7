"""The lookahead motion planner (issue 12): trapezoids, junction speeds, stops, feed caps."""

import math

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.core.params import ParamsError
from octoprint_kincomp.firmware.planner import MotionSettings, plan_program

START = (0.0, 0.0, 0.0)


def plan(text, **kw):
    return plan_program(text.strip().splitlines(), START, MotionSettings(**kw))


def test_single_move_trapezoid_and_triangle():
    p = plan("G1 X10 F1800", accel_mm_s2=1000.0)  # 30 mm/s, reached after 0.45 mm
    assert p.duration == pytest.approx(10 / 30 + 30 / 1000)
    pos, vel = p.sample(np.array([0.01, 0.03, p.duration / 2, p.duration - 0.01]))
    assert pos[0, 0] == pytest.approx(0.5 * 1000 * 0.01**2)  # accelerating from rest
    assert vel[1, 0] == pytest.approx(30.0) and vel[2, 0] == pytest.approx(30.0)
    assert pos[3, 0] == pytest.approx(10 - 0.5 * 1000 * 0.01**2)  # braking to a stop
    short = plan("G1 X0.2 F1800", accel_mm_s2=1000.0)  # never reaches 30 mm/s
    assert short.duration == pytest.approx(2 * math.sqrt(0.2 / 1000))
    assert short.vc[0] == pytest.approx(math.sqrt(1000 * 0.2))


def test_junction_speed_marlin_jd_and_klipper_scv():
    text = "G1 X10 F3000\nG1 Y10"
    jd = plan(text, accel_mm_s2=1500.0, junction_deviation_mm=0.013)
    s = math.sqrt(0.5)
    assert jd.v1[0] == pytest.approx(math.sqrt(1500 * 0.013 * s / (1 - s)))
    assert jd.v1[0] == pytest.approx(jd.v0[1]) and jd.settings.corner_speed_90 == pytest.approx(
        jd.v1[0]
    )
    scv = plan(text, accel_mm_s2=1500.0, square_corner_velocity_mm_s=5.0)
    assert scv.v1[0] == pytest.approx(5.0)  # Klipper: the 90 degree corner speed itself
    # a reversal stops; a straight continuation does not slow down
    assert plan("G1 X10 F3000\nG1 X0").v1[0] == 0.0
    assert plan("G1 X10 F3000\nG1 X20").v1[0] == pytest.approx(50.0)


def test_stops_at_m400_and_dwell():
    p = plan("G1 X10 F3000\nM400\nG1 X20\nG4 P500\nG1 X30", accel_mm_s2=1000.0)
    assert p.v1[0] == 0.0 and p.v0[1] == 0.0
    waits = np.nonzero(p.L == 0)[0]
    assert len(waits) == 1 and p.tc[waits[0]] == pytest.approx(0.5)
    one = plan("G1 X10 F3000", accel_mm_s2=1000.0).duration
    assert p.duration == pytest.approx(3 * one + 0.5)


def test_axis_feed_caps():
    p = plan("G1 Z10 F3000", max_feed_mm_min={"x": 18000, "y": 18000, "z": 600})
    assert p.vc[0] == pytest.approx(10.0)  # Z capped at 600 mm/min
    diag = plan("G1 X10 Z10 F3000", max_feed_mm_min={"x": 18000, "y": 18000, "z": 600})
    assert diag.vc[0] == pytest.approx(10.0 * math.sqrt(2))  # Z component at its cap


def test_constant_speed_option():
    p = plan("G1 X10 F600\nG1 Y10\nG4 S1", constant_speed=True)
    assert p.duration == pytest.approx(1 + 1 + 1)


def test_circle_plan_is_continuous_and_runs_at_feed():
    spec = TestSpec()
    p = plan_program(generate(spec), spec.centre, MotionSettings(accel_mm_s2=500.0))
    ends = p.p0 + p.u * p.L[:, None]
    assert np.abs(ends[:-1] - p.p0[1:]).max() < 1e-9  # positions continuous
    assert np.abs(p.v1[:-1] - p.v0[1:]).max() < 1e-9  # speeds continuous
    ts = np.arange(0, p.duration, 0.002)
    _, vel = p.sample(ts)
    speed = np.linalg.norm(vel, axis=1)
    assert speed.max() <= 50.0 + 1e-9  # the travel feed is the fastest
    on_circle = np.isclose(p.vc, 1850 / 60.0)
    assert on_circle.sum() > 2000  # the chords reach the programmed feed


def test_settings_documents_round_trip():
    s = MotionSettings(
        accel_mm_s2=800.0,
        square_corner_velocity_mm_s=6.0,
        max_feed_mm_min={"x": 9000, "y": 9000, "z": 600},
    )
    back = MotionSettings.from_metadata(s.metadata())
    assert back.accel_mm_s2 == 800.0 and back.square_corner_velocity_mm_s == 6.0
    assert back.max_feed_mm_min == {"x": 9000, "y": 9000, "z": 600}
    assert MotionSettings.from_metadata({"plane": "XY"}) is None  # an old trace
    assert MotionSettings.from_metadata({"motion": "constant_speed"}).constant_speed
    with pytest.raises(ParamsError, match="accel_mm_s2"):
        MotionSettings.from_dict({"accel_mm_s2": -5})
    with pytest.raises(ParamsError, match="max_feed_mm_min.q"):
        MotionSettings.from_dict({"max_feed_mm_min": {"q": 5}})
