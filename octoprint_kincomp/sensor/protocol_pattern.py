"""Indicators that print a fixed ASCII format: a regular expression and a scale factor.

The setting ``pattern`` is a Python regular expression that must match the whole line (after
stripping blanks at both ends) with a named group ``value`` holding the number; ``scale``
multiplies that number to give the reading in the setting's units. Examples:

* ``+00.0123`` (mm): pattern ``(?P<value>[+-]\\d+\\.\\d+)``, scale 1;
* ``01A+00001234`` (a counter in 0.1 um): pattern ``01A(?P<value>[+-]\\d{8})``, scale 0.0001
  with units mm (or 0.1 with units um).

Blanks inside the value are ignored (``+ 0.0123``). Times are host arrival times, as for the
plain protocol (:mod:`.protocol_plain` states the timing error). A pattern is checked when it
is set: it must compile, have exactly one group named ``value``, and be at most 200 characters;
``scale`` must be finite and not zero. Lines are at most 200 bytes, which bounds the matching
time of any pattern.
"""

from __future__ import annotations

import math
import re
from typing import Optional, Pattern

from ..core.messages import Msg
from .parsing import BadLine, Parser, Sample, parse_number
from .sensor_error import SensorError

MAX_PATTERN = 200


def compile_pattern(pattern: str) -> Pattern:
    """The compiled pattern, or SensorError (field ``pattern``) saying what is wrong."""
    if not isinstance(pattern, str) or not pattern.strip():
        raise SensorError(Msg("a pattern is needed for the pattern protocol"), "pattern")
    if len(pattern) > MAX_PATTERN:
        raise SensorError(
            Msg("the pattern is longer than %(n)s characters", n=MAX_PATTERN), "pattern"
        )
    try:
        rx = re.compile(pattern)
    except re.error as exc:
        raise SensorError(
            Msg("the pattern is not a valid regular expression: %(error)s", error=str(exc)),
            "pattern",
        ) from None
    if "value" not in rx.groupindex:
        raise SensorError(
            Msg("the pattern needs a named group (?P<value>...) around the number"), "pattern"
        )
    return rx


MAX_SCALE = 1e9  # |scale| within 1/MAX_SCALE .. MAX_SCALE: a factor, never a typo's 1e308


def check_scale(scale) -> float:
    """The pattern protocol's value factor: a number (a numeric text from a command line or
    config file too, never true/false), finite, with 1e-9 <= |scale| <= 1e9 (so a reading
    times it stays finite). KinComp's settings take JSON numbers only (plugin/settings)."""
    try:
        if isinstance(scale, bool):
            raise TypeError(scale)
        value = float(scale)
    except (TypeError, ValueError):
        raise SensorError(
            Msg("scale must be a number, got %(got)s", got=repr(scale)[:30]), "scale"
        ) from None
    if not math.isfinite(value) or not 1.0 / MAX_SCALE <= abs(value) <= MAX_SCALE:
        raise SensorError(
            Msg(
                "scale must be finite, not zero, and within %(lo)s..%(hi)s (either sign)",
                lo=f"{1.0 / MAX_SCALE:g}",
                hi=f"{MAX_SCALE:g}",
            ),
            "scale",
        )
    return value


class PatternParser(Parser):
    name = "pattern"

    def __init__(self, pattern: str, scale: float = 1.0, **kw):
        super().__init__(**kw)
        self.pattern = compile_pattern(pattern)
        self.scale = check_scale(scale)

    def _line(self, text: str, t_host: float) -> Optional[Sample]:
        m = self.pattern.fullmatch(text)
        if m is None or m.group("value") is None:
            raise BadLine("garbage")
        value = parse_number(m.group("value").replace(" ", "")) * self.scale
        return Sample(t_host, self.reading_mm(value), self.seq)

    def info(self):
        info = super().info()
        info["sensor_pattern"] = self.pattern.pattern
        info["sensor_scale"] = f"{self.scale:g}"
        return info
