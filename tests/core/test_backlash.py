"""Backlash state machine: take-up moves, smoothing, per-side values (issue 2)."""

import pytest

from octoprint_kincomp.core.backlash import BacklashTracker, deadband_steps
from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.gcode import parse_command, parse_words
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from tests.core.test_compensator import assert_lands
from tests.support.helpers import (
    Printer,
    compensate_groups,
    desired_positions,
    dist,
    printed,
)

# every test here runs once per engine (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("engine")

BL = Params.from_dict({"backlash": {"x": 40.0, "y": 25.0}})
PER_SIDE = Params.from_dict(
    {
        "backlash": {
            "x": [{"at_mm": 10, "um": 37.4}, {"at_mm": 210, "um": 4.4}],
            "y": [{"at_mm": 10, "um": 5.4}, {"at_mm": 210, "um": 11.3}],
        },
        "squareness_um_per_m": {"xy": -3638.6},
        "scale_ppm": {"x": -451.7, "y": 287},
    }
)
ZIGZAG = [
    "G28",
    "G1 X10 Y10 Z0.3 F3000",
    "G1 X100 Y10",
    "G1 X100 Y20",
    "G1 X10 Y20",
    "G1 X10 Y30",
    "G1 X100 Y30",
    "G1 X55 Y5",
    "G1 X210 Y210",
    "G1 X10 Y10",
]


def xs(line):
    cmd = parse_command(line)
    return {w.letter: w.value for w in parse_words(cmd.body)}


def test_immediate_takeup_inserts_a_move_at_the_reversal():
    comp, groups = compensate_groups(BL, ZIGZAG)
    outs = dict(groups)
    # X reverses on "G1 X10 Y20": a take-up line (no E, only X) comes first
    take, move = outs["G1 X10 Y20"]
    assert set(xs(take)) == {"X"}
    # take-up is the full backlash (from +b/2 to -b/2)
    before = xs(outs["G1 X100 Y10"][-1])["X"]
    assert before - xs(take)["X"] == pytest.approx(0.040, abs=1e-3)
    assert comp.report.takeup_moves >= 3


def test_immediate_takeup_lands_on_every_point():
    assert_lands(BL, ZIGZAG)
    assert_lands(PER_SIDE, ZIGZAG)


def test_per_side_values_are_the_local_step():
    p = Params.from_dict(
        {"backlash": {"x": [{"at_mm": 10, "um": 37.4}, {"at_mm": 210, "um": 4.4}]}}
    )
    comp = make_compensator(p, Options(decimals=6))
    comp.process("G28")
    first = comp.process("G1 X210 Y0 Z1")
    # from home (direction unknown) the +X move ends on +b/2, b taken at X=210: 4.4 um
    assert xs(first[-1])["X"] == pytest.approx(210 + 0.0044 / 2, abs=1e-6)
    out = comp.process("G1 X10")  # reversal at X=210: step 4.4 um
    assert xs(out[0])["X"] == pytest.approx(210 - 0.0044 / 2, abs=1e-6)
    out = comp.process("G1 X210")  # reversal at X=10: step 37.4 um
    assert xs(out[0])["X"] - (10 - 0.0374 / 2) == pytest.approx(0.0374, abs=1e-6)


def test_fraction_scales_the_takeup():
    half = Params.from_dict({"backlash": {"x": 40.0, "fraction": 0.5}})
    comp = make_compensator(half, Options(decimals=6))
    comp.process("G28")
    comp.process("G1 X50 Y0 Z1")
    a = xs(comp.process("G1 X10")[0])["X"]
    assert a == pytest.approx(50 - 0.010, abs=1e-9)  # offset went from +10 um to -10 um


def test_deadband_ignores_float_noise_but_not_real_reversals():
    comp = make_compensator(BL, Options(decimals=8))
    comp.process("G28")
    comp.process("G1 X50 Y0 Z1")
    out = comp.process("G1 X49.9999999997")
    assert len(out) == 1  # 0.3 nm: float noise, no take-up
    out = comp.process("G1 X49.999")
    assert len(out) == 2  # 1 um back is a real reversal: the carriage would stay in the play


