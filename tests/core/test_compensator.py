"""Streaming compensator: modal state, frames, arcs, unknown positions (issue 2)."""

import math

import pytest

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.gcode import parse_command, parse_words
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from tests.support.helpers import (
    Printer,
    compensate_groups,
    desired_positions,
    dist,
    dist_to_polyline,
)

# every test here runs once per engine (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("engine")

SKEW = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": -3638.6, "xz": 420.0, "yz": -250.0},
        "scale_ppm": {"x": -451.7, "y": 287.0, "z": 120.0},
    }
)


def words(line):
    cmd = parse_command(line)
    return {w.letter: w.value for w in parse_words(cmd.body)}


def is_arc(line):
    cmd = parse_command(line)
    return cmd is not None and cmd.kind == "G" and cmd.number in (2, 3) and cmd.sub is None


def run(params, lines, options=None):
    comp, groups = compensate_groups(params, lines, options)
    return comp, [out for _, out in groups]


def assert_lands(params, lines, options=None, tol=1e-6, **fw):
    """Replaying the output on a printer with the true errors lands on every desired point."""
    opts = options or Options(decimals=8)
    comp, groups = compensate_groups(params, lines, opts)
    want = desired_positions(lines, **fw)
    printer = Printer(params, **fw)
    for (line, outs), target in zip(groups, want):
        for o in outs:
            printer.run_line(o)
        got = printer.actual()
        assert dist(got, target) < tol, (line, outs, got, target)
    return comp


def test_zero_params_pass_every_line_object_through():
    comp = make_compensator(Params())
    for line in ["G28", "G1 X10 Y10", "G2 X20 Y10 I5 J0", "G91", "g1 x1", "; c", ""]:
        assert comp.process(line) is line


@pytest.mark.parametrize("code", ["G0", "G1", "G00", "G01", "g1", "g01"])
def test_g0_g1_spellings_are_compensated(code):
    _, outs = run(SKEW, ["G28", f"{code} X10 Y100 Z5"])
    assert outs[0] == ["G28"]
    (line,) = outs[1]
    assert line.split()[0] == code
    w = words(line)
    assert w["X"] != 10 and w["Y"] != 100


def test_y_only_move_also_writes_x_under_xy_skew():
    _, outs = run(SKEW, ["G28", "G1 X10 Y10 Z1", "G1 Y50"])
    w = words(outs[2][0])
    assert set(w) == {"X", "Y"}
    assert w["X"] == pytest.approx(10 + 3638.6e-6 * 50 - 3638.6e-6 * 0, abs=0.2)


def test_e_and_f_words_unchanged_and_comment_kept():
    _, outs = run(SKEW, ["G28", "G1 X10 Y10 Z0.3 E1.23456 F1800 ; perimeter"])
    line = outs[1][0]
    assert "E1.23456" in line and "F1800" in line
    assert line.endswith("; perimeter")


def test_land_on_desired_points_absolute_program():
    assert_lands(
        SKEW,
        ["G28", "G1 X10 Y20 Z0.3 F3000", "G1 X200 Y180 E5", "G0 Z10", "G1 X5.5 Y230.25", "G1 Z0.2"],
    )


def test_g91_output_stays_relative_and_lands():
    lines = [
        "G28",
        "G1 X50 Y50 Z1",
        "G91",
        "G1 X10 Y5",
        "G1 Y-20 Z0.5",
        "G1 X-3.3",
        "G90",
        "G1 X100 Y100",
    ]
    comp, outs = run(SKEW, lines, Options(decimals=8))
    rel = outs[3][0]
    w = words(rel)
    assert abs(w["X"] - 10) < 0.1 and abs(w["Y"] - 5) < 0.1  # deltas, not absolute positions
    assert_lands(SKEW, lines)


