"""The one table of what a G-code command does to the printer's state, by its code.

Every place that must know whether a line moves, re-frames, homes, changes tools or is inert asks
:func:`classify`: the reference compensator's dispatch (``compensator.py``), the simulator's
firmware interpreter (``firmware/interpreter.py``) and the queue's check of which lines make a
position report stale (``service/printing/queue.py``). An accelerated engine that decides on its own
which lines it takes is held against the table by :func:`check_engine`.

A code is its letter, number and sub-code (``G92.1``: ``("G", 92, 1)``; ``sub`` None
without a dot). The classes, by group:

* moves: ``LINEAR`` (G0, G1), ``ARC`` (G2, G3);
* re-frames (later coordinates mean something else; nothing moves): ``DISTANCE`` (G90/G91,
  value True for absolute), ``UNITS`` (G20/G21, True for inches), ``PLANE`` (G17/18/19, the
  number), ``ARC_CENTRE`` (G90.1/G91.1, True for absolute I/J/K), ``EXTRUDER`` (M82/M83,
  True for absolute E), ``SET_POSITION`` (G92), ``DROP_OFFSETS`` (G92.1);
* homes: ``HOME`` (G28);
* loses the position (the head moves on its own: probing, levelling, parking, nozzle
  cleaning, restoring a saved position, Bambu's probe move): ``LOSES``, whatever sub-code;
* changes tools: ``TOOL`` (any ``T``; hotend offsets may shift the frame);
* ``VARIANT``: another sub-code of a move or of G92 (``G1.1``, ``G92.2``): the reference
  path cannot read it and passes it as written; a firmware may still move or re-frame on it;
* inert (nothing moves or re-frames): ``DWELL`` (G4) and ``STOP`` (M400, M0, M1, whatever
  sub-code: the moves finish first), where the simulator's planner waits or stops, and
  ``INERT``: every other code (M104, M106, M220 ...). The table lists a few common inert
  codes; any code it does not list is inert too.
"""

from __future__ import annotations

from typing import Callable, Dict, Iterable, List, NamedTuple, Optional, Tuple

from .gcode import parse_command

LINEAR = "linear"
ARC = "arc"
DISTANCE = "distance"
UNITS = "units"
PLANE = "plane"
ARC_CENTRE = "arc_centre"
EXTRUDER = "extruder"
SET_POSITION = "set_position"
DROP_OFFSETS = "drop_offsets"
HOME = "home"
LOSES = "loses_position"
TOOL = "tool"
VARIANT = "variant"
DWELL = "dwell"
STOP = "stop"
INERT = "inert"

MOVES = frozenset({LINEAR, ARC})
REFRAMES = frozenset({DISTANCE, UNITS, PLANE, ARC_CENTRE, EXTRUDER, SET_POSITION, DROP_OFFSETS})
# what the reference path passes as written without changing its state: to an engine's
# output these are one class, and an engine may take any of them as INERT
PASSES = frozenset({VARIANT, DWELL, STOP, INERT})
CLASSES = MOVES | REFRAMES | PASSES | {HOME, LOSES, TOOL}

Code = Tuple[str, int, Optional[int]]  # (letter, number, sub-code or None)


class Entry(NamedTuple):
    """A code's class and, for a mode switch, the mode it sets (see the module doc)."""

    cls: str
    value: object = None


# codes whose every sub-code (and none) makes the head's position unknown
_LOSES_G = (12, 27, 29, 30, 31, 32, 33, 34, 35, 38, 61, 80, 380, 425)
_LOSES_M = (48,)

