"""The travel's edges and the move classes (issue 36, items 1 and 2), on every engine.

Each defect found running KinComp's output through real Klipper has a test here: a linearised
arc's apex chord end past the limit, the clamp rounding outward, the Z-only move that forgot
the homed X drive, the play after homing, and a move without X/Y that got X/Y (Klipper then
checks it as an XY extrusion: ``Move exceeds maximum extrusion``).
"""

import pytest

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator

pytestmark = pytest.mark.usefixtures("engine")

# the parameters of the issue's Klipper runs (um/m, ppm, um)
REALISTIC = {
    "squareness_um_per_m": {"xy": 1500.0, "xz": -800.0, "yz": 600.0},
    "scale_ppm": {"x": 300.0, "y": -200.0, "z": 150.0},
    "backlash": {"x": 60.0, "y": 40.0},
}


def run(params, lines, **opts):
    comp = make_compensator(Params.from_dict(params), Options(**opts))
    out = []
    for line in lines:
        got = comp.process(line)
        out += [got] if isinstance(got, str) else got
    return out, comp.report


def coords(lines, letter):
    """Every ``letter`` coordinate written on the move lines (mm)."""
    out = []
    for line in lines:
        if line[:2] in ("G0", "G1", "G2", "G3"):
            out += [float(w[1:]) for w in line.split(";")[0].split()[1:] if w[0] == letter]
    return out


def test_a_linearised_arcs_apex_stays_inside_when_the_source_apex_grazes_the_limit():
    """The benchy's arc whose true apex is 0.6 um past Y 115.983 (Klipper checks only its own
    1 mm segments' ends, which stay inside): its chord end at the apex was written fully
    compensated, Y116.027; a take-up too."""
    limits = (0, 128.602, 0, 115.983, 0, 21.8)
    lines = [
        "G28",
        "G92 E0",
        "G1 X119.859 Y100 Z0.2 F3000",
        "G1 X119.859 Y104.442",
        "G3 X99.174 Y115.967 I-19.805 J-11.221 E1",
        "G1 X75.226 Y114.517 E2",
    ]
    out, rep = run(REALISTIC, lines, limits=limits, home_mm=(0.0, 0.0, 0.0))
    assert max(coords(out, "Y")) <= 115.983
    assert rep.limit_hits >= 1 and rep.limit_worst_axis == "Y"
    # warn sends it as before (and says so)
    out, rep = run(REALISTIC, lines, limits=limits, home_mm=(0.0, 0.0, 0.0), policy="warn")
    assert max(coords(out, "Y")) > 116.0 and rep.limit_hits >= 1


def test_points_the_program_puts_on_the_edge_are_not_pushed_past_it():
    """Bambu's wiper at Y265 on a 265 mm bed and Prusa's purge at Y-3 (a profile that allows
    it): compensation kept them inside; they were written Y265.05 and Y-3.0x."""
    limits = (-5, 250, -3, 265, 0, 250)
    lines = ["G28", "G1 X10 Y10 Z0.3", "G1 X60 Y265", "G1 X51.736 Y254.734", "G1 X5 Y-3 E1"]
    out, rep = run(REALISTIC, lines, limits=limits, home_mm=(0.0, 0.0, 0.0))
    ys = coords(out, "Y")
    assert max(ys) == 265.0 and min(ys) == -3.0
    assert rep.limit_hits >= 2 and rep.limit_worst_um > 40.0
    # past the profile's edge: the travel ends at the program's point, not at the limit
    lines[4] = "G1 X5 Y-4 E1"
    out, rep = run(REALISTIC, lines, limits=limits, home_mm=(0.0, 0.0, 0.0))
    assert min(coords(out, "Y")) == -4.0 and rep.source_outside == 1


def test_the_first_z_move_after_homing_stays_inside():
    """``G28`` / ``G1 Z5 F5000`` at the homed corner: XZ/YZ skew wanted X/Y below 0 (Klipper:
    ``Move out of range: 0.030 -0.020 0.000``, the print ends at line 2)."""
    out, rep = run(
        REALISTIC, ["G28", "G1 Z5 F5000"], limits=(0, 235, 0, 235, 0, 250), home_mm=(0, 0, 0)
    )
    assert min(coords(out, "X") + coords(out, "Y") + [0.0]) >= 0.0
    assert out[-1].startswith("G1 Z") and rep.limit_hits >= 1


