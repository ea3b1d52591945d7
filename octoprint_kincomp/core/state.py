"""The stream state: the one record of where a G-code stream stands, which the reference
compensator reads and writes.

It is declared here, field by field, because it is a contract: the compiled kernel keeps
its own typed copy of the fields it needs while it takes lines (``engines/csrc/kernel.h``
``State``) and takes them from here, or writes them back here, only as a tuple of plain
values in the order of ``engines/kernel.py`` ``RECORD`` (``record`` and ``adopt`` there:
the one place to mirror a new or renamed field; the kernel's self-check against the
reference path catches a mismatch at start-up). ``Compensator.state`` hands it back from
the kernel before anyone reads it.

Frames (mm): logical ``L`` is what the program writes (after G20 inch conversion); the
desired machine position ``m = L - w`` (``w``: the program's G92 offset) is the homed frame
in which the calibration holds; the commanded (carriage) position ``c`` is the inverse model
of ``m`` plus the backlash offset; the firmware coordinate written on the line is
``fw = c + g`` (``g``: the firmware's own G92 offset).
"""

from __future__ import annotations

import copy
from typing import List, Optional, Tuple

from .params import AXES


class Report:
    """What the compensator did (the dry-run report). Counts of lines; corrections in um.

    Arcs: ``arcs_kept`` written as one G2/G3, ``arcs_split`` as several (cut where a
    backlash axis reverses, or where one circle does not fit), ``arcs_linearised`` as G1
    chords only; ``arc_segments``: the lines written for arcs (take-ups not counted);
    ``arc_max_deviation_um``: the largest estimated deviation of a written arc from the
    compensated path (core/arcpath.py). ``max_correction_um``: the largest correction per
    axis, [X, Y, Z] in um (a dict by axis name in :meth:`to_dict`).

    The travel's edge (``core/path.py`` ``PathWriter.limit``): ``limit_hits`` compensated
    coordinates that would leave it (kept on the edge unless the policy is ``warn``),
    ``limit_worst_um`` the largest shortfall (um, >= 0: the correction lost there, or how
    far past under ``warn``) and ``limit_worst_axis`` its axis (None: no hit),
    ``limit_examples`` the first 20 (line, axis, wanted command mm), ``source_outside``
    points the program itself puts outside the limits."""

    __slots__ = (
        "lines",
        "moves",
        "moves_compensated",
        "untouched_unknown",
        "malformed",
        "malformed_examples",
        "arcs_kept",
        "arcs_split",
        "arcs_linearised",
        "arc_segments",
        "arc_max_deviation_um",
        "takeup_moves",
        "lines_out",
        "max_correction_um",
        "limit_hits",
        "limit_examples",
        "limit_worst_um",
        "limit_worst_axis",
        "source_outside",
    )

    def __init__(self) -> None:
        self.lines = 0
        self.moves = 0
        self.moves_compensated = 0
        self.untouched_unknown = 0
        self.malformed = 0
        self.malformed_examples: List[Tuple[int, str]] = []
        self.arcs_kept = 0
        self.arcs_split = 0
        self.arcs_linearised = 0
        self.arc_segments = 0
        self.arc_max_deviation_um = 0.0
        self.takeup_moves = 0
        self.lines_out = 0
        self.max_correction_um: List[float] = [0.0, 0.0, 0.0]  # um, per axis (0 X, 1 Y, 2 Z)
        self.limit_hits = 0
        self.limit_examples: List[Tuple[int, str, float]] = []
        self.limit_worst_um = 0.0  # um: the largest shortfall at the travel's edge
        self.limit_worst_axis: Optional[str] = None  # its axis, "X"/"Y"/"Z"
        self.source_outside = 0

    def __repr__(self) -> str:
        return f"Report({self.to_dict()!r})"

    def to_dict(self) -> dict:
        return {
            "lines": self.lines,
            "lines_out": self.lines_out,
            "moves": self.moves,
            "moves_compensated": self.moves_compensated,
            "untouched_unknown_position": self.untouched_unknown,
            "malformed": self.malformed,
            "malformed_examples": [list(x) for x in self.malformed_examples],
            "arcs_kept": self.arcs_kept,
            "arcs_split": self.arcs_split,
            "arcs_linearised": self.arcs_linearised,
            "arc_segments": self.arc_segments,
            "arc_max_deviation_um": round(self.arc_max_deviation_um, 3),
            "backlash_takeup_moves": self.takeup_moves,
            "max_correction_um": {a: round(v, 3) for a, v in zip(AXES, self.max_correction_um)},
            "limit_hits": self.limit_hits,
            "limit_examples": [list(x) for x in self.limit_examples],
            "limit_worst_um": round(self.limit_worst_um, 3),
            "limit_worst_axis": self.limit_worst_axis,
            "source_outside_limits": self.source_outside,
        }


