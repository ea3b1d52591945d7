"""The firmware's own compensation in force: skew, backlash and axis scale (issue 34).

KinComp learns it from what the firmware reports (``M503``: Marlin prints its settings as the
commands that set them) and from what is sent to it: skew (Marlin/Klipper ``M852 I J K``,
RepRapFirmware ``M556 S X Y Z``, Klipper ``SET_SKEW XY=ac,bd,ad`` and ``SKEW_PROFILE LOAD``),
backlash (``M425 X Y Z [F]``) and per-axis scale (RepRapFirmware ``M579 X Y Z``). Case does
not matter; a command that sets everything to zero (or ``F0``, ``SET_SKEW CLEAR=1``) turns the
kind off.

:class:`FirmwareCompensation` is the state: per kind the command in force (None: off) and
whether the state is known at all. It is recorded with every test (the run's
``firmware_compensation``; a trace's metadata key of the same name, :meth:`text`), so that a
test measured with the firmware compensating is analysed as what the firmware left over.

Conventions (``firmware/export.py``): KinComp's squareness ``xy`` (um/m) is Marlin's ``M852 I``
and Klipper's skew factor times 1e6; ``M556`` takes the deviation in mm over ``S`` mm with the
opposite sign (X: XY, Y: YZ, Z: ZX); a scale ``s`` (ppm) is ``M579`` factor ``1 / (1 + s)``;
``M425`` backlash in mm, ``F`` the share taken up. Imports ``core/`` only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Dict, Optional

from .export import klipper_skew_factor

KINDS = ("skew", "backlash", "scale")
_WORD = re.compile(r"([A-Za-z])\s*([-+]?\d*\.?\d+)")
# what a Marlin M503 reply always holds: seeing it means the firmware has reported its state
REPORT_MARKERS = ("M92", "M203", "M201")
# the commands that turn each kind off (the advice names them)
OFF = {
    "skew": {
        "M852": "M852 I0 J0 K0",
        "M556": "M556 S100 X0 Y0 Z0",
        "SET_SKEW": "SET_SKEW CLEAR=1",
        "SKEW_PROFILE": "SET_SKEW CLEAR=1",
    },
    "backlash": {"M425": "M425 F0"},
    "scale": {"M579": "M579 X1 Y1 Z1"},
}


def _values(text: str) -> Dict[str, float]:
    return {m.group(1).upper(): float(m.group(2)) for m in _WORD.finditer(text)}


@dataclass
class FirmwareCompensation:
    """What the firmware compensates itself: per kind the command in force as text (None:
    off); ``known``: whether the state is known (False: the firmware never reported it and
    nothing was sent: it may compensate anything)."""

    known: bool = False
    skew: Optional[str] = None
    backlash: Optional[str] = None
    scale: Optional[str] = None

    # -- reading commands ------------------------------------------------------------------
    def read(self, line: str, reported: bool = False) -> bool:
        """Update the state from one command or line (``echo:`` stripped by the caller;
        ``reported``: the firmware printed it, as M503 does: then the state is known);
        True when the line told something about it."""
        text = line.split(";", 1)[0].strip()
        up = text.upper()
        seen = False
        for code in ("M852", "M556"):
            rest = _after(up, text, code)
            if rest is not None:
                seen |= self._skew_cmd(code, rest)
        rest = _after(up, text, "M425")
        if rest is not None:
            seen |= self._backlash_cmd(rest)
        rest = _after(up, text, "M579")
        if rest is not None:
            seen |= self._scale_cmd(rest)
        if up.startswith("SET_SKEW"):
            seen = True
            self.skew = None if "CLEAR" in up else (text if "=" in up else self.skew)
        elif up.startswith("SKEW_PROFILE") and "LOAD" in up:
            seen = True
            self.skew = text
        if reported and (seen or any(up.startswith(m) for m in REPORT_MARKERS)):
            self.known = True
        return seen

    def _skew_cmd(self, code: str, rest: str) -> bool:
        vals = _values(rest)
        keys = ("I", "J", "K", "S") if code == "M852" else ("X", "Y", "Z")
        if code == "M556":
            vals.pop("S", None)
        if any(abs(vals.get(k, 0.0)) > 0 for k in keys):
            self.skew = f"{code}{rest.rstrip()}"
        elif any(k in vals for k in keys):
            self.skew = None
        else:
            return False
        return True

    def _backlash_cmd(self, rest: str) -> bool:
        vals = _values(rest)
        axes = [vals[k] for k in ("X", "Y", "Z") if k in vals]
        fraction = vals.get("F", 1.0)
        if axes:
            self.backlash = (
                f"M425{rest.rstrip()}" if any(abs(v) > 0 for v in axes) and fraction > 0 else None
            )
        elif "F" in vals and fraction == 0:
            self.backlash = None
        elif "F" in vals and self.backlash:  # a new fraction for the values in force
            self.backlash = self.backlash + f" F{fraction:g}"
        else:
            return False
        return True

    def _scale_cmd(self, rest: str) -> bool:
        vals = _values(rest)
        factors = [vals[k] for k in ("X", "Y", "Z") if k in vals]
        if any(abs(f - 1.0) > 1e-9 for f in factors):
            self.scale = f"M579{rest.rstrip()}"
        elif factors:
            self.scale = None
        else:
            return False
        return True

    # -- what it compensates -----------------------------------------------------------------
    @property
    def active(self) -> bool:
        return any(getattr(self, k) for k in KINDS)

    def kinds(self):
        """The kinds in force."""
        return [k for k in KINDS if getattr(self, k)]

    def skew_um_per_m(self) -> Optional[Dict[str, float]]:
        """The skew it corrects in KinComp's squareness keys and sign (um/m); None when off
        or when the values are not known (a Klipper skew profile loaded by name)."""
        cmd = self.skew
        if not cmd:
            return None
        up = cmd.upper()
        if up.startswith("M852"):
            v = _values(cmd[4:])
            xy = v.get("I", v.get("S", 0.0))
            return {"xy": xy * 1e6, "xz": v.get("J", 0.0) * 1e6, "yz": v.get("K", 0.0) * 1e6}
        if up.startswith("M556"):
            v = _values(cmd[4:])
            s = v.get("S", 100.0) or 100.0
            return {
                "xy": -v.get("X", 0.0) / s * 1e6,
                "yz": -v.get("Y", 0.0) / s * 1e6,
                "xz": -v.get("Z", 0.0) / s * 1e6,
            }
        if up.startswith("SET_SKEW"):
            out = {"xy": 0.0, "xz": 0.0, "yz": 0.0}
            for key, a, b, c in re.findall(r"(XY|XZ|YZ)\s*=\s*([\d.]+),([\d.]+),([\d.]+)", up):
                try:
                    out[key.lower()] = klipper_skew_factor(float(a), float(b), float(c)) * 1e6
                except (ValueError, ZeroDivisionError):
                    return None
            return out
        return None

    def backlash_um(self) -> Optional[Dict[str, float]]:
        """The play it takes up per axis (um, its fraction applied); None when off."""
        if not self.backlash:
            return None
        v = _values(self.backlash[4:])
        f = v.get("F", 1.0)
        return {a: v.get(a.upper(), 0.0) * 1e3 * f for a in "xyz"}

    def scale_ppm(self) -> Optional[Dict[str, float]]:
        """The axis scale it corrects (ppm, KinComp's sign); None when off."""
        if not self.scale:
            return None
        v = _values(self.scale[4:])
        return {a: (1.0 / v.get(a.upper(), 1.0) - 1.0) * 1e6 for a in "xyz"}

    def off_command(self, kind: str) -> str:
        """The command that turns ``kind`` off on this firmware."""
        cmd = (getattr(self, kind) or "").upper()
        for code, off in OFF[kind].items():
            if cmd.startswith(code):
                return off
        return next(iter(OFF[kind].values()))

    # -- documents -------------------------------------------------------------------------
    def text(self) -> str:
        """One line: the commands in force joined by ``; ``, ``none`` (known, nothing in
        force) or ``unknown``; :meth:`from_text` reads it back."""
        if self.active:
            return "; ".join(getattr(self, k) for k in KINDS if getattr(self, k))
        return "none" if self.known else "unknown"

    @staticmethod
    def from_text(text: Optional[str]) -> FirmwareCompensation:
        """The state a :meth:`text` (or an M503 reply, or commands one a line) describes."""
        out = FirmwareCompensation()
        body = (text or "").strip()
        if not body or body.lower() == "unknown":
            return out
        out.known = True
        if body.lower() == "none":
            return out
        for part in re.split(r"[;\n]", body):
            part = part.strip()
            if part.lower().startswith("echo:"):
                part = part[5:].strip()
            if part:
                out.read(part, reported=True)
        return out

    def to_dict(self) -> Dict[str, object]:
        return {
            "known": self.known,
            "skew": self.skew,
            "backlash": self.backlash,
            "scale": self.scale,
            "text": self.text(),
            "skew_um_per_m": self.skew_um_per_m(),
            "backlash_um": self.backlash_um(),
            "scale_ppm": self.scale_ppm(),
        }

    @staticmethod
    def from_dict(d) -> FirmwareCompensation:
        if not isinstance(d, dict):
            return FirmwareCompensation()
        return FirmwareCompensation(
            bool(d.get("known")),
            d.get("skew") or None,
            d.get("backlash") or None,
            d.get("scale") or None,
        )

    def same_as(self, other: FirmwareCompensation, kind: str) -> bool:
        """Whether ``other`` compensates ``kind`` with the same command."""
        a, b = getattr(self, kind), getattr(other, kind)
        return _norm(a) == _norm(b)


def _norm(cmd: Optional[str]) -> str:
    return " ".join((cmd or "").upper().split())


def _after(up: str, text: str, code: str) -> Optional[str]:
    """The text after ``code`` (a whole command word) in ``text``; None when absent."""
    i = up.find(code)
    if i < 0 or up[i + len(code) : i + len(code) + 1].isdigit():
        return None
    if i > 0 and up[i - 1].isalnum():
        return None
    return text[i + len(code) :]
