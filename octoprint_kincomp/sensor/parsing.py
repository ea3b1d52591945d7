"""What the three protocol parsers share: bytes in, samples and diagnostics out.

A parser is fed the bytes as they arrive with the host time of their arrival
(:meth:`Parser.feed`), and returns the complete samples they hold. It never blocks and keeps
bounded memory (:mod:`.line_splitter`). A :class:`Sample` holds

* ``t`` (s): the device's own clock (KinComp protocol), or the host's arrival time (plain and
  pattern protocols; see :mod:`.retime` for how those are re-timed);
* ``mm``: the bar length change in mm, positive = bar longer (converted by the
  :class:`~.convention.Convention`);
* ``seq``: the number of the line in the stream (bad lines count too: a corrupted line most
  likely was a sample; header and comment lines do not), so that host-timed samples can be
  re-timed by their place in the device's regular sequence.

Bad lines are counted in :attr:`Parser.diagnostics` (:mod:`.diagnostics`); a parser raises
:class:`~.errors.SensorError` only for what no number of lines can fix (e.g. an unsupported
protocol version).
"""

from __future__ import annotations

import math
import re
from typing import Dict, List, NamedTuple, Optional, Tuple

from ..core.messages import Msg
from .convention import Convention
from .diagnostics import Diagnostics
from .line_splitter import DEFAULT_MAX_LINE, LineSplitter
from .sensor_error import SensorError

NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
NOT_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
SANITY_MM = 1000.0  # |reading| above this is out of range whatever the sensor's range
PRINTABLE = re.compile(rb"[\t\x20-\x7e]*")


class Sample(NamedTuple):
    t: float  # s (device clock, or host arrival time)
    mm: float  # bar length change, mm, + = longer
    seq: int  # line number in the stream


class BadLine(Exception):
    """One line is not a usable sample (``kind`` as in :mod:`.diagnostics`)."""

    def __init__(self, kind: str):
        super().__init__(kind)
        self.kind = kind


def parse_range(text, field: str = "range") -> Optional[Tuple[float, float]]:
    """``"lo,hi"`` or ``(lo, hi)`` -> (lo, hi) with lo < hi, finite; None/"" -> None."""
    if text is None or text == "":
        return None
    try:
        parts = text.split(",") if isinstance(text, str) else list(text)
        lo, hi = (float(v) for v in parts)
    except (TypeError, ValueError):
        raise SensorError(
            Msg(
                "%(field)s must be two numbers 'low,high', got %(got)s",
                field=field,
                got=repr(str(text)[:40]),
            ),
            field,
        ) from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise SensorError(Msg("%(field)s must be finite with low < high", field=field), field)
    return lo, hi


def parse_number(text: str) -> float:
    """A strict decimal number; raises BadLine('not_finite' or 'garbage')."""
    text = text.strip()
    if NUMBER.fullmatch(text):
        value = float(text)
        if math.isfinite(value):
            return value
        raise BadLine("not_finite")  # e.g. 1e999
    if NOT_FINITE.fullmatch(text):
        raise BadLine("not_finite")
    raise BadLine("garbage")


class Parser:
    """Base: splits lines, counts faults, converts readings. Subclasses parse one line."""

    name = ""
    device_clock = False  # True: Sample.t is the device's clock, else host arrival time

    def __init__(
        self,
        convention: Optional[Convention] = None,
        range_raw: Optional[Tuple[float, float]] = None,
        diagnostics: Optional[Diagnostics] = None,
        max_line: int = DEFAULT_MAX_LINE,
    ):
        self.convention = convention if convention is not None else Convention()
        self.range_raw = range_raw  # in the units the sensor sends, before the sign
        self.diagnostics = diagnostics or Diagnostics()
        self.meta: Dict[str, str] = {}  # what the sensor says about itself
        self.seq = 0
        self._lines = LineSplitter(max_line)

    def feed(self, data: bytes, t_host: float) -> List[Sample]:
        out: List[Sample] = []
        diag = self.diagnostics
        for raw in self._lines.feed(data):
            self.seq += 1
            if raw is None:
                diag.bad("too_long")
                continue
            if not PRINTABLE.fullmatch(raw):
                diag.bad("unreadable", raw)
                continue
            text = raw.decode("ascii").strip()
            if not text:
                self.seq -= 1
                continue
            try:
                sample = self._line(text, t_host)
            except BadLine as bad:
                diag.bad(bad.kind, text)
                continue
            if sample is None:  # header or comment: not a sample, not counted in seq
                self.seq -= 1
                diag.other()
            else:
                diag.good()
                out.append(sample)
        return out

    def _line(self, text: str, t_host: float) -> Optional[Sample]:
        """One printable, stripped, non-empty line -> a Sample, None (no sample) or BadLine."""
        raise NotImplementedError

    def reading_mm(self, raw: float) -> float:
        """Range-check a reading in the sensor's units and convert it to mm (+ = longer)."""
        if self.range_raw is not None and not (self.range_raw[0] <= raw <= self.range_raw[1]):
            raise BadLine("out_of_range")
        mm = self.convention.to_mm(raw)
        if not math.isfinite(mm):
            raise BadLine("not_finite")
        if abs(mm) > SANITY_MM:
            raise BadLine("out_of_range")
        return mm

    def info(self) -> Dict[str, str]:
        """Metadata for the trace: protocol, units, sign, range and what the sensor said."""
        info = {
            "sensor_protocol": self.name,
            "sensor_units": self.convention.units,
            "sensor_positive": "longer" if self.convention.longer_positive else "shorter",
            "timing": "device clock" if self.device_clock else "host arrival",
        }
        if self.range_raw is not None:
            info["sensor_range"] = f"{self.range_raw[0]:g},{self.range_raw[1]:g}"
        info.update(self.meta)
        return info
