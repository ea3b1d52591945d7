"""The speed factor during a ballbar test: it stays at 100 %.

Every test program sets ``M220 S100`` before its first move (``calibration/ballbar/program.py``).
While one of KinComp's test programs prints (a file in its program folder), an ``M220`` that would
change the factor again and that does not come from the program itself (OctoPrint's feed rate
slider, the terminal, another plugin) is held back: a test run at 80 % or 120 % is a different test,
and its timing no longer matches the plan. Asking for the factor (``M220`` without ``S``) and ``M220
S100`` pass.
"""

from __future__ import annotations

import re
from typing import Optional

_M220 = re.compile(r"^\s*M220\b(.*)$", re.IGNORECASE)
_S = re.compile(r"\bS\s*(-?\d*\.?\d+)", re.IGNORECASE)
FILE_TAG = "source:file"


def changes_factor(cmd: str) -> Optional[float]:
    """The factor (%) an ``M220`` command sets (``R``, Marlin's restore: NaN); None when it
    is no M220 or sets nothing."""
    m = _M220.match(cmd)
    if not m:
        return None
    rest = m.group(1)
    s = _S.search(rest)
    if s:
        return float(s.group(1))
    if re.search(r"\bR\b", rest, re.IGNORECASE):
        return float("nan")
    return None


def held_back(cmd: str, tags, printing_test: bool) -> bool:
    """True when ``cmd`` would change the speed factor of a test program that is printing
    (and does not come from the program's own lines)."""
    if not printing_test or (tags and FILE_TAG in tags):
        return False
    factor = changes_factor(cmd)
    return factor is not None and factor != 100.0