ISSUE_ROW = ["G28", "G1 Z0.3", "G1 X10 Y10 E0.1"]
ISSUE_PARAMS = {"squareness_um_per_m": {"xy": -3638.6}, "backlash": {"x": 50.0}}


@pytest.mark.parametrize("limits", [None, (0, 250, 0, 250, 0, 200)])
def test_a_z_move_keeps_the_homed_x_drive(limits):
    """The issue's last row (``--home 250,?,5``): the Z-only move made the compensator forget
    where the homed X drive is, so the first extrusion got no take-up (24.6 um off)."""
    opts = dict(limits=limits, home_mm=(250.0, None, 5.0))
    with_z, _ = run(ISSUE_PARAMS, ISSUE_ROW, **opts)
    without, _ = run(ISSUE_PARAMS, [ISSUE_ROW[0], ISSUE_ROW[2]], **opts)
    assert with_z == [with_z[0], "G1 Z0.3"] + without[1:]
    assert without[-1] == "G1 X10.011 Y10 E0.1"


def test_the_play_after_homing_is_the_homing_approachs():
    """A home on a limit is an endstop the firmware approached last: the play is taken up
    toward it. Moving away takes up the whole play; no take-up toward (or past) the edge."""
    opts = dict(limits=(0, 250, 0, 250, 0, 200), home_mm=(250.0, None, 5.0))
    out, _ = run(ISSUE_PARAMS, ISSUE_ROW, **opts)
    assert out[2] == "G1 X249.95"  # 50 um: the whole play (half of it, unknown direction)
    out, _ = run(ISSUE_PARAMS, ISSUE_ROW, home_mm=(250.0, None, 5.0))
    assert out[2] == "G1 X249.975"
    # homed at X0 and Y0: the skew of the first Z lift points toward the switches there
    out, _ = run(
        REALISTIC,
        ["G28", "G1 Z5", "G1 X100 Y100"],
        limits=(0, 235, 0, 235, 0, 250),
        home_mm=(0,) * 3,
    )
    assert out[1] == "G1 Z4.999"  # no take-up line past X0/Y0
    # moving away: from the switches (X0, Y0, the play toward them) to the geometric start
    # (X 4 um, Y -3 um) with the new direction's offset (X +30 um, Y +20 um)
    assert out[2] == "G1 X0.034 Y0.017"


@pytest.mark.parametrize(
    "source",
    ["G1 Z5 E15 F200", "G1 Z5 E15 F200 ; prime", "G0 Z5", "G1 F200 Z5 E15", "G1 Z5"],
)
def test_a_move_without_xy_stays_without_xy(source):
    """XZ skew alone (-800 um/m): ``G1 Z5 E15 F200`` became ``G1 X140.004 Z5 E15 F200``,
    which Klipper checks as an XY extrusion (1.503 vs 0.640 mm^2: the print stops). The X/Y
    correction goes in a move of its own, before, without E."""
    params = {"squareness_um_per_m": {"xz": -800.0, "yz": 600.0}}
    lines = ["G28", "G1 X140 Y100 Z0.3", source]
    out, _ = run(params, lines, home_mm=(0.0, 0.0, 0.0))
    head = source.split()[0]
    assert out[-2] == head + " X140.004 Y99.997"
    last = out[-1].split(";")[0].split()
    assert last[0] == head and not any(w[0] in "XY" for w in last[1:])
    assert [w for w in last if w[0] in "EF"] == [w for w in source.split() if w[0] in "EF"]
    assert out[-1].endswith("; prime") == source.endswith("; prime")


def test_relative_and_e_only_moves_keep_their_class():
    params = {"squareness_um_per_m": {"xz": -800.0}}
    lines = ["G28", "G1 X140 Y100 Z0.3", "G91", "G1 Z5 E1", "G1 E-0.8", "G90", "G1 E3"]
    out, _ = run(params, lines, home_mm=(0.0, 0.0, 0.0))
    assert out[3:6] == ["G1 X0.004", "G1 Z5 E1", "G1 E-0.8"]
    assert out[-1] == "G1 E3"
    # the X/Y of a move that names X or Y stays on it
    out, _ = run(params, ["G28", "G1 X140 Y100 Z0.3", "G1 X140 Z5 E1"], home_mm=(0, 0, 0))
    assert out[-1] == "G1 X140.004 Z5 E1"