class BacklashState:
    """Per axis (x, y, z): the travel direction of the carriage command and where a
    reversal would be measured from.

    ``dir``: +1 the command last moved towards +, -1 towards -, 0 unknown (start, homing);
    the commanded take-up offset has the sign of ``dir``.
    ``anchor``: the geometric carriage command (mm, without the take-up offset) farthest
    along the current direction; None: not known yet (the next move's start is taken).
    ``ramping``, ``ramp_from`` (mm, offset at the reversal), ``ramp_done`` (mm of path since
    the reversal): a take-up spread over ``smoothing_mm`` of path (see backlash.py).
    """

    FIELDS = ("dir", "anchor", "ramping", "ramp_from", "ramp_done")
    __slots__ = FIELDS

    def __init__(self) -> None:
        self.dir: List[int] = [0, 0, 0]
        self.anchor: List[Optional[float]] = [None, None, None]
        self.ramping: List[bool] = [False, False, False]
        self.ramp_from: List[float] = [0.0, 0.0, 0.0]
        self.ramp_done: List[float] = [0.0, 0.0, 0.0]

    def forget(self, k: int) -> None:
        """Axis ``k``'s direction is unknown from here on."""
        self.dir[k] = 0
        self.anchor[k] = None
        self.ramping[k] = False
        self.ramp_from[k] = 0.0
        self.ramp_done[k] = 0.0


