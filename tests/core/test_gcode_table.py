"""The G-code table (core/gcode_table.py): what each code does, that the reference path acts
as the table says, and the check an accelerated engine's own classification must pass."""

import copy

import pytest

from octoprint_kincomp.core import gcode_table as gt
from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.gcode import parse_command
from octoprint_kincomp.core.params import Params

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 500.0}, "backlash": {"x": 40.0}})


@pytest.mark.parametrize(
    "code, cls, value",
    [
        ("G1", gt.LINEAR, None),
        ("g01", gt.LINEAR, None),
        ("G2", gt.ARC, True),
        ("G3", gt.ARC, False),
        ("G90", gt.DISTANCE, True),
        ("G91", gt.DISTANCE, False),
        ("G90.1", gt.ARC_CENTRE, True),
        ("G20", gt.UNITS, True),
        ("G18", gt.PLANE, 18),
        ("M083", gt.EXTRUDER, False),
        ("G92", gt.SET_POSITION, None),
        ("G92.1", gt.DROP_OFFSETS, None),
        ("G28", gt.HOME, None),
        ("G29", gt.LOSES, None),
        ("G38.2", gt.LOSES, None),  # every sub-code of a probing code
        ("M48", gt.LOSES, None),
        ("T3", gt.TOOL, None),
        ("G1.1", gt.VARIANT, None),
        ("G92.2", gt.VARIANT, None),
        ("G4", gt.DWELL, None),
        ("M400", gt.STOP, None),
        ("M0.2", gt.STOP, None),
        ("M104", gt.INERT, None),
        ("G28.1", gt.INERT, None),
        ("M82.1", gt.INERT, None),
        ("G5", gt.INERT, None),  # not listed: inert
    ],
)
def test_classify(code, cls, value):
    cmd = parse_command(code)
    entry = gt.classify(cmd.kind, cmd.number, cmd.sub)
    assert (entry.cls, entry.value) == (cls, value)
    assert gt.classify_code(code) == cls


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