def test_g91_rounding_does_not_accumulate():
    lines = ["G28", "G1 X0 Y0 Z1", "G91"] + ["G1 X0.1234 Y0.0567"] * 500 + ["G90"]
    comp, outs = run(SKEW, lines, Options(decimals=3))
    sx = sum(words(o[0])["X"] for o in outs[3:503])
    want = comp.model.inverse((61.7, 28.35, 1.0))[0] - comp.model.inverse((0, 0, 1.0))[0]
    assert abs(sx - want) <= 0.0005 + 1e-9


def test_g92_offsets_and_omitted_axes_and_e0():
    lines = [
        "G28",
        "G1 X100 Y100 Z2",
        "G92 X0 Y0",
        "G1 X10 Y10",
        "G92 E0",
        "G1 X20 E3",
        "G92",
        "G1 X5 Y5 Z1",
        "G92.1",
        "G1 X50 Y60 Z3",
    ]
    comp, outs = run(SKEW, lines)
    assert outs[2] == ["G92 X0 Y0"] and outs[4] == ["G92 E0"] and outs[6] == ["G92"]
    assert_lands(SKEW, lines)


def test_g20_inches():
    lines = ["G28", "G20", "G1 X2 Y3 Z0.1", "G91", "G1 X0.5", "G90", "G21", "G1 X10 Y10"]
    comp, outs = run(SKEW, lines, Options(decimals=8))
    w = words(outs[2][0])
    assert w["X"] == pytest.approx(2.0, abs=0.02)  # still inches on the wire
    assert_lands(SKEW, lines)


def test_homing_never_transformed_and_makes_position_known():
    comp = make_compensator(SKEW)
    assert comp.process("G1 X10 Y10") == "G1 X10 Y10"  # unknown position: untouched
    assert comp.report.untouched_unknown == 1
    assert comp.process("G28 X Y") == "G28 X Y"
    assert comp.known == (True, True, False)
    # xz skew couples X to Z, which is still unknown -> untouched
    assert comp.process("G1 X20") == "G1 X20"
    assert comp.process("G28 Z") == "G28 Z"
    out = comp.process("G1 X20")
    assert out != "G1 X20" and isinstance(out, list)


def test_unknown_axis_not_needed_when_not_coupled():
    p = Params.from_dict({"squareness_um_per_m": {"xy": 500}})
    comp = make_compensator(p)
    comp.process("G28 X Y")
    out = comp.process("G1 X10 Y10")
    assert isinstance(out, list)  # Z unknown but X/Y do not depend on it
    assert "Z" not in out[0]


def test_absolute_move_defines_unknown_position():
    comp = make_compensator(SKEW)
    out = comp.process("G1 X10 Y20 Z5")  # every needed axis is in the line itself
    assert isinstance(out, list)
    assert comp.known == (True, True, True)


def test_relative_move_from_unknown_passes_untouched():
    comp = make_compensator(SKEW)
    comp.process("G91")
    assert comp.process("G1 X5") == "G1 X5"
    assert comp.report.untouched_unknown == 1


@pytest.mark.parametrize(
    "cmd", ["G29", "G29.2 S0", "G30", "G38.2 Z-5", "M48", "G80", "G27", "G380 S3 Z-5 F1200"]
)
def test_probing_passes_untouched_and_forgets_position(cmd):
    comp = make_compensator(SKEW)
    comp.process("G28")
    assert comp.process(cmd) == cmd
    assert comp.known == (False, False, False)


def test_unknown_commands_and_tool_change():
    comp = make_compensator(SKEW)
    comp.process("G28")
    for c in [
        "M104 S200",
        "M620.1 E F523 T240",
        "G2814 Z0.32",
        "M1002 judge_flag x",
        "G4 P100",
        "M117 Hello; world",
    ]:
        assert comp.process(c) is c
    assert comp.known == (True, True, True)
    assert comp.process("T1") == "T1"
    assert comp.known == (False, False, False)


