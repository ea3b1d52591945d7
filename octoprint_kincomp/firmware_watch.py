"""Notices when the firmware compensates too (double compensation), from what it reports
(``M503`` lines) and from what is sent to it (``M852``, ``M425``, ``M556``, ``SET_SKEW``)."""

from __future__ import annotations

import re
from typing import Dict, Optional

_WORD = re.compile(r"([A-Za-z])\s*([-+]?\d*\.?\d+)")


def _values(text: str) -> Dict[str, float]:
    return {m.group(1).upper(): float(m.group(2)) for m in _WORD.finditer(text)}


class FirmwareWatcher:
    """Tracks whether the firmware applies skew or backlash compensation itself."""

    def __init__(self):
        self.skew: Optional[str] = None  # where it was seen, e.g. "M852 I0.001 (sent)"
        self.backlash: Optional[str] = None

    def reset(self) -> None:
        self.skew = None
        self.backlash = None

    def _skew_cmd(self, code: str, rest: str, where: str) -> None:
        vals = _values(rest)
        keys = ("I", "J", "K", "S") if code == "M852" else ("X", "Y", "Z")
        if any(abs(vals.get(k, 0.0)) > 0 for k in keys):
            self.skew = f"{code}{rest.rstrip()} ({where})"
        elif any(k in vals for k in keys):
            self.skew = None

    def _backlash_cmd(self, rest: str, where: str) -> None:
        vals = _values(rest)
        axes = [vals[k] for k in ("X", "Y", "Z") if k in vals]
        fraction = vals.get("F", 1.0)
        if axes:
            if any(abs(v) > 0 for v in axes) and fraction > 0:
                self.backlash = f"M425{rest.rstrip()} ({where})"
            else:
                self.backlash = None
        elif "F" in vals and fraction == 0:
            self.backlash = None

    def _line(self, text: str, where: str) -> None:
        text = text.split(";", 1)[0].strip()
        low = text.upper()
        for code in ("M852", "M556"):
            i = low.find(code)
            if i >= 0 and not low[i + 4: i + 5].isdigit():
                self._skew_cmd(code, text[i + 4:], where)
        i = low.find("M425")
        if i >= 0 and not low[i + 4: i + 5].isdigit():
            self._backlash_cmd(text[i + 4:], where)
        if low.startswith("SET_SKEW"):
            if "CLEAR" in low:
                self.skew = None
            elif "=" in low:
                self.skew = f"{text} ({where})"

    def sent(self, cmd: str) -> None:
        """A command on its way to the printer."""
        self._line(cmd, "sent")

    def received(self, line: str) -> None:
        """A line from the printer (M503 prints the settings as commands after 'echo:')."""
        body = line.strip()
        if body.lower().startswith("echo:"):
            body = body[5:]
        self._line(body, "reported by the firmware")

    def conflicts(self, params) -> Dict[str, str]:
        """What KinComp and the firmware would both compensate."""
        out = {}
        sq = params.squareness_um_per_m
        if self.skew and any(sq[k] != 0.0 for k in sq):
            out["skew"] = self.skew
        if self.backlash and params.has_backlash:
            out["backlash"] = self.backlash
        return out