def test_the_default_deadband_ignores_retreats_far_below_a_step():
    """Issue 28: an X retreat of 7 nm (a BambuStudio helix) cost a take-up, a sliver and a
    take-up back; the deadband is a twentieth of a step, of the printer's step size when
    given, else of a typical 80 steps/mm (0.625 um). A 1 um retreat is still taken up."""
    assert Options().deadband_mm == pytest.approx(0.000625)
    assert Options(steps_per_mm=80).deadband_mm == pytest.approx(0.000625)
    assert Options(steps_per_mm=100).deadband_mm == pytest.approx(0.0005)
    assert Options(steps_per_mm=400, deadband_mm=0.002).deadband_mm == 0.002
    for bad in (0, -80, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            Options(steps_per_mm=bad)
    step80 = dict(decimals=8, steps_per_mm=80)
    for opts, retreat, lines in (
        (Options(**step80), 0.000007, 1),
        (Options(**step80), 0.0006, 1),
        (Options(**step80), 0.001, 2),
        (Options(decimals=8), 0.000007, 1),
        (Options(decimals=8), 0.001, 2),
        (Options(decimals=8, steps_per_mm=1000), 0.0006, 2),
        (Options(decimals=8, deadband_mm=1e-6), 0.000007, 2),
    ):
        comp = make_compensator(BL, opts)
        comp.process("G28")
        comp.process("G1 X50 Y0 Z1")
        assert len(comp.process(f"G1 X{50 - retreat:.6f}")) == lines, (opts, retreat)


def test_the_deadband_is_derived_from_the_finer_of_the_x_and_y_drives():
    assert deadband_steps({"x": 80.0, "y": 160.0, "z": 400.0}) == 160.0
    assert deadband_steps({"x": 100.0}) == 100.0
    assert deadband_steps({"z": 400.0}) is None and deadband_steps({}) is None


def test_sub_deadband_steps_cannot_add_up_to_an_untaken_reversal():
    """The deadband is a hysteresis around the farthest command reached, not a per-step
    threshold: 0.4 nm retreats one after another are a reversal once they pass 1 nm in all
    (a deadband of 1 nm set here; the default is derived from the step size)."""
    t = BacklashTracker(BL, deadband_mm=1e-6)
    assert t.detect_reversals((0, 0, 0), (10, 0, 0), (0, 0, 0)) == [0]
    x, revs = 10.0, []
    for _ in range(10):
        revs.append(t.detect_reversals((x, 0, 0), (x - 4e-7, 0, 0), (x, 0, 0)))
        x -= 4e-7
    # steps 1 and 2 reach -0.8 nm (inside the deadband), step 3 reaches -1.2 nm: reversal
    assert revs[:2] == [[], []] and revs[2] == [0] and t.dir[0] == -1
    assert all(r == [] for r in revs[3:])  # then simply moving on in -X
    # moving forward within the deadband of the extreme is no reversal either
    assert t.detect_reversals((x, 0, 0), (x + 9e-7, 0, 0), (x, 0, 0)) == []
    assert t.detect_reversals((x, 0, 0), (x + 1.1e-6, 0, 0), (x, 0, 0)) == [0]


def test_first_move_after_homing_under_skew_is_judged_from_the_home_command():
    """G28 X at Z=50 with XZ skew: the drive sits at the home command 0 while the X command
    for X=0 is -0.25 mm. The next move drives X from 0 to -0.25 - b/2, a -X move from a
    reset direction, and so it needs the take-up (judging it from inverse(home) saw no
    step and left the carriage b/2 = 50 um off). The take-up starts where the drive is
    (the home command: b/2 to -0.05 mm), the move then carries the skew correction."""
    p = Params.from_dict({"squareness_um_per_m": {"xz": 5000.0}, "backlash": {"x": 100.0}})
    lines = ["G28", "G1 X0 Y0 Z50", "G28 X", "G1 Y10"]
    comp, groups = compensate_groups(p, lines, Options(decimals=6))
    take, move = groups[-1][1]  # a take-up move, then the move
    assert set(xs(take)) == {"X"} and xs(take)["X"] == pytest.approx(-0.05, abs=1e-6)
    assert xs(move)["X"] == pytest.approx(-0.25 - 0.05, abs=1e-6)
    assert dist(printed(p, groups).actual(), (0, 10, 50)) < 2e-6


def test_smoothing_spreads_takeup_over_following_path():
    p = Params.from_dict({"backlash": {"x": 40.0, "smoothing_mm": 2.0}})
    comp, groups = compensate_groups(
        p, ["G28", "M83", "G1 X50 Y0 Z1 F3000", "G1 X40 E1", "G1 X30 E1"], Options(decimals=6)
    )
    outs = dict(groups)
    first = outs["G1 X40 E1"]
    # no take-up move; the reversing move is split where the 2 mm ramp ends
    assert len(first) == 2
    a, b = xs(first[0]), xs(first[1])
    assert a["X"] == pytest.approx(48 - 0.020, abs=1e-6)  # ramp finished after 2 mm
    assert b["X"] == pytest.approx(40 - 0.020, abs=1e-6)
    # E split in proportion to the path: 2 mm of 10 mm
    assert a["E"] + b["E"] == pytest.approx(1.0, abs=1e-9) and a["E"] == pytest.approx(0.2)
    assert comp.report.takeup_moves == 0
    # after the ramp the printer lands exactly again
    assert dist(printed(p, groups).actual(), (30, 0, 1)) < 1e-6


def test_smoothing_ramp_spanning_several_moves():
    p = Params.from_dict({"backlash": {"y": 30.0, "smoothing_mm": 5.0}})
    lines = ["G28", "G1 X0 Y50 Z1", "G1 Y49", "G1 Y48", "G1 Y47", "G1 Y46", "G1 Y45", "G1 Y40"]
    comp, groups = compensate_groups(p, lines, Options(decimals=6))
    ys = [xs(o)["Y"] for _, outs in groups[2:] for o in outs]
    offsets = [y - d for y, d in zip(ys, [49, 48, 47, 46, 45, 40])]
    # ramp from +15 um to -15 um over 5 mm of travel: -3 um... then -15 um
    assert offsets == pytest.approx([0.009, 0.003, -0.003, -0.009, -0.015, -0.015], abs=1e-9)


def test_backlash_on_arcs_reverses_at_quadrants():
    """Exact landing with a 1 nm deadband; with the default (a twentieth of a step, issue
    28) a retreat below it is not taken up and the carriage lands within it."""
    lines = ["G28", "G92 E0", "G1 X100 Y100 Z1 F3000", "G2 X100 Y100 I20 J0 E3"]
    comp = assert_lands(PER_SIDE, lines, Options(decimals=8, deadband_mm=1e-6))
    assert comp.report.takeup_moves >= 3
    opts = Options(decimals=8, steps_per_mm=80)
    assert_lands(PER_SIDE, lines, opts, tol=opts.deadband_mm + 1e-6)


def test_backlash_in_relative_mode():
    lines = [
        "G28",
        "G1 X50 Y50 Z1",
        "G91",
        "G1 X10",
        "G1 X-5",
        "G1 Y3",
        "G1 Y-8 X2",
        "G90",
        "G1 X10 Y10",
    ]
    assert_lands(PER_SIDE, lines)


def test_homing_resets_direction():
    t = BacklashTracker(BL)
    t.detect_reversals((0, 0, 0), (10, 0, 0), (0, 0, 0))
    assert t.dir[0] == 1
    t.reset([0])
    assert t.dir[0] == 0 and t.target(0, 5.0) == 0.0


def test_partial_homing_under_skew_starts_the_next_move_where_the_drives_are():
    """G28 Y under XY skew: X's drive stays put while the command of X's desired position
    jumps with Y (X's command depends on Y). The next move must start from the drive, not
    from that command: from there X continues in -X and needs no take-up, and a take-up of
    another axis must not drag X to the jumped command first (found by the property
    tests: 36 to 100 um off on a printer with play)."""
    p = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -3000.0, "xz": -3000.0},
            "backlash": {"x": 100.0, "y": 100.0, "z": 60.0},
        }
    )
    lines = [
        "G28",
        "G1 X50 Y100 Z10",
        "G1 X0 Y100 Z0",
        "G28 Y Z",
        "G1 Z30",
        "G1 X20",
        "G28 X",
        "G1 Y0",
    ]
    comp, groups = compensate_groups(p, lines, Options(decimals=6))
    printer = Printer(p)
    for (line, outs), want in zip(groups, desired_positions(lines)):
        for o in outs:
            printer.run_line(o)
        if line.startswith("G1"):
            assert dist(printer.actual(), want) < 2e-6, (line, outs)
    after_home = dict(groups)["G1 Z30"]
    # no take-up drags X: X moves only in the X/Y move of its own before the Z move (the Z
    # move keeps its class, issue 36), to the command of the new point
    assert after_home[-1].startswith("G1 Z") and after_home[-2].startswith("G1 X")
    assert all("X" not in xs(o) for o in after_home[:-2])