def test_line_numbers_and_checksums_are_stripped_from_rewritten_moves():
    comp = make_compensator(SKEW)
    comp.process("G28")
    out = comp.process("N12 G1 X10 Y10 Z1*77")
    assert isinstance(out, list) and not out[0].startswith("N") and "*" not in out[0]
    assert comp.process("N13 M105*35") == "N13 M105*35"


def test_malformed_motion_lines_pass_and_are_counted():
    comp = make_compensator(SKEW)
    comp.process("G28")
    for bad in ["G1 X10 X20", "G1 X1.2.3", "G1 X", "G1 Xfoo", "G1 X10 #"]:
        assert comp.process(bad) is bad
    assert comp.report.malformed == 5


def test_indentation_is_kept():
    comp = make_compensator(SKEW)
    comp.process("G28")
    out = comp.process("    G1 X10 Y10 Z1")
    assert out[0].startswith("    G1 ")


# -- arcs -----------------------------------------------------------------------------------

ARC_CASES = [
    ["G28", "G92 E0", "G1 X50 Y50 Z1 F3000", "G2 X70 Y50 I10 J0 E1.5"],
    ["G28", "G1 X50 Y50 Z1 F3000", "G3 X70 Y50 I10 J0"],
    ["G28", "G1 X50 Y50 Z1 F3000", "G2 X60 Y60 R10"],
    ["G28", "G1 X50 Y50 Z1 F3000", "G2 X60 Y60 R-10"],
    ["G28", "G1 X50 Y50 Z1 F3000", "G3 X50 Y50 I15 J0"],  # full circle
    ["G28", "G1 X50 Y50 Z1 F3000", "G3 X50 Y50 Z3 I15 J0 P1"],  # helix, two turns
    ["G28", "G1 X50 Y50 Z20 F3000", "G18", "G2 X70 Z20 I10 K0"],
    ["G28", "G1 X50 Y50 Z20 F3000", "G18", "G3 X50 Z20 K5 I0"],
    ["G28", "G1 X50 Y50 Z20 F3000", "G19", "G2 Y70 Z20 J10 K0"],
    ["G28", "G1 X50 Y50 Z20 F3000", "G19", "G3 Y60 Z30 R10"],
    ["G28", "G1 X50 Y50 Z20 F3000", "G91", "G2 X2 Y0 I1 J0", "G2 X-1.5 I-0.75 J0", "G90"],
    ["G28", "G1 X50 Y50 Z20 F3000", "G90.1", "G2 X70 Y50 I60 J50", "G91.1"],
]


@pytest.mark.parametrize("lines", ARC_CASES)
def test_arcs_linearised_and_land_on_the_arc(lines):
    params = SKEW
    opts = Options(decimals=8, chord_tol_mm=0.005, linearise_arcs=True)
    comp, groups = compensate_groups(params, lines, opts)
    # linearised (firmware without arcs): every output of an arc is a G1 chord
    arc_out = [o for line, outs in groups if is_arc(line) for o in outs]
    assert arc_out and all(o.startswith("G1") for o in arc_out)
    assert comp.report.arcs_linearised >= 1
    assert_lands(params, lines, opts)
    # the chord end points, once moved by the true errors, lie on the desired arc
    ideal = Printer(Params(), arc_tol_mm=1e-6)
    printer = Printer(params)
    for line, outs in groups:
        before = ideal.actual()
        want = [before] + ideal.run_line(line)
        got = [p for o in outs for p in printer.run_line(o)]
        if is_arc(line):
            for p in got:
                assert dist_to_polyline(p, want) < 2e-6  # reference sagitta is 1e-6 mm


def test_arc_e_split_relative_sums_exactly():
    lines = ["G28", "M83", "G1 X50 Y50 Z1 F3000", "G2 X70 Y50 I10 J0 E1.23457"]
    comp, groups = compensate_groups(SKEW, lines, Options(decimals=8, linearise_arcs=True))
    outs = groups[3][1]
    es = [words(o)["E"] for o in outs]
    assert len(es) > 10
    assert round(sum(es), 5) == 1.23457
    # E per chord is proportional to the chord's length on the desired path
    pts = desired_positions(lines)[2:3] + [
        comp.model.forward((words(o)["X"], words(o)["Y"], 1.0)) for o in outs
    ]
    lens = [dist(a, b) for a, b in zip(pts, pts[1:])]
    total = sum(lens)
    for e, length in zip(es, lens):
        assert e == pytest.approx(1.23457 * length / total, abs=2e-5)


