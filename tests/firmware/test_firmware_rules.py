"""KinComp against the rules of the firmware that cannot run here (Marlin, RepRapFirmware).

Klipper runs in the suite (tests/firmware/test_klipper*.py). For Marlin and RepRapFirmware
the rules KinComp relies on are written in docs/marlin.md and docs/reprapfirmware.md from
their documentation and source; each test below computes one rule by hand, from the
firmware's formula and the move's geometry, and holds KinComp's planner and programs to it:

* junction speeds: Marlin's junction deviation with each axis' ``M201`` along the change of
  direction and its small-segment limit, Marlin's classic jerk (``M205 X Y Z`` without ``J``),
  RepRapFirmware's per-drive ``M566`` jerk, which never joins an X/Y move to a Z-only one;
* acceleration: each move's own, lowered so that no axis exceeds its ``M201``;
* the pause a program writes: ``M0`` for Marlin, ``M291 S2`` for RepRapFirmware (its ``M0``
  ends the print), never a pause a firmware does not know.
"""

import math

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.program import (
    PAUSES,
    TestSpec,
    generate,
    is_pause,
    pause_for,
)
from octoprint_kincomp.firmware import junctions
from octoprint_kincomp.firmware.planner import MotionSettings, plan_program

START = (0.0, 0.0, 0.0)
S45 = math.sqrt(0.5)  # sin of half a 90 degree turn


def _plan(text, **kw):
    return plan_program(text.strip().splitlines(), START, MotionSettings(**kw))


def _unit(*vectors):
    U = np.array(vectors, dtype=float)
    return U / np.linalg.norm(U, axis=1)[:, None]


# -- Marlin: junction deviation -------------------------------------------------------------


def test_marlin_jd_corner_uses_the_axes_m201_along_the_change_of_direction():
    """v^2 = a_j JD s / (1 - s); a_j: the block's acceleration capped so that no axis of the
    change of direction exceeds its M201. Two diagonal moves at 90 degrees (M201 X1000
    Y1000, M204 1500): each block accelerates at 1000 / sin 45 = 1414 mm/s^2 (neither axis
    over 1000), but their change of direction is along X alone, so a_j = 1000."""
    limits = {"x": 1000.0, "y": 1000.0, "z": 100.0}

    def jd_plan(text, **kw):
        return _plan(text, planner="marlin", accel_mm_s2=1500.0, junction_deviation_mm=0.013, **kw)

    def corner(a_j):
        return math.sqrt(a_j * 0.013 * S45 / (1 - S45))

    p = jd_plan("G1 X20 Y20 F3000\nG1 X0 Y40", max_accel_mm_s2=limits)
    assert p.v1[0] == pytest.approx(corner(1000.0), rel=1e-9)
    # the block's own acceleration is the cap along its direction
    assert p.a[0] == pytest.approx(1000.0 / S45, rel=1e-9)
    # axis-aligned moves: the block's acceleration (its axis' M201) is already the lower
    aligned = jd_plan("G1 X20 F3000\nG1 Y20", max_accel_mm_s2=limits)
    assert aligned.v1[0] == pytest.approx(corner(1000.0), rel=1e-9)
    free = jd_plan("G1 X20 F3000\nG1 Y20")
    assert free.v1[0] == pytest.approx(corner(1500.0), rel=1e-9)


def test_marlin_small_segments_are_held_to_a_length_over_angle():
    """JD_HANDLE_SMALL_SEGMENTS: a block under 1 mm turning by less than 45 degrees is also
    held to v^2 <= a L / theta, theta Marlin's approximate acos (within 0.033 rad)."""
    t = np.linspace(0.0, 1.0, 201)
    assert np.abs(junctions.marlin_theta(t) - np.arccos(t)).max() <= 0.0331
    U = _unit((1, 0, 0), (math.cos(math.radians(30)), math.sin(math.radians(30)), 0))
    L = np.array([5.0, 0.1])
    acc = np.array([1500.0, 1500.0])
    small = junctions.marlin_jd(U, L, acc, 0.013, None)[0]
    theta = junctions.marlin_theta(np.array([math.cos(math.radians(30))]))[0]
    assert small == pytest.approx(0.1 * 1500.0 / theta, rel=1e-9)
    s = math.sin(math.radians(75))  # half the angle between the extensions (150 deg)
    plain = junctions.marlin_jd(U, L, acc, 0.013, None, small_segments=False)[0]
    assert plain == pytest.approx(1500.0 * 0.013 * s / (1 - s), rel=1e-9)
    assert small < plain
    # 1 mm or longer, or a turn of 45 degrees or more: the plain rule
    assert junctions.marlin_jd(U, np.array([5.0, 1.0]), acc, 0.013, None)[0] == pytest.approx(
        plain, rel=1e-9
    )


def test_marlin_reversal_stops():
    U = _unit((1, 0, 0), (-1, 0, 0))
    assert junctions.marlin_jd(U, np.array([5.0, 5.0]), np.array([1500.0] * 2), 0.013, None)[0] == 0


# -- Marlin: classic jerk -------------------------------------------------------------------