@pytest.mark.parametrize(
    "home, apart",
    [
        ((0.0, 200.0, 0.0), ["G28 X", "G28 Y", "G28 Z"]),  # X homed while Y is unknown
        ((0.0, 0.0, 0.0), ["G28 X", "G28 Y"]),
    ],
)
def test_homing_axes_one_by_one_leaves_the_drives_where_one_g28_does(home, apart):
    """Review finding: a second partial G28 forgot where the first had left the drives."""
    p = Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}, "backlash": {"x": 100.0}})
    o = Options(home_mm=home)
    pre = ["G28", "G1 X10 Y100 Z5"]
    together = " ".join(["G28"] + [line[-1] for line in apart])
    _, a = compensate_groups(p, pre + [together, "G1 X5 Y10 Z1"], o)
    _, b = compensate_groups(p, pre + apart + ["G1 X5 Y10 Z1"], o)
    assert b[-1][1] == a[-1][1]


def test_the_printer_with_play_lands_after_homing_axes_one_by_one():
    p = Params.from_dict(
        {"squareness_um_per_m": {"xy": 2000.0}, "backlash": {"x": 100.0, "y": 40.0}}
    )
    lines = [
        "G28",
        "G1 X45.381 Y59.404",
        "G1 X10.303 Y122.670",
        "G1 X37.939 Y104.742",
        "G28 X",
        "G28 Y",
        "G1 X0.082 Y96.494",
    ]
    _, groups = compensate_groups(p, lines, Options(decimals=6))
    assert dist(printed(p, groups).actual(), desired_positions(lines)[-1]) < 2e-6