def test_arc_e_split_absolute_ends_on_written_value():
    lines = ["G28", "M82", "G92 E10", "G1 X50 Y50 Z1 F3000", "G2 X70 Y50 I10 J0 E11.5"]
    _, outs = run(SKEW, lines)
    es = [words(o)["E"] for o in outs[4]]
    assert es[-1] == 11.5 and outs[4][-1].split()[-1] == "E11.5"
    assert all(b > a for a, b in zip(es, es[1:]))
    assert es[0] > 10


def test_arc_with_absolute_e_and_unknown_e_passes_untouched():
    lines = ["G28", "M82", "G1 X50 Y50 Z1 F3000", "G2 X70 Y50 I10 J0 E11.5"]
    comp, outs = run(SKEW, lines)
    assert outs[3] == ["G2 X70 Y50 I10 J0 E11.5"]
    assert comp.report.untouched_unknown == 1


def test_arc_chords_end_where_the_skewed_commands_reverse():
    lines = ["G28", "G1 X50 Y50 Z1 F3000", "G3 X50 Y50 I15 J0"]
    comp, outs = run(SKEW, lines, Options(decimals=8, chord_tol_mm=0.5, linearise_arcs=True))
    pts = [(words(o).get("X"), words(o).get("Y")) for o in outs[2]]
    # commanded X and Y as functions of the arc angle: each chord must be monotonic in both,
    # i.e. every local extreme of the command sequence is a chord end (not inside a chord)
    Ai = comp.model.A_inv
    for k in (0, 1):
        t_star = math.atan2(Ai[k, 1], Ai[k, 0])
        for t in (t_star, t_star + math.pi):
            d = (65 + 15 * math.cos(t), 50 + 15 * math.sin(t), 1.0)
            q = comp.model.inverse(d)
            assert (
                any(
                    x is not None
                    and y is not None
                    and abs(x - q[0]) < 1e-7
                    and abs(y - q[1]) < 1e-7
                    for x, y in pts
                )
                or dist(d, (50, 50, 1)) < 0.01
            )


def test_pure_translation_keeps_arcs():
    p = Params.from_dict({"axis_errors": {"x": {"tx_um": 30.0}}})
    comp, outs = run(p, ["G28", "G1 X10 Y10 Z1", "G2 X20 Y10 I5 J0 E1"])
    (line,) = outs[2]
    assert line.startswith("G2 ") and "I5" in line and "J0" in line and "E1" in line
    assert words(line)["X"] == pytest.approx(20 - 0.03)


def test_malformed_arc_passes_untouched():
    """(An R below half the chord is no longer malformed: Marlin prints the half circle,
    see test_arc_fit; an R arc ending where it starts describes no circle.)"""
    comp, outs = run(SKEW, ["G28", "G1 X0 Y0 Z1", "G2 X0 Y0 R10"])
    assert outs[2] == ["G2 X0 Y0 R10"]
    assert comp.report.malformed == 1


def test_bambu_spiral_lift_full_circle_with_p():
    lines = ["G28", "G1 X100 Y100 Z1 F3000", "G17", "G2 Z1.4 I0.86 J0.86 P1 F20000"]
    assert_lands(SKEW, lines)


def test_arc_chords_respect_the_chord_tolerance():
    from octoprint_kincomp.core import arcs

    for tol in (0.01, 0.002):
        pts = [(50.0, 50.0, 0.0)] + arcs.linearise(
            (50, 50, 0), (50, 50, 0), 17, 70, 50, False, tol, breaks=(0.3, 1.2)
        )
        for p, q in zip(pts, pts[1:]):
            chord = math.dist(p, q)
            sagitta = 20 - math.sqrt(20**2 - (chord / 2) ** 2)
            assert sagitta <= tol * (1 + 1e-9)