@pytest.mark.parametrize(
    "turn_deg, want_mm_s",
    [(90, 10.0), (45, 10.0 / math.sin(math.radians(45)))],  # Y changes by v sin(turn)
)
def test_marlin_classic_jerk_keeps_each_axis_change_within_m205(turn_deg, want_mm_s):
    """M205 X10 Y10 without J: at the same nominal speed on both sides the junction speed is
    the highest at which no axis' speed changes by more than its jerk (90 degrees: the jerk
    itself; 45: Y's change v sin 45 binds)."""
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    text = f"G1 X20 F3000\nG1 X{20 + 20 * c:.6f} Y{20 * s:.6f}"
    p = _plan(
        text,
        planner="marlin",
        junction_deviation_mm=None,
        jerk_mm_s={"x": 10.0, "y": 10.0, "z": 0.3},
        accel_mm_s2=1500.0,
    )
    assert MotionSettings(junction_deviation_mm=None, jerk_mm_s={"x": 10.0}).classic_jerk
    assert p.v1[0] == pytest.approx(want_mm_s, rel=1e-6)
    # each axis' change at that speed is within its jerk, and one of them at it
    u0, u1 = np.array([1.0, 0.0]), np.array([c, s])
    change = np.abs(u1 - u0) * p.v1[0]
    assert change.max() == pytest.approx(10.0, rel=1e-6)


def test_marlin_classic_jerk_reversal_is_limited_by_the_larger_speed():
    """An axis that reverses changes by the larger of its two speeds (Marlin 2.1.2): a
    reversal at 50 mm/s with X jerk 10 leaves 10 mm/s, not 5."""
    U = _unit((1, 0, 0), (-1, 0, 0))
    v2 = junctions.marlin_jerk(U, np.array([50.0, 50.0]), np.array([10.0, 10.0, 0.3]))[0]
    assert math.sqrt(v2) == pytest.approx(10.0, rel=1e-9)


# -- RepRapFirmware -------------------------------------------------------------------------


@pytest.mark.parametrize("turn_deg", [90, 45, 20])
def test_rrf_m566_jerk_per_drive(turn_deg):
    """M566 X900 Y900 (mm/min: 15 mm/s): v = min over drives of jerk / |change of unit
    direction| (90 degrees: 15 / 1; 45: 15 / sin 45 = 21.2 for Y)."""
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    text = f"G1 X20 F6000\nG1 X{20 + 20 * c:.6f} Y{20 * s:.6f}"
    p = _plan(
        text,
        planner="reprapfirmware",
        jerk_mm_s={"x": 15.0, "y": 15.0, "z": 1.0},
        accel_mm_s2=3000.0,
        junction_deviation_mm=None,
    )
    want = min(15.0 / abs(c - 1.0), 15.0 / s)
    assert p.v1[0] == pytest.approx(want, rel=1e-6)


def test_rrf_never_joins_an_xy_move_to_a_z_only_move():
    """Under RepRapFirmware's default jerk policy (M566 P0) moves of different classes are
    not blended: the head stops between an X move and a Z-only move even where the jerk
    would allow speed."""
    p = _plan(
        "G1 X20 F3000\nG1 Z5\nG1 X40",
        planner="reprapfirmware",
        jerk_mm_s={"x": 15.0, "y": 15.0, "z": 100.0},
        junction_deviation_mm=None,
    )
    assert p.v1[0] == 0.0 and p.v1[1] == 0.0
    # the same junctions under Marlin's classic jerk (Z's jerk high) are not stops
    m = _plan(
        "G1 X20 F3000\nG1 Z5\nG1 X40",
        planner="marlin",
        jerk_mm_s={"x": 15.0, "y": 15.0, "z": 100.0},
        junction_deviation_mm=None,
    )
    assert m.v1[0] > 0.0


# -- acceleration ---------------------------------------------------------------------------


@pytest.mark.parametrize("firmware", ["marlin", "reprapfirmware"])
def test_a_move_with_z_accelerates_within_the_z_axis_m201(firmware):
    """Each move's own acceleration: the base acceleration lowered so that no axis exceeds
    its M201 (a 45 degree XZ move with Z at 100 mm/s^2: 100 / sin 45 along the path;
    RepRapFirmware's M201 box gives the same)."""
    p = _plan(
        "G1 X10 Z10 F600",
        planner=firmware,
        accel_mm_s2=1500.0,
        max_accel_mm_s2={"x": 3000.0, "y": 3000.0, "z": 100.0},
        max_feed_mm_min={"x": 18000.0, "y": 18000.0, "z": 18000.0},
    )
    v = 10.0  # mm/s (F600)
    a = 100.0 / S45
    L = math.sqrt(200.0)
    assert p.duration == pytest.approx(L / v + v / a, rel=1e-9)  # trapezoid from rest to rest


# -- the pause a program writes -------------------------------------------------------------


@pytest.mark.parametrize(
    "firmware, first_word",
    [("marlin", "M0"), ("reprapfirmware", "M291"), ("klipper", "PAUSE"), (None, "M0")],
)
def test_each_firmware_gets_a_pause_it_knows(firmware, first_word):
    """Marlin and any host-driven firmware: M0 (OctoPrint pauses its job there too);
    RepRapFirmware: a blocking message box (M291 S2), never M0, which ends its print;
    Klipper: PAUSE (M0 is unknown to it)."""
    command = pause_for(firmware)
    spec = TestSpec(
        plane="XY",
        centre=(110.0, 110.0, 10.0),
        radius_mm=50.0,
        mount_pause=True,
        pause_command=command,
    )
    text = generate(spec).splitlines()
    pauses = [ln for ln in text if is_pause(ln.split(";")[0].strip())]
    assert len(pauses) == 2 and all(ln.split()[0] == first_word for ln in pauses), pauses
    if first_word == "M291":
        assert all(" S2" in ln for ln in pauses)  # S2: waits for OK (S0/S1 do not block)
    if firmware == "reprapfirmware":
        assert not any(ln.split()[0].upper() in ("M0", "M1") for ln in text if ln.strip())
    assert set(PAUSES) >= {"M0", "PAUSE", "M291"}
