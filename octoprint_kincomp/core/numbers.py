"""What counts as a number wherever KinComp takes one: a JSON number (an int or a float, not
a bool) that is finite as a float. JSON's integers have no bound (``1`` and 400 zeros parse as
a Python int), and ``float()`` of one beyond the float range raises OverflowError: such a
value is not finite, and is refused like NaN and Infinity (one rule for request bodies,
stored settings and parameters)."""

from __future__ import annotations

import math
from typing import Any, Optional


def finite(value: Any) -> Optional[float]:
    """``value`` as a float when it is a finite JSON number, else None (bools, texts, NaN,
    Infinity and integers beyond the float range, about 1.8e308)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        v = float(value)
    except OverflowError:
        return None
    return v if math.isfinite(v) else None


def finite_text(text: str) -> Optional[float]:
    """The number a text states (``"1e307"``, ``"3000"``) as a finite float, else None (not
    a number, NaN, Infinity, or beyond the float range: ``"1e309"``)."""
    try:
        v = float(text)
    except (TypeError, ValueError, OverflowError):
        return None
    return v if math.isfinite(v) else None
