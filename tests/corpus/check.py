"""The invariants a compensated real slicer file must hold (issue 28), checked on the
project's own models: the firmware interpreter (firmware/interpreter.py) for what a line commands,
the printer with the true errors and play (tests/support/helpers.Printer) for where the
nozzle lands.

Per input line of a program compensated line by line on the reference path:

* a line that is not a G0-G3 move is written as it is, in its place;
* the extrusion of each input move (mm of filament, from the E words as Marlin reads them) is
  the extrusion of its output lines;
* every compensated move (not passed as written for an unknown position) ends, on the printer
  with the errors, within ``chord_tol_mm`` plus the output resolution of its commanded point
  (plus, for an axis whose backlash direction is not known when the move starts, which is
  the first move from an unknown position, half its backlash: no take-up can be judged
  there, the carriage lags wherever the play happened to be; and, after its direction was
  judged from such a state, half its backlash less what the axis has travelled since, until
  it has travelled that far or reversed: see :func:`unsettled_lag`);
* no output move of no length extrudes (or carries F alone) where the input move had length;
* the output has at most ``growth`` times the lines of the input.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Tuple

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.gcode import parse_command
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Move
from tests.support.helpers import Printer, dist, still_extruding

TRUE_HOME = (0.0, 0.0, 0.0)  # where the simulated printer homes (mm)


@dataclass
class Findings:
    lines: int = 0
    lines_out: int = 0
    checked_moves: int = 0
    max_deviation_mm: float = 0.0  # of moves whose backlash directions were known
    max_first_deviation_mm: float = 0.0  # of moves with an axis of unknown direction
    worst: Optional[Tuple[int, str, List[str], float]] = None
    reordered: List[Tuple[int, str, List[str]]] = field(default_factory=list)
    extrusion: List[Tuple[int, str, float, float]] = field(default_factory=list)
    zero_length: List[Tuple[str, str]] = field(default_factory=list)

    @property
    def growth(self) -> float:
        return self.lines_out / max(1, self.lines)


def named_axes(line: str) -> bool:
    """Whether a move line names X, Y or Z (outside its comment)."""
    return any(w[:1] in "XYZxyz" for w in line.split(";")[0].split()[1:])


def is_move(line: str) -> bool:
    cmd = parse_command(line)
    return cmd is not None and cmd.kind == "G" and cmd.number <= 3 and cmd.sub is None


def compensate(params: Params, lines: List[str], options: Options):
    """The reference path (no accelerated engine): (compensator, [(line, [out lines],
    whether it was compensated)])."""
    comp = Compensator(params, options)
    groups, m_after = [], []
    for line in lines:
        before = comp.report.untouched_unknown
        dirs = tuple(comp.state.backlash.dir)
        out = comp.process(line)
        outs = [line] if out is line else list(out)
        groups.append((line, outs, comp.report.untouched_unknown == before, dirs))
        m_after.append(tuple(comp.state.m))
    return comp, groups, m_after


def unsettled_lag(lag: float, travelled: float) -> float:
    """How far (mm) a carriage may still be from its point when its axis' backlash direction
    was unknown and has since been judged (a take-up of ``lag``, half the backlash, mm) and
    the axis has travelled ``travelled`` mm from where it was then, without reversing.

    The play's side was unknown: the carriage was anywhere within ``lag`` of the drive. The
    compensator, judging direction +1 (say) on a retreat of L, commands the point plus
    ``lag``: the drive moves L + ``lag``, which pushes the carriage onto the point unless the
    play sat on the other side, where the carriage stays up to ``lag - L`` beyond it (any
    other choice leaves up to ``lag``). It stays there while the axis stands still (a Z move
    under XZ skew nudging X by 0.3 um, then moves of other axes: BambuStudio's nozzle load
    line); travel of ``lag`` in that direction or a reversal (a take-up of the whole
    backlash) puts it on its point."""
    return max(0.0, lag - travelled)


def check(params: Params, lines: List[str], options: Options, with_groups: bool = False):
    """The :class:`Findings` of ``lines`` (and the reference path's groups if
    ``with_groups``)."""
    comp, groups, m_after = compensate(params, lines, options)
    f = Findings(lines=len(lines), lines_out=sum(len(g[1]) for g in groups))
    tol = options.chord_tol_mm + 10.0**-options.decimals
    bl = comp.backlash
    lag = [
        bl.half * max(um for _, um in bl.tables[k].points) if bl.active[k] else 0.0
        for k in range(3)
    ]
    # (the play follows the drive along each written arc: cut finely enough that it turns
    # where the drive turns; the E sums and the end points do not depend on the cut)
    want = FirmwareInterpreter(home_mm=TRUE_HOME, arc_tol_mm=0.05)
    printer = Printer(params, home_mm=TRUE_HOME, arc_tol_mm=0.001)
    # per axis judged from an unknown direction and not yet settled (see unsettled_lag):
    # [where it was when its direction was unknown (mm), travelled since (mm), direction]
    unsettled: List[Optional[List[float]]] = [None, None, None]
    for i, (line, outs, compensated, dirs) in enumerate(groups):
        move = is_move(line)
        if not move and outs != [line]:
            f.reordered.append((i + 1, line, outs))
        for k in range(3):
            u = unsettled[k]
            if dirs[k] == 0:
                unsettled[k] = [want.machine[k], 0.0, 0]
            elif u is not None and u[2] == 0:
                u[2] = dirs[k]
            elif u is not None and dirs[k] != u[2]:
                unsettled[k] = None  # reversed: the take-up of the whole play settles it
        asked = [ev for ev in want.execute(line) if isinstance(ev, Move)]
        for k in range(3):
            u = unsettled[k]
            if u is not None:
                u[1] = max(u[1], abs(want.machine[k] - u[0]))
                if u[1] >= lag[k]:
                    unsettled[k] = None
        e_want = sum(ev.e for ev in asked)
        had_length = any(dist(ev.start, ev.end) > 0 for ev in asked)
        e_got = 0.0
        for o in outs:
            printer.run_line(o)
            e_got += sum(ev.e for ev in printer.events if isinstance(ev, Move))
            if had_length and still_extruding(o, printer.events, len(outs)):
                f.zero_length.append((line, o))
        if abs(e_got - e_want) > 1e-4:
            f.extrusion.append((i + 1, line, e_want, e_got))
        if move and compensated and named_axes(line) and None not in m_after[i]:
            d = dist(printer.actual(), want.machine)
            f.checked_moves += 1
            first = (
                sum(
                    (lag[k] if dirs[k] == 0 else unsettled_lag(lag[k], unsettled[k][1])) ** 2
                    for k in range(3)
                    if dirs[k] == 0 or unsettled[k] is not None
                )
                ** 0.5
            )
            if first > 0.0:
                f.max_first_deviation_mm = max(f.max_first_deviation_mm, d)
            elif d > f.max_deviation_mm:
                f.max_deviation_mm = d
            if d > tol + first and (f.worst is None or d > f.worst[3]):
                f.worst = (i + 1, line, outs, d)
    return (f, groups) if with_groups else f
