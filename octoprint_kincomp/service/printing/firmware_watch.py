"""Notices when the firmware compensates too (double compensation), from what it reports
(``M503`` lines, which KinComp asks a Marlin firmware for after its ``M115`` reply) and from
what is sent to it: skew (Marlin/Klipper ``M852``, RepRapFirmware ``M556``, Klipper
``SET_SKEW``), backlash (``M425``) and per-axis scale (RepRapFirmware ``M579``). Case does
not matter."""

from __future__ import annotations

import re
from typing import Dict, Optional

_WORD = re.compile(r"([A-Za-z])\s*([-+]?\d*\.?\d+)")
# commands (upper case) whose lines the watcher reads; callers pre-filter with these
HINTS = ("M852", "M425", "M556", "M579", "SET_SKEW")


def _values(text: str) -> Dict[str, float]:
    return {m.group(1).upper(): float(m.group(2)) for m in _WORD.finditer(text)}


class FirmwareWatcher:
    """Tracks whether the firmware applies skew or backlash compensation itself."""

    def __init__(self):
        self.skew: Optional[str] = None  # where it was seen, e.g. "M852 I0.001 (sent)"
        self.backlash: Optional[str] = None
        self.scale: Optional[str] = None

    def reset(self) -> None:
        self.skew = None
        self.backlash = None
        self.scale = None

    @staticmethod
    def relevant(text: str) -> bool:
        """Cheap pre-filter: does ``text`` mention a command the watcher reads?"""
        up = text.upper()
        return any(h in up for h in HINTS)

    def _scale_cmd(self, rest: str, where: str) -> None:
        vals = _values(rest)
        factors = [vals[k] for k in ("X", "Y", "Z") if k in vals]
        if any(abs(f - 1.0) > 1e-9 for f in factors):
            self.scale = f"M579{rest.rstrip()} ({where})"
        elif factors:
            self.scale = None

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
            if i >= 0 and not low[i + 4 : i + 5].isdigit():
                self._skew_cmd(code, text[i + 4 :], where)
        i = low.find("M425")
        if i >= 0 and not low[i + 4 : i + 5].isdigit():
            self._backlash_cmd(text[i + 4 :], where)
        i = low.find("M579")
        if i >= 0 and not low[i + 4 : i + 5].isdigit():
            self._scale_cmd(text[i + 4 :], where)
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
        if self.scale and any(v != 0.0 for v in params.scale_ppm.values()):
            out["scale"] = self.scale
        return out
