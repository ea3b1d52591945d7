"""A firmware-like G-code executor: what an ideal printer would command, move by move.

It reads G-code the way Marlin does (G90/G91, G92 offsets, G20/G21, M82/M83, G28 homing to
``home_mm``, G2/G3 in G17/G18/G19 with IJK/R/P, G4 dwell), each code as the G-code table
(``core/gcode_table.py``) classifies it, and yields the commanded path in the homed machine
frame (mm). It knows nothing about errors: the simulator applies the printer's true errors to
this path, and the tests use it as the oracle of where a program tells the head to go. Other
codes (probing, tool changes, inert ones) are ignored; a move, homing or G92 with malformed
words is skipped and counted.
Arcs are cut into chords of at most ``arc_tol_mm`` sagitta (an ideal firmware by default).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, List, Optional, Tuple, Union

from ..core import arcs, gcode_table
from ..core.gcode import parse_command, parse_words

MM_PER_INCH = 25.4
Vec = Tuple[float, float, float]
# the classes whose words this firmware runs: homing, G92 and the moves
_RUN = frozenset({gcode_table.HOME, gcode_table.SET_POSITION, gcode_table.LINEAR, gcode_table.ARC})


@dataclass(frozen=True)
class Move:
    """A straight commanded segment in the machine frame (mm); ``feed`` in mm/min."""

    start: Vec
    end: Vec
    feed: float
    kind: str  # "G0", "G1" or "arc"
    lineno: int
    e: float = 0.0  # extrusion of this segment (mm of filament)


@dataclass(frozen=True)
class Dwell:
    seconds: float
    lineno: int


@dataclass(frozen=True)
class Home:
    axes: Tuple[int, ...]
    lineno: int


Event = Union[Move, Dwell, Home]


class FirmwareInterpreter:
    def __init__(
        self,
        home_mm: Vec = (0.0, 0.0, 0.0),
        arc_tol_mm: float = 1e-4,
        start: Optional[Vec] = None,
        g90_influences_extruder: bool = True,
        default_feed: float = 1500.0,
    ):
        self.home = tuple(float(v) for v in home_mm)
        self.arc_tol = arc_tol_mm
        self.machine: List[float] = list(start if start is not None else self.home)
        self.g = [0.0, 0.0, 0.0]  # firmware G92 offsets: logical = machine + g
        self.absolute = True
        self.e_abs_mode: Optional[bool] = None
        self.g90_e = g90_influences_extruder
        self.inches = False
        self.plane = 17
        self.ij_absolute = False
        self.feed = default_feed
        self.e = 0.0
        self.lineno = 0
        self.malformed = 0
        self.last_arc: Optional[arcs.Arc] = None  # the geometry of the last arc run

    @property
    def logical(self) -> Vec:
        return tuple(self.machine[k] + self.g[k] for k in range(3))

    def _e_relative(self) -> bool:
        if self.e_abs_mode is not None:
            return not self.e_abs_mode
        return (not self.absolute) if self.g90_e else False

    def run(self, lines: Iterable[str]) -> Iterator[Event]:
        for line in lines:
            yield from self.execute(line.rstrip("\r\n"))

    def execute(self, line: str) -> List[Event]:
        self.lineno += 1
        cmd = parse_command(line)
        if cmd is None:
            return []
        entry = gcode_table.classify(cmd.kind, cmd.number, cmd.sub)
        cls = entry.cls
        u = MM_PER_INCH if self.inches else 1.0
        if cls == gcode_table.EXTRUDER:
            self.e_abs_mode = entry.value
        elif cls == gcode_table.ARC_CENTRE:
            self.ij_absolute = entry.value
        elif cls == gcode_table.DROP_OFFSETS:
            self.g = [0.0, 0.0, 0.0]
        elif cls == gcode_table.DISTANCE:
            self.absolute = entry.value
            if self.g90_e:
                self.e_abs_mode = None
        elif cls == gcode_table.UNITS:
            self.inches = entry.value
        elif cls == gcode_table.PLANE:
            self.plane = entry.value
        elif cls == gcode_table.DWELL:
            words = parse_words(cmd.body) or []
            wd = {w.letter: w.value for w in words}
            secs = wd.get("S", 0.0) + wd.get("P", 0.0) / 1000.0
            return [Dwell(secs, self.lineno)]
        elif cls in _RUN:
            return self._run(cmd, entry, u)
        return []  # (no other code changes what this ideal firmware commands)

    def _run(self, cmd, entry: gcode_table.Entry, u: float) -> List[Event]:
        """A homing, G92 or a move (``u``: mm per program unit)."""
        cls = entry.cls
        words = parse_words(cmd.body, allow_bare=(cls == gcode_table.HOME))
        if words is None:
            self.malformed += 1
            return []
        wd = {w.letter: w.value for w in words}
        if cls == gcode_table.HOME:
            axes = tuple(k for k, a in enumerate("XYZ") if a in wd) or (0, 1, 2)
            for k in axes:
                self.machine[k] = self.home[k]
                self.g[k] = 0.0
            return [Home(axes, self.lineno)]
        if cls == gcode_table.SET_POSITION:
            if not any(a in wd for a in "XYZE"):
                wd = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
            for k, a in enumerate("XYZ"):
                if a in wd:
                    self.g[k] = wd[a] * u - self.machine[k]
            if "E" in wd:
                self.e = wd["E"]
            return []
        if wd.get("F", 0.0) > 0.0:  # (Marlin, RRF: a feed of 0 or less is ignored)
            self.feed = wd["F"] * u
        target = list(self.machine)
        for k, a in enumerate("XYZ"):
            if a in wd:
                if self.absolute:
                    target[k] = wd[a] * u - self.g[k]
                else:
                    target[k] = self.machine[k] + wd[a] * u
        de = 0.0
        if "E" in wd:
            if self._e_relative():
                de = wd["E"]
                self.e += de
            else:
                de = wd["E"] - self.e
                self.e = wd["E"]
        start = tuple(self.machine)
        end = tuple(target)
        if cls == gcode_table.LINEAR:
            self.machine = target
            return [Move(start, end, self.feed, f"G{cmd.number}", self.lineno, de)]
        return self._arc(entry.value, wd, start, end, u, de)

    def _arc(self, clockwise, wd, start, end, u, de) -> List[Event]:
        ia, ib, _, la, lb = arcs.PLANES[self.plane]
        offs = (wd[la] * u if la in wd else None, wd[lb] * u if lb in wd else None)
        radius = wd["R"] * u if "R" in wd else None
        turns = int(wd.get("P", 0))
        try:
            ca, cb = arcs.centre_from_words(
                start, end, self.plane, offs, radius, clockwise, self.ij_absolute
            )
            if self.ij_absolute:
                ca -= self.g[ia]
                cb -= self.g[ib]
            pts = arcs.linearise(start, end, self.plane, ca, cb, clockwise, self.arc_tol, turns)
            self.last_arc = arcs.Arc(start, end, self.plane, ca, cb, clockwise, turns)
        except arcs.ArcError:
            self.malformed += 1
            self.last_arc = None
            pts = [end]
        total = 0.0
        prev = start
        lens = []
        for p in pts:
            seg = sum((p[k] - prev[k]) ** 2 for k in range(3)) ** 0.5
            lens.append(seg)
            total += seg
            prev = p
        out: List[Event] = []
        prev = start
        for p, seg in zip(pts, lens):
            out.append(
                Move(prev, p, self.feed, "arc", self.lineno, de * seg / total if total > 0 else 0.0)
            )
            prev = p
        self.machine = list(end)
        return out


def commanded_path(lines: Iterable[str], **kwargs) -> List[Event]:
    """All events of a program (convenience for tests and the simulator)."""
    return list(FirmwareInterpreter(**kwargs).run(lines))