def test_g92_on_an_unknown_axis_does_not_invent_a_machine_frame():
    """G92 X0 Y0 before homing says where the program's zero is, not where the machine is:
    the axes' frames are lost, absolute moves on them pass untouched (reported) until G28
    or G92.1 restores them; a known axis (Z here) keeps working through G92 as usual."""
    comp = make_compensator(SKEW)
    comp.process("G1 Z5 F600")  # Z known from an absolute move (firmware frame = homed)
    assert comp.process("G92 X0 Y0") == "G92 X0 Y0"
    assert comp.state.frame_lost == [True, True, False]
    before = comp.report.untouched_unknown
    for line in ("G1 X10 Y100", "G1 X20 Y90 Z6"):
        assert comp.process(line) is line
    assert comp.known == (False, False, True)
    assert comp.report.untouched_unknown == before + 2
    comp.process("G92 Z0")  # a known axis: an ordinary offset
    assert comp.state.frame_lost[2] is False and comp.known[2]
    comp.process("G28 X Y")
    assert comp.state.frame_lost == [False, False, False]
    assert comp.process("G1 X10 Y100") != ["G1 X10 Y100"]  # compensated again
    # G92.1 drops the offsets: the firmware frame is the native one, positions still unknown
    comp2 = make_compensator(SKEW)
    comp2.process("G92 X5")
    comp2.process("G92.1")
    assert comp2.state.frame_lost == [False, False, False] and comp2.known == (False, False, False)
    assert comp2.process("G1 X10 Y100 Z1") != "G1 X10 Y100 Z1"


@pytest.mark.parametrize(
    "run_in",
    [
        ["M83", "G1 X50 Y50 Z1 F3000 E1", "G91", "G1 Z0.2 E-0.5", "G90"],  # G91 moves E too
        ["M83", "G1 X50 Y50 Z1 F3000 E1", "G1 E-0.5", "G91", "G1 Z0.2", "G90"],
        ["G91", "G1 X50 Y50 Z1.2 E0.25", "G1 E0.25", "G90"],  # G91 alone: E relative too
    ],
)
def test_e_is_tracked_through_g90_g91_m82_m83_as_marlin_does(run_in):
    """Issue 28: after M83, a G91 move and G90, E is absolute again (Marlin: G90 clears the
    relative flag of every axis, E's too) and its position is the sum of the relative
    moves since G92 E0; the next arc with E is compensated and split from there (it passed
    untouched: relative E was not summed)."""
    lines = ["G28", "G90", "G92 E0"] + run_in + ["G2 X70 Y50 I10 J0 E3"]
    comp, outs = run(SKEW, lines)
    arc = outs[-1]
    assert comp.report.untouched_unknown == 0 and arc != ["G2 X70 Y50 I10 J0 E3"]
    assert comp.state.e_pos == 3.0
    es = [words(o)["E"] for o in arc if "E" in words(o)]
    assert len(es) > 1 and es[-1] == 3.0
    assert all(b > a for a, b in zip(es, es[1:]))
    # the first piece's E follows from 0.5 (1 - 0.5) by length: more than half of 2.5 needs
    # more than half of the arc
    assert 0.5 < es[0] < 3.0
    assert_lands(SKEW, lines, Options(decimals=8), tol=2e-3)


def test_relative_e_from_an_unknown_position_leaves_it_unknown():
    lines = ["G28", "M83", "G1 X50 Y50 Z1 F3000 E1", "G90", "M82", "G2 X70 Y50 I10 J0 E3"]
    comp, outs = run(SKEW, lines)
    assert outs[-1] == ["G2 X70 Y50 I10 J0 E3"] and comp.report.untouched_unknown == 1