class StreamState:
    """Where the stream stands (see the module docstring for the frames).

    Positions, per axis x, y, z, in mm:

    * ``m``: desired machine position (None: unknown);
    * ``fw``: firmware coordinate last commanded (None: unknown) and ``fw_text`` its text as
      last written on a line (None: not written yet, or no longer what the firmware holds);
    * ``w``, ``g``: the program's and the firmware's G92 offsets;
    * ``frame_lost``: a G92 on an axis of unknown position shifted the firmware frame by an
      unknown amount: its absolute coordinates give no machine position until G28/G92.1.

    Modes: ``absolute`` (G90/G91), ``e_absolute_mode`` (M82 True / M83 False / None: follow
    G90/G91), ``inches`` (G20/G21), ``plane`` (17/18/19), ``ij_absolute`` (G90.1/G91.1).
    ``e_pos``: absolute E position (the program's E units; None: unknown), ``feed``: mm/min
    (None: unknown), ``tool``: the last T number, ``lineno``: lines seen.

    ``q_drive``: per axis, the geometric carriage command (mm) a drive is at where that is
    not the command of the desired position ``m`` (after G28: a homed drive at the home
    command, and under skew an axis that was not homed but whose command depends on the
    homed ones), None elsewhere; None as a whole when there is none. The next compensated
    move starts from there (and the compiled kernel leaves it to the reference path).

    The compiled kernel only (the reference path resets them on every line it handles):
    ``q_last``: the carriage command (mm) of the point the last line ended on, as a tuple,
    None: recompute it; ``limit_recheck``: per axis, re-evaluate its text even if its
    command did not change (it touched a limit).

    ``backlash``: :class:`BacklashState`; ``report``: :class:`Report`.
    """

    # The fields, declared once (``__slots__``, ``take_over`` and the compiled kernel's record,
    # engines/kernel.py RECORD, are made from or checked against these):
    POSITIONS = ("m", "fw", "fw_text", "w", "g", "frame_lost")  # per axis x, y, z: lists
    MODES = ("absolute", "e_absolute_mode", "inches", "plane", "ij_absolute")
    PROGRAM = ("e_pos", "feed", "tool", "lineno")
    KERNEL_ONLY = ("q_last", "limit_recheck")
    FIELDS = ("report", "backlash") + POSITIONS + MODES + PROGRAM + KERNEL_ONLY + ("q_drive",)
    __slots__ = FIELDS

    def __init__(self) -> None:
        self.report = Report()
        self.lineno = 0
        self.backlash = BacklashState()
        self.reset()

    def reset(self) -> None:
        """Back to the power-on state: positions unknown, G90, G21, M82, G17. The report and
        the line count go on."""
        self.m: List[Optional[float]] = [None, None, None]
        self.fw: List[Optional[float]] = [None, None, None]
        self.fw_text: List[Optional[str]] = [None, None, None]
        self.w = [0.0, 0.0, 0.0]
        self.g = [0.0, 0.0, 0.0]
        self.frame_lost = [False, False, False]
        self.absolute = True
        self.e_absolute_mode: Optional[bool] = None
        self.inches = False
        self.plane = 17
        self.ij_absolute = False
        self.e_pos: Optional[float] = None
        self.feed: Optional[float] = None
        self.tool: Optional[int] = None
        self.q_last: Optional[Tuple[float, float, float]] = None
        self.limit_recheck = [True, True, True]
        self.q_drive: Optional[Tuple[Optional[float], ...]] = None
        for k in range(3):
            self.backlash.forget(k)

    def forget_position(self, axes=(0, 1, 2)) -> None:
        """The position of ``axes`` is unknown (their next move must re-establish it)."""
        for k in axes:
            self.m[k] = None
            self.fw[k] = None
            self.fw_text[k] = None
            self.backlash.forget(k)
        self.q_drive = None

    def take_over(self, other: StreamState, backlash_axes=()) -> None:
        """Continue from ``other``'s modes and positions (new parameters mid-stream: desired
        positions do not depend on the model and the firmware coordinates are what the
        firmware holds). Backlash directions carry over for ``backlash_axes`` (the anchor is
        a geometric command, the same frame under either model)."""
        for name in self.POSITIONS:
            setattr(self, name, list(getattr(other, name)))
        for name in self.MODES + self.PROGRAM:
            setattr(self, name, getattr(other, name))
        for k in backlash_axes:
            self.backlash.dir[k] = other.backlash.dir[k]
            self.backlash.anchor[k] = other.backlash.anchor[k]
        self.q_last = None
        self.limit_recheck = [True, True, True]
        # where the drives are does not depend on the model
        self.q_drive = other.q_drive

    # what a line refused by the limits policy "error" must leave as it was
    _RESTORED = (
        "m",
        "fw",
        "fw_text",
        "w",
        "g",
        "e_pos",
        "feed",
        "q_last",
        "limit_recheck",
        "q_drive",
    )

    def snapshot(self) -> tuple:
        bl = self.backlash
        return (
            tuple(copy.copy(getattr(self, a)) for a in self._RESTORED),
            tuple(list(getattr(bl, a)) for a in BacklashState.FIELDS),
        )

    def restore(self, snap: tuple) -> None:
        mine, bl = snap
        for a, v in zip(self._RESTORED, mine):
            setattr(self, a, copy.copy(v))
        for a, v in zip(BacklashState.FIELDS, bl):
            setattr(self.backlash, a, list(v))