TABLE: Dict[Code, Entry] = {
    ("G", 0, None): Entry(LINEAR),
    ("G", 1, None): Entry(LINEAR),
    ("G", 2, None): Entry(ARC, True),  # (value: clockwise)
    ("G", 3, None): Entry(ARC, False),
    ("G", 4, None): Entry(DWELL),
    ("G", 17, None): Entry(PLANE, 17),
    ("G", 18, None): Entry(PLANE, 18),
    ("G", 19, None): Entry(PLANE, 19),
    ("G", 20, None): Entry(UNITS, True),
    ("G", 21, None): Entry(UNITS, False),
    ("G", 28, None): Entry(HOME),
    ("G", 90, None): Entry(DISTANCE, True),
    ("G", 91, None): Entry(DISTANCE, False),
    ("G", 90, 1): Entry(ARC_CENTRE, True),
    ("G", 91, 1): Entry(ARC_CENTRE, False),
    ("G", 92, None): Entry(SET_POSITION),
    ("G", 92, 1): Entry(DROP_OFFSETS),
    ("M", 82, None): Entry(EXTRUDER, True),
    ("M", 83, None): Entry(EXTRUDER, False),
    # inert, listed for the reader (and probed by check_engine): temperatures, fans,
    # feed and flow factors, messages, reports
    **{
        ("M", n, None): Entry(INERT)
        for n in (17, 104, 105, 106, 107, 109, 114, 117, 140, 190, 220, 221)
    },
}

# by letter and number, whatever the sub-code (after TABLE's exact codes)
_ANY_SUB: Dict[Tuple[str, int], Entry] = {
    **{("G", n): Entry(LOSES) for n in _LOSES_G},
    **{("M", n): Entry(LOSES) for n in _LOSES_M},
    **{("G", n): Entry(VARIANT) for n in (0, 1, 2, 3, 92)},
    **{("M", n): Entry(STOP) for n in (0, 1, 400)},
}

_TOOL = Entry(TOOL)
_INERT = Entry(INERT)


def classify(kind: str, number: int, sub: Optional[int] = None) -> Entry:
    """What the code ``kind number[.sub]`` does (``kind`` upper case: G, M or T)."""
    entry = TABLE.get((kind, number, sub))
    if entry is not None:
        return entry
    if kind == "T":
        return _TOOL
    return _ANY_SUB.get((kind, number), _INERT)


def classify_code(code: str) -> Optional[str]:
    """The class of a code as written at the start of a line (``"g01"``, ``"G92.1"``,
    ``"M082"``); None where the text opens no command (the line is no G-code)."""
    cmd = parse_command(code)
    if cmd is None:
        return None
    return classify(cmd.kind, cmd.number, cmd.sub).cls


# codes the table does not list, each probed by check_engine: all inert (or VARIANT/LOSES
# by their number), so an engine that takes them must take them as the table says
PROBES = (
    "G5", "G6", "G10", "G11", "G26", "G28.1", "G29.2", "G38.2", "G53", "G54", "G60", "G64",
    "G76", "G1.1", "G1.0", "G2.1", "G92.2", "G4.1", "G17.1", "G20.1", "G90.2", "M2", "M18",
    "M48.1", "M82.1", "M84", "M92", "M201", "M203", "M204", "M205", "M500", "M600", "M900",
    "T0", "T1", "T9",
)  # fmt: skip


def _spellings(code: str) -> List[str]:
    """A code as firmware accepts it: as listed, in lower case, with a leading zero."""
    letter, rest = code[0], code[1:]
    return [code, letter.lower() + rest, letter + "0" + rest]


def _listed() -> Iterable[str]:
    for kind, number, sub in TABLE:
        yield f"{kind}{number}" if sub is None else f"{kind}{number}.{sub}"
    for kind, number in _ANY_SUB:
        yield f"{kind}{number}"
        yield f"{kind}{number}.5"


def check_engine(classify_engine: Callable[[str], Optional[str]]) -> List[str]:
    """Where an engine's classification disagrees with the table: one sentence each, none
    when it agrees. ``classify_engine(code)`` gets a code as it may open a line (``"G1"``,
    ``"g01"``, ``"G92.1"``, ``"T0"``) and returns the class (one of :data:`CLASSES`) the
    engine acts on for lines with that code, or None where it hands them to the reference
    path (always allowed); ``INERT`` stands for any class of :data:`PASSES`. Every code of
    the table and of :data:`PROBES` is asked, each in the spellings of :func:`_spellings`."""
    problems = []
    for code in [*_listed(), *PROBES]:
        for text in _spellings(code):
            said = classify_engine(text)
            if said is None:
                continue
            want = classify_code(text)
            if said != want and not (said == INERT and want in PASSES):
                problems.append(f"{text}: the engine takes it as {said}, the table says {want}")
    return problems
