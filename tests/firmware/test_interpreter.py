"""The firmware interpreter (firmware/interpreter.py) acting on each code as the G-code table
classifies it, and the play of the simulated drives (simulator/play.py)."""

import pytest

from octoprint_kincomp.core import gcode_table
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter
from octoprint_kincomp.simulator.play import Play


def test_play_operator():
    pl = Play(Params.from_dict({"backlash": {"x": 100.0}}))
    assert pl.carriage(0, 0.0) == 0.0
    assert pl.carriage(0, 1.0) == pytest.approx(1.0 - 0.05)
    assert pl.carriage(0, 0.95) == pytest.approx(0.95)  # inside the play: carriage stays
    assert pl.carriage(0, 0.92) == pytest.approx(0.95)
    assert pl.carriage(0, 0.5) == pytest.approx(0.55)


def _interpreter_state(fw):
    return (
        list(fw.machine),
        list(fw.g),
        fw.absolute,
        fw.inches,
        fw.plane,
        fw.ij_absolute,
        fw.e_abs_mode,
        fw.e,
    )


def _interpreter_after(code):
    fw = FirmwareInterpreter(home_mm=(0.0, 0.0, 0.0))
    list(fw.run(["G28", "G92 X2", "G1 X10 Y10 Z1 E1 F3000"]))
    before = _interpreter_state(fw)
    events = fw.execute(f"{code} X5")
    return before, _interpreter_state(fw), events


@pytest.mark.parametrize(
    "code, field, want",
    [("G91", 2, False), ("G20", 3, True), ("G19", 4, 19), ("G90.1", 5, True), ("M83", 6, False)],
)
def test_the_interpreter_sets_the_mode_the_table_gives(code, field, want):
    before, after, events = _interpreter_after(code)
    assert before[field] != want and after[field] == want and events == []


def test_the_interpreter_drops_the_offsets_on_g92_1():
    before, after, _ = _interpreter_after("G92.1")
    assert before[1] == [2.0, 0.0, 0.0] and after[1] == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("code", [*gcode_table.PROBES, "M104", "M220", "M400", "G29", "M48"])
def test_the_interpreter_ignores_what_it_does_not_run(code):
    """Codes the table calls inert, variants, probing and tool changes command nothing."""
    assert gcode_table.classify_code(code) not in gcode_table.MOVES | gcode_table.REFRAMES
    before, after, events = _interpreter_after(code)
    assert after == before and events == []
