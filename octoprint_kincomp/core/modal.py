"""Commands that move no axis but change what later coordinates mean: G92 (set position),
G92.1 (drop the offsets) and G28 (homing). They act on the stream state (positions in mm,
see state.py) and the backlash direction state; G92 and G28 lines pass unchanged. Where the
firmware homes an axis may be unknown (None): the axis is then unknown after G28 until
the position is learned (the plugin asks the firmware with M114) or an absolute move names
it."""

from __future__ import annotations

from typing import Dict, List, Optional, Sequence

from .gcode import parse_words
from .state import StreamState

AXIS_LETTERS = ("X", "Y", "Z")


def _g92_words(body: str) -> Optional[Dict[str, float]]:
    """The positions a G92 sets, by letter (program units); a G92 naming none of X, Y, Z, E
    sets all four to 0. None when the words are malformed."""
    words = parse_words(body)
    if words is None:
        return None
    given = {w.letter: w.value for w in words}
    if not any(k in given for k in ("X", "Y", "Z", "E")):
        given = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
    return given


def g92_axes(body: str) -> List[int]:
    """The axes (0 X, 1 Y, 2 Z) whose frame a G92 with the words of ``body`` sets (all
    three when the words are malformed: the firmware may take any of them)."""
    given = _g92_words(body)
    if given is None:
        return [0, 1, 2]
    return [k for k, a in enumerate(AXIS_LETTERS) if a in given]


def set_position(st: StreamState, backlash, body: str, unit: float) -> Optional[bool]:
    """G92 with the words of ``body`` (``unit``: mm per program unit). Returns None when
    the words are malformed. An axis of unknown position loses its frame (module doc of
    state.py): its new offset to the machine frame is unknown."""
    given = _g92_words(body)
    if given is None:
        return None
    for k, letter in enumerate(AXIS_LETTERS):
        if letter not in given:
            continue
        v = given[letter] * unit
        if st.m[k] is None:
            st.frame_lost[k] = True
            st.fw[k] = None
            st.fw_text[k] = None
            backlash.reset((k,))
            continue
        c = st.fw[k] - st.g[k]
        st.w[k] = v - st.m[k]
        st.g[k] = v - c
        st.fw[k] = v
        st.fw_text[k] = None
    if "E" in given:
        st.e_pos = given["E"]
    return True


def reset_offsets(st: StreamState) -> None:
    """G92.1: the offsets are dropped. The head does not move, so the desired machine
    position stays where it is (adding ``w`` to it would make the next move drive the axes
    the program did not mention to ``m + w``); only the firmware coordinate loses ``g``."""
    for k in range(3):
        if st.m[k] is not None:
            st.fw[k] -= st.g[k]
            st.fw_text[k] = None
        st.w[k] = 0.0
        st.g[k] = 0.0
        st.frame_lost[k] = False  # the firmware frame is the native one again


def named_axes(body: str) -> List[int]:
    """The axes (0 X, 1 Y, 2 Z) the words of ``body`` name, bare letters too; all three
    when the words do not parse (such a line may move any of them)."""
    words = parse_words(body, allow_bare=True)
    if words is None:
        return [0, 1, 2]
    letters = {w.letter for w in words}
    return [k for k, a in enumerate(AXIS_LETTERS) if a in letters]


def homed_axes(body: str) -> List[int]:
    """The axes a G28 with the words of ``body`` homes: all when it names none."""
    return named_axes(body) or [0, 1, 2]


def home(st: StreamState, backlash, axes: Sequence[int], at: Sequence[Optional[float]]) -> None:
    """The drives of ``axes`` were homed: their frames are restored and each is known at
    ``at[k]`` (mm, machine frame = firmware frame after homing), or, where ``at[k]`` is None
    (where the firmware homes is not known), unknown: no correction may then assume a home
    position (a printer homing X at its maximum would be driven across the bed)."""
    for k in axes:
        st.w[k] = 0.0
        st.g[k] = 0.0
        st.frame_lost[k] = False
        st.fw_text[k] = None
        if at[k] is None:
            st.m[k] = None
            st.fw[k] = None
            backlash.reset((k,))
            continue
        st.m[k] = float(at[k])
        st.fw[k] = float(at[k])
        # the drive is at the home command, which under skew is not inverse(home): the
        # first move's reversal is judged from there
        backlash.place(k, float(at[k]))