def test_a_move_passed_as_written_keeps_the_drive_state_of_the_axes_it_needs():
    """Issue 28 (the worst of the corpus run): with Z's home unknown, a move that passes as
    written because Y's command needs Z moves the Y drive in +Y (its carriage lags b/2); the
    Z move after it must keep that offset, not start Y from a forgotten direction."""
    p = Params.from_dict({"squareness_um_per_m": {"yz": 500.0}, "backlash": {"y": 30.0}})
    lines = ["G90", "M83", "G28", "G1 X0 Y95 F9000", "G1 Z0.05", "G1 X10 Y100 E1"]
    _, groups = compensate_groups(p, lines, Options(home_mm=(None, 0.0, None), decimals=6))
    assert groups[3][1] == ["G1 X0 Y95 F9000"]  # untouched: Y needs Z
    printer = Printer(p)
    for (line, outs), want in zip(groups, desired_positions(lines)):
        for o in outs:
            printer.run_line(o)
        if line in ("G1 Z0.05", "G1 X10 Y100 E1"):
            assert dist(printer.actual(), want) < 2e-6, (line, outs)


def test_an_axis_a_passed_move_does_not_name_keeps_its_drive_and_offset():
    """Home known for X and Z only (``--home 250,?,5``) under XY and XZ skew with X
    backlash: a Z move passes as written (X's command needs the unknown Y); X's drive is
    still at its home command and the first XY move must judge X's take-up from there (it
    landed b/2 = 25 um off)."""
    p = Params.from_dict(
        {"squareness_um_per_m": {"xy": 2000.0, "xz": 1000.0}, "backlash": {"x": 50.0}}
    )
    lines = ["G28", "G1 Z10", "G1 X200 Y100", "G1 X220 Y120", "G1 X210 Y90"]
    _, groups = compensate_groups(p, lines, Options(home_mm=(250.0, None, 5.0), decimals=6))
    assert groups[1][1] == ["G1 Z10"]  # untouched: X's command needs Y
    home = (250.0, 0.0, 5.0)
    printer = Printer(p, home_mm=home)
    for (line, outs), want in zip(groups, desired_positions(lines, home_mm=home)):
        for o in outs:
            printer.run_line(o)
        if line.startswith("G1 X"):
            assert dist(printer.actual(), want) < 2e-6, (line, outs)
