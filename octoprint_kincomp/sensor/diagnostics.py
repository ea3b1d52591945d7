"""Counting what was wrong in a sensor stream, and deciding when it is too much.

Every line that is not a usable sample is counted under one kind:

* ``unreadable``: bytes that are not printable ASCII (binary data, or the mojibake of a wrong
  baud rate);
* ``too_long``: no line end within the line limit (a stream that never sends a newline);
* ``garbage``: text that does not follow the protocol;
* ``not_finite``: NaN or infinite readings;
* ``out_of_range``: readings outside the sensor's range (in the sensor's own units);
* ``clock``: a device time stamp that went backwards (not a counter wrap);
* ``header``: a bad ``# key: value`` line of the KinComp protocol.

A bounded number of bad lines is tolerated. The stream is refused (:meth:`Diagnostics.fatal`)
when more than ``max_bad`` lines were bad since the last :meth:`reset`, or when at least
``burst_fraction`` of the last ``window`` lines were bad. Memory is bounded: counts, and a few
short examples per kind.
"""

from __future__ import annotations

from collections import deque
from typing import Dict, List, Optional

from ..core.messages import Msg

KINDS = ("unreadable", "too_long", "garbage", "not_finite", "out_of_range", "clock", "header")
EXAMPLES = 3  # kept per kind
EXAMPLE_CHARS = 40

_REASONS = {
    "unreadable": Msg("unreadable bytes: wrong baud rate, or the sensor does not send text"),
    "too_long": Msg("lines without a line end: wrong baud rate or protocol"),
    "garbage": Msg("lines that do not follow the protocol"),
    "not_finite": Msg("NaN or infinite readings"),
    "out_of_range": Msg("readings outside the sensor's range: bar not seated, or wrong units"),
    "clock": Msg("device time stamps that went backwards"),
    "header": Msg("bad header lines"),
}


def example_text(raw) -> str:
    """A short, printable rendering of a bad line for messages."""
    if raw is None:
        return ""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "backslashreplace")
    text = "".join(c if 32 <= ord(c) < 127 else "?" for c in str(raw))
    return text[:EXAMPLE_CHARS] + ("..." if len(text) > EXAMPLE_CHARS else "")


class Diagnostics:
    def __init__(self, max_bad: int = 200, window: int = 100, burst_fraction: float = 0.5):
        self.max_bad = int(max_bad)
        self.window = int(window)
        self.burst_fraction = float(burst_fraction)
        self.reset()

    def reset(self) -> None:
        self.lines = 0
        self.samples = 0
        self.counts: Dict[str, int] = dict.fromkeys(KINDS, 0)
        self.examples: Dict[str, List[str]] = {k: [] for k in KINDS}
        self.notes: List[Msg] = []
        self._recent: deque = deque(maxlen=self.window)

    @property
    def bad_lines(self) -> int:
        return sum(self.counts.values())

    def good(self) -> None:
        self.lines += 1
        self.samples += 1
        self._recent.append(False)

    def other(self) -> None:
        """A line that is fine but no sample (header, comment)."""
        self.lines += 1
        self._recent.append(False)

    def bad(self, kind: str, raw=None) -> None:
        self.lines += 1
        self.counts[kind] += 1
        self._recent.append(True)
        if raw is not None and len(self.examples[kind]) < EXAMPLES:
            self.examples[kind].append(example_text(raw))

    def note(self, msg: Msg) -> None:
        if msg not in self.notes and len(self.notes) < 20:
            self.notes.append(msg)

    def _worst(self) -> str:
        return max(KINDS, key=lambda k: self.counts[k])

    def fatal(self, total_limit: bool = True) -> Optional[Msg]:
        """Why the stream must be refused, or None. ``total_limit``: apply ``max_bad`` too
        (during a capture); without it only a burst of bad lines is fatal (live preview)."""
        burst = sum(self._recent)
        too_many = total_limit and self.bad_lines > self.max_bad
        if not too_many and not (
            len(self._recent) >= min(self.window, 20)
            and burst >= self.burst_fraction * len(self._recent)
        ):
            return None
        kind = self._worst()
        example = self.examples[kind][0] if self.examples[kind] else ""
        if too_many:
            return Msg(
                "too many bad lines from the sensor (%(bad)s of %(lines)s): %(reason)s, "
                "e.g. %(example)s",
                bad=self.bad_lines,
                lines=self.lines,
                reason=_REASONS[kind],
                example=repr(example),
            )
        return Msg(
            "the sensor sends mostly bad lines (%(burst)s of the last %(n)s): "
            "%(reason)s, e.g. %(example)s",
            burst=burst,
            n=len(self._recent),
            reason=_REASONS[kind],
            example=repr(example),
        )

    def as_dict(self) -> Dict[str, object]:
        return {
            "lines": self.lines,
            "samples": self.samples,
            "bad_lines": self.bad_lines,
            "counts": {k: v for k, v in self.counts.items() if v},
            "examples": {k: list(v) for k, v in self.examples.items() if v},
            "notes": list(self.notes),
        }
