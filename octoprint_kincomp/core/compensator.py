"""The streaming compensator: G-code line in, compensated line(s) out, O(1) memory.

One engine serves the OctoPrint queuing hook, the upload preprocessor and the command line.

Frames (all in mm internally):

* logical ``L``: what the program writes (after G20 inch conversion);
* desired machine position ``m = L - w`` where ``w`` is the program's G92 offset: the homed
  frame in which the calibration holds;
* commanded machine position ``c = inverse(m) + backlash offset (+ servo lead)``;
* firmware coordinate ``fw = c + g`` where ``g`` is the firmware's own G92 offset. This is what
  is written on the output lines (divided by 25.4 in G20 mode).

With all-zero parameters ``c == m`` and ``g == w``, so ``fw == L`` and every line passes
unchanged. G92 lines are never rewritten; their effect is tracked in ``w`` and ``g``.

A move is compensated when every axis it needs has a known position; otherwise it passes
untouched and is counted in the report (``untouched_unknown``). Homing (G28) makes the homed
axes known at ``home_mm`` (None for an axis: where the firmware homes it is not known, so it
stays unknown until :meth:`Compensator.homed_at` learns it or an absolute move names it; a Z
move right after G28 then goes out as written instead of dragging X and Y to an assumed
home: the plugin and the command line default to that); probing and other commands that move
the head on their own make positions unknown again; tool changes too (hotend offsets).

Absent other information the firmware frame is taken as the homed frame (``g == 0``): an
absolute move from an unknown position has a known target. A G92 on an axis whose position is
unknown shifts the firmware frame by an unknown amount, so that axis' frame is *lost*: its
absolute coordinates no longer give machine positions until G28 (or G92.1, which drops the
offsets) restores it; a position is never invented.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple, Union

from .arcpath import ArcWriter
from .backlash import DEFAULT_DEADBAND_MM, BacklashTracker, deadband_for
from .compensation_errors import CompensationError, LimitError
from .gcode import parse_command, parse_words
from .gcode_table import (
    ARC,
    ARC_CENTRE,
    DISTANCE,
    DROP_OFFSETS,
    EXTRUDER,
    HOME,
    LINEAR,
    LOSES,
    PLANE,
    SET_POSITION,
    TOOL,
    UNITS,
    classify,
)
from .kinematics import KinematicModel, changes_nothing
from .modal import home, homed_axes, reset_offsets, set_position
from .moves import MoveHandler
from .params import AXES, Params
from .path import PathWriter
from .state import Report, StreamState

__all__ = ["Compensator", "CompensationError", "LimitError", "Options", "Report", "POLICIES"]

MM_PER_INCH = 25.4
POLICIES = ("warn", "clamp", "error")


@dataclass
class Options:
    """Engine options that are not part of the machine model.

    ``limits``: (x0, x1, y0, y1, z0, z1) mm in the homed machine frame, or None;
    ``policy``: what happens when compensation pushes a point outside the limits (the
    printer's travel): ``clamp`` (the default: keep the commanded point on the limit, its
    text rounded toward the inside, and count the shortfall), ``warn`` (count it, send it)
    or ``error`` (raise :class:`LimitError`). A point the program itself places on or past
    a limit marks where the travel really ends there: compensation does not push it
    further out, nor pull it in (``core/path.py`` ``PathWriter.limit``).
    ``chord_tol_mm``: how far a written arc or chord may deviate from the desired arc;
    ``linearise_arcs``: write every G2/G3 as G1 chords (firmware without arc support).
    ``home_mm``: per axis where G28 leaves it (mm, machine frame), None: not known (see the
    module docstring; the library default 0,0,0 suits the simulator's printers, not every
    real one).
    ``steps_per_mm``: the printer's resolution (steps per mm) from which the reversal
    deadband is derived (``backlash.deadband_for``: a twentieth of a step; None: a typical
    80 steps/mm, 0.625 um); ``deadband_mm`` (mm) sets the deadband itself instead.
    """

    chord_tol_mm: float = 0.01
    limits: Optional[Tuple[float, float, float, float, float, float]] = None
    policy: str = "clamp"
    decimals: int = 3
    home_mm: Tuple[Optional[float], Optional[float], Optional[float]] = (0.0, 0.0, 0.0)
    deadband_mm: Optional[float] = None
    steps_per_mm: Optional[float] = None
    g90_influences_extruder: bool = True
    linearise_arcs: bool = False

    def __post_init__(self):
        if self.policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}")
        if not (1e-5 <= self.chord_tol_mm <= 1.0):
            raise ValueError("chord_tol_mm must be within 0.00001..1 mm")
        if not (3 <= self.decimals <= 8):
            raise ValueError("decimals must be within 3..8")
        if self.limits is not None:
            lim = tuple(float(v) for v in self.limits)
            if len(lim) != 6 or any(not math.isfinite(v) for v in lim):
                raise ValueError("limits needs six finite numbers x0,x1,y0,y1,z0,z1")
            if lim[0] >= lim[1] or lim[2] >= lim[3] or lim[4] >= lim[5]:
                raise ValueError("limits must be given as min,max pairs with min < max")
            self.limits = lim
        if self.steps_per_mm is not None and not (
            isinstance(self.steps_per_mm, (int, float))
            and math.isfinite(self.steps_per_mm)
            and self.steps_per_mm > 0
        ):
            raise ValueError("steps_per_mm must be a number above 0")
        if self.deadband_mm is None:
            self.deadband_mm = (
                DEFAULT_DEADBAND_MM
                if self.steps_per_mm is None
                else deadband_for(self.steps_per_mm)
            )
        elif not (math.isfinite(self.deadband_mm) and 0 <= self.deadband_mm <= 0.1):
            raise ValueError("deadband_mm must be within 0..0.1 mm")
        home_mm = tuple(self.home_mm)
        if len(home_mm) != 3 or any(
            v is not None
            and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v))
            for v in home_mm
        ):
            raise ValueError("home_mm needs three finite numbers or None (unknown)")
        self.home_mm = tuple(None if v is None else float(v) for v in home_mm)


class Compensator:
    """Streaming G-code compensator (see the module docstring for frames and conventions).

    ``process(line)`` takes one line without its line ending and returns either the very same
    string object (unchanged) or a list of replacement lines (possibly one).

    ``fast``: an accelerated line engine for this model (``engines.select`` makes it), or
    None. It is offered every line first and either writes exactly what this reference path
    would write or declines with the state untouched. While it takes lines it holds the
    stream state itself; it hands it back into :attr:`state` before it declines one and
    whenever :attr:`state` is read (``release()``). The tests prove every engine equal to
    this path, byte for byte.
    """

    def __init__(self, params: Params, options: Optional[Options] = None, fast=None):
        self.params = params
        self.options = options or Options()
        self.fast = fast
        self.model = KinematicModel(params)
        self._state = StreamState()
        self.backlash = BacklashTracker(params, self._state.backlash, self.options.deadband_mm)
        self.servo_s = (
            [params.servo_lag_ms[a] * 1e-3 for a in AXES] if params.has_servo_precomp else None
        )
        self.passthrough = changes_nothing(params)
        self.pure_translation = (
            self.model.is_translation and not self.backlash.any_active and not self.servo_s
        )
        inv_coupling = self._inverse_coupling()
        # needs[k]: axes whose position the command for axis k depends on (incl. k).
        self.needs = tuple(
            frozenset({k} | {j for j in range(3) if inv_coupling[k][j]}) for k in range(3)
        )
        # moved_by[j]: command axes that change when axis j moves (incl. j).
        self.moved_by = tuple(
            frozenset({j} | {k for k in range(3) if inv_coupling[k][j]}) for j in range(3)
        )
        self.writer = PathWriter(
            self.model, self.backlash, self.options, self._state, self.needs, self.servo_s
        )
        self.moves = MoveHandler(self)
        self.arc_writer = ArcWriter(self.writer, self)
        # policy "error": lines are processed so that a refused one changes nothing
        self._guarded = self.options.policy == "error" and self.options.limits is not None

    @property
    def accelerable(self) -> bool:
        """Whether an accelerated line engine can serve this model: an affine model without
        smoothed take-ups or servo lead (everything else takes this reference path)."""
        return (
            not self.passthrough
            and self.model.is_affine
            and self.backlash.smoothing == 0
            and self.servo_s is None
        )

    @property
    def state(self) -> StreamState:
        """The stream state, current: an accelerated engine that holds it while it takes
        lines (the compiled kernel) hands it back first. Read it here each time: a reference
        kept across lines the engine takes is stale, and a change made through it while the
        engine holds the state is lost."""
        fast = self.fast
        if fast is not None:
            fast.release()
        return self._state

    @property
    def report(self) -> Report:
        return self.state.report

    @property
    def lineno(self) -> int:
        return self.state.lineno

    def _inverse_coupling(self):
        m = self.model
        if m.is_affine:
            Ai = m.A_inv
            return [[k != j and Ai[k, j] != 0.0 for j in range(3)] for k in range(3)]
        return [[m.coupling[k][j] or m.coupling[j][k] for j in range(3)] for k in range(3)]

    # -- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the power-on state: positions unknown, G90, G21, M82, G17."""
        self.state.reset()

    def adopt_state(self, other: Compensator) -> None:
        """Continue from ``other``'s modal state and positions (a parameter change in the
        middle of a stream); backlash directions carry over for axes active in both."""
        carried = [k for k in range(3) if self.backlash.active[k] and other.backlash.active[k]]
        self.state.take_over(other.state, carried)

    def invalidate(self, axes: Sequence[int] = (0, 1, 2)) -> None:
        """Forget the position of ``axes`` (their next move must re-establish it)."""
        self.state.forget_position(axes)

    @property
    def known(self) -> Tuple[bool, bool, bool]:
        return tuple(v is not None for v in self.state.m)

    @property
    def e_relative(self) -> bool:
        st = self.state
        if st.e_absolute_mode is not None:
            return not st.e_absolute_mode
        return not st.absolute if self.options.g90_influences_extruder else False

    # -- entry point ---------------------------------------------------------------------
    @property
    def guarded(self) -> bool:
        """The limits policy "error" is in force: ``process`` keeps a snapshot of the state
        around each line, so that a refused line changes nothing."""
        return self._guarded

    def process(self, line: str) -> Union[str, List[str]]:
        if self._guarded:
            return self._process_guarded(line)
        fast = self.fast
        if fast is not None:
            out = fast.line(line)
            if out is not None:
                return out
        return self.process_declined(line)

    def process_declined(self, line: str) -> Union[str, List[str]]:
        """``process`` for a line the accelerated engine declined (``engines/contract.py``):
        the reference path alone."""
        st = self.state
        st.q_last = None
        st.limit_recheck = [True, True, True]
        st.lineno += 1
        rep = st.report
        rep.lines += 1
        stripped = line.lstrip()
        if not stripped or stripped[0] not in "GgMmTtNn":
            rep.lines_out += 1
            return line
        cmd = parse_command(line)
        if cmd is None:
            rep.lines_out += 1
            return line
        out = self._dispatch(cmd, line)
        if out is line:
            rep.lines_out += 1
            return line
        rep.lines_out += len(out)
        indent = line[: len(line) - len(stripped)]
        if indent:
            out = [indent + o for o in out]
        return out

    def _process_guarded(self, line: str) -> Union[str, List[str]]:
        """``process`` for the limits policy ``error``: a line refused with LimitError leaves
        the state as it was before the line, so a stream that does not send it can go on
        from there (the print resumed after the pause) with every position still known. A
        caller that sends it as written anyway must forget the positions (see queue)."""
        saved = self.state.snapshot()
        self._guarded = False
        try:
            return self.process(line)
        except LimitError:
            self.state.restore(saved)
            raise
        finally:
            self._guarded = True

    def _home(self, body: str) -> None:
        """G28: the homed axes are at ``options.home_mm`` (unknown where that is None)."""
        self.homed_at(homed_axes(body), self.options.home_mm)

    def homed_at(self, axes: Sequence[int], at: Sequence[Optional[float]]) -> None:
        """The drives of ``axes`` were homed and are at ``at[k]`` (mm; None: not known):
        G28, or the firmware's position report after it (the plugin learns an unknown
        home so). The homed drives are at the home command, which under skew is not the
        command of the home position; the command of an axis that is not homed can depend
        on the homed ones (X's on Y under XY skew) while its drive stays where it was. The
        next move starts from where the drives really are (``StreamState.q_drive``), so its
        backlash reversals and take-ups are judged from there."""
        st = self.state
        q_before = self.writer.carriage(st.m)
        if st.q_drive is not None:
            q_before = [q if d is None else d for q, d in zip(q_before, st.q_drive)]
        home(st, self.backlash, axes, at)
        if self.passthrough:
            st.q_drive = None
            return
        q_after = self.writer.carriage(st.m)
        drive = [at[k] if k in axes else q_before[k] for k in range(3)]
        for k in self._approached(axes, at):
            drive[k] = st.backlash.anchor[k]
        stays = [
            None if drive[k] is None or q_after[k] == drive[k] else float(drive[k])
            for k in range(3)
        ]
        st.q_drive = None if stays == [None, None, None] else tuple(stays)

    def _approached(self, axes: Sequence[int], at: Sequence[Optional[float]]) -> List[int]:
        """The homed axes whose play is known after homing: a home on a limit (mm, the
        travel's edge) is an endstop there, which the firmware's last homing move approached
        (Marlin, RepRapFirmware and Klipper all finish homing toward the switch), so the play
        is taken up toward it. Their backlash direction is set to that approach (-1 at the
        lower limit, +1 at the upper) and the anchor to the drive's geometric command (the
        home minus the offset of that direction, mm): the first move away takes up the whole
        play, a move toward the switch none (no take-up past the edge). Elsewhere (no
        limits, a home inside the travel such as Klipper's safe_z_home) the direction stays
        unknown."""
        lim = self.options.limits
        bl = self.backlash
        if lim is None or not bl.any_active:
            return []
        out = []
        for k in axes:
            if at[k] is None or not bl.active[k]:
                continue
            d = -1 if at[k] <= lim[2 * k] else 1 if at[k] >= lim[2 * k + 1] else 0
            if d:
                bl.dir[k] = d
                bl.anchor[k] = float(at[k]) - bl.target(k, float(at[k]))
                out.append(k)
        return out

    def malformed(self, line: str) -> str:
        rep = self.state.report
        rep.malformed += 1
        if len(rep.malformed_examples) < 20:
            rep.malformed_examples.append((self.state.lineno, line[:80]))
        return line

    def _dispatch(self, cmd, line: str):
        """A command line's effect on the state, by its class in the G-code table."""
        entry = classify(cmd.kind, cmd.number, cmd.sub)
        cls = entry.cls
        st = self.state
        if cls == LINEAR or cls == ARC:
            st.report.moves += 1
            words = parse_words(cmd.body)
            if words is None:
                return self.malformed(line)
            if cls == LINEAR:
                return self.moves.linear(cmd, words, line)
            return self.moves.arc(cmd, words, line)
        if cls == DISTANCE:
            st.absolute = entry.value
            if self.options.g90_influences_extruder:
                st.e_absolute_mode = None
        elif cls == UNITS:
            st.inches = entry.value
            st.fw_text = [None, None, None]
        elif cls == PLANE:
            st.plane = entry.value
        elif cls == ARC_CENTRE:
            st.ij_absolute = entry.value
        elif cls == EXTRUDER:
            st.e_absolute_mode = entry.value
        elif cls == SET_POSITION:
            unit = MM_PER_INCH if st.inches else 1.0
            if set_position(st, self.backlash, cmd.body, unit) is None:
                return self.malformed(line)
        elif cls == DROP_OFFSETS:
            reset_offsets(st)
        elif cls == HOME:
            self._home(cmd.body)
        elif cls == LOSES:
            self.invalidate()
        elif cls == TOOL and cmd.number != st.tool:
            st.tool = cmd.number
            self.invalidate()
        return line
