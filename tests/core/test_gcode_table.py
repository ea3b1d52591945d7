"""The G-code table (core/gcode_table.py): what each code does, that the reference path acts
as the table says, and the check an accelerated engine's own classification must pass."""

import copy

import pytest

from octoprint_kincomp.core import gcode_table as gt
from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.gcode import parse_command
from octoprint_kincomp.core.params import Params

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 500.0}, "backlash": {"x": 40.0}})


# each class and codes the table must give it (as written at the start of a line)
EXPECTED = """linear G1 g01 G0; arc G2 G3; distance G90 G91; arc_centre G90.1 G91.1; units G20
G21; plane G17 G18 g19; extruder M82 M083; set_position G92; drop_offsets G92.1; home G28;
loses_position G29 G38.2 M48 G80.5; tool T3 t0; variant G1.1 G92.2 G0.0; dwell G4; stop M400
M0.2; inert M104 G28.1 M82.1 G5 G4.1"""
CASES = [(code, part.split()[0]) for part in EXPECTED.split(";") for code in part.split()[1:]]


@pytest.mark.parametrize("code, cls", CASES)
def test_classify(code, cls):
    cmd = parse_command(code)
    assert gt.classify(cmd.kind, cmd.number, cmd.sub).cls == cls
    assert gt.classify_code(code) == cls


def test_the_values_of_mode_switches_and_arcs():
    values = {c: gt.classify(c[0], int(c[1:])).value for c in ("G2", "G3", "G18", "M83", "G20")}
    assert values == {"G2": True, "G3": False, "G18": 18, "M83": False, "G20": True}
    assert gt.classify("G", 90, 1).value is True and gt.classify("G", 91, 1).value is False


def test_every_class_belongs_to_a_group():
    assert {e.cls for e in gt.TABLE.values()} <= gt.CLASSES
    assert gt.classify_code("; a comment") is None


def _state(comp):
    st = comp.state
    return copy.deepcopy(
        (
            st.m,
            st.fw,
            st.w,
            st.g,
            st.frame_lost,
            st.absolute,
            st.inches,
            st.plane,
            st.ij_absolute,
            st.e_absolute_mode,
            st.tool,
            st.backlash.dir,
        )
    )


def _after(code):
    """A compensator in a known, moved state; the state before and after ``code X5``."""
    comp = Compensator(SKEW, Options(home_mm=(0.0, 0.0, 0.0)))
    for line in ("G28", "T0", "G1 X10 Y10 Z1 F3000", "G1 X5"):
        comp.process(line)
    before = _state(comp)
    out = comp.process(f"{code} X5")
    return before, _state(comp), out


@pytest.mark.parametrize("code", [*gt.PROBES, "G4", "M104", "M220", "M400", "M1.1"])
def test_the_reference_path_leaves_inert_and_variant_codes_alone(code):
    cls = gt.classify_code(code)
    before, after, out = _after(code)
    if cls in (gt.INERT, gt.DWELL, gt.STOP, gt.VARIANT):
        assert after == before and out == f"{code} X5"
    elif cls in (gt.LOSES, gt.TOOL) and code != "T0":
        assert after[0] == [None, None, None]  # positions forgotten
    else:
        assert cls == gt.TOOL and after == before  # the tool in use: nothing changes


@pytest.mark.parametrize(
    "code, field, want",
    [
        ("G91", 5, False),
        ("G20", 6, True),
        ("G19", 7, 19),
        ("G90.1", 8, True),
        ("M83", 9, False),
    ],
)
def test_the_reference_path_sets_the_mode_the_table_gives(code, field, want):
    before, after, _ = _after(code)
    assert gt.classify_code(code) in gt.REFRAMES
    assert before[field] != want and after[field] == want


def _kernel_like(code):
    """A stand-in of the compiled kernel's choice: it takes "G0".."G3" as written, upper
    case, and hands every other line to the reference path."""
    return {"G0": gt.LINEAR, "G1": gt.LINEAR, "G2": gt.ARC, "G3": gt.ARC}.get(code)


def _tokens_like(code, state_m=("82", "83", "48")):
    """A stand-in of a byte-level engine: G0/G1 by their first two bytes, and any M code
    that starts with a digit 1-9 and is none of ``state_m`` taken as inert."""
    if code in ("G0", "G1"):
        return gt.LINEAR
    if code[0] == "M" and code[1] in "123456789" and code[1:3] not in state_m:
        return gt.INERT
    return None


def test_engines_that_agree_with_the_table_pass():
    assert gt.check_engine(_kernel_like) == []
    assert gt.check_engine(_tokens_like) == []
    assert gt.check_engine(lambda code: None) == []  # declining is always allowed


def test_an_engine_that_misses_a_state_changing_code_is_named():
    problems = gt.check_engine(lambda code: _tokens_like(code, state_m=("82", "48")))
    assert problems == ["M83: the engine takes it as inert, the table says extruder"]


def test_an_engine_that_reads_a_sub_code_as_its_move_is_named():
    def prefix(code):  # "G1.1" and "G1.0" taken for G1
        return gt.LINEAR if code[:2] in ("G0", "G1") and code[2:3] in ("", ".") else None

    problems = gt.check_engine(prefix)
    assert "G1.1: the engine takes it as linear, the table says variant" in problems
    assert "G1.0: the engine takes it as linear, the table says variant" in problems
    assert all(".1" in p or ".0" in p or ".5" in p for p in problems)
