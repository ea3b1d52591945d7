"""The printer's motion limits, read from what the firmware says, and the feed a ballbar test
can really run at.

Units: feeds in mm/min (as G-code ``F``), speeds in mm/s, accelerations in mm/s^2, junction
deviation in mm. Axes are ``x``, ``y``, ``z``.

Sources (:func:`parse_limits` reads any mix of them from one text):

* the firmware's answer to ``M503`` (Marlin, Prusa, RepRapFirmware; ``echo:`` and ``Recv:``
  prefixes and comments are fine): ``M201`` axis max accelerations (mm/s^2), ``M203`` axis max
  feeds, ``M204`` accelerations (``P`` print, ``T`` travel, ``S`` both), ``M205`` ``J``
  junction deviation (mm) and ``X``/``Y``/``Z`` jerk (mm/s), RepRapFirmware's ``M566``
  instantaneous speed changes (mm/min, read as jerk in mm/s). ``M203`` is in mm/s on Marlin
  and Prusa but in mm/min on RepRapFirmware: the unit is taken from the line's own comment or
  the header above it ("Maximum feedrates (units/s)", "mm/min"), else from the firmware's
  name, else mm/s is assumed and said (``notes``);
* Klipper's ``printer.cfg`` ``[printer]`` section: ``max_velocity``, ``max_accel``,
  ``max_z_velocity``, ``max_z_accel``, ``square_corner_velocity`` (mm/s, mm/s^2),
  ``minimum_cruise_ratio`` (the older ``max_accel_to_decel`` read as ``1 - it / max_accel``),
  and ``SET_VELOCITY_LIMIT VELOCITY= ACCEL= SQUARE_CORNER_VELOCITY= MINIMUM_CRUISE_RATIO=``
  lines. What a Klipper text leaves out is Klipper's default, with its source saying so:
  ``square_corner_velocity`` 5 mm/s, ``minimum_cruise_ratio`` 0.5 (``klippy/toolhead.py``);
* OctoPrint's printer profile (axis speeds in mm/min): :meth:`MotionLimits.from_feeds`.

The firmware (:func:`firmware_kind`: ``marlin``, ``klipper``, ``reprapfirmware``) is the one
the firmware's name (``M115``) says, else the one the text's own lines show (Klipper's keys,
``M566``, Marlin's ``M205 J`` or its ``echo:`` lines); ``MotionLimits.firmware`` holds it, None
when nothing tells.

Several sources combine to the lower value of each limit (:meth:`MotionLimits.combined`):
a test must run on the printer as it is, whichever source is right.

Feasibility (:func:`circle_feed`): on a circle the peak speed of each axis equals the feed
(at the points where the path runs along that axis), so the feed may not exceed either
plane axis' max feed. The centripetal acceleration is ``v^2 / R``; Marlin's and Klipper's
planners limit a chord junction on a circle to ``v^2 <= a R`` with the move's acceleration,
which the slower of the two axes bounds where the path runs along it. And the feed must be
reached within the overshoot arc before the capture starts: ``v^2 <= 2 a R * overshoot``
(radians; from standstill at the feed-in corner, conservative). With ``a`` the lowest known
of the plane axes' max accelerations and the print acceleration.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple

from ..core.messages import Msg, joined
from ..core.numbers import finite_text

AXES = ("x", "y", "z")
FIRMWARES = ("marlin", "klipper", "reprapfirmware")  # the planners KinComp models
# what Klipper uses when printer.cfg does not say (klippy/toolhead.py: ToolHead.__init__)
KLIPPER_DEFAULTS = {"square_corner_velocity": 5.0, "minimum_cruise_ratio": 0.5}
PLANE_AXES = {"XY": ("x", "y"), "XZ": ("x", "z"), "YZ": ("y", "z")}
# below this feed (1 mm/s) a test is refused rather than run: a 50 mm vertical circle would
# take over four minutes per direction, long enough for the bar and frame to drift
MIN_TEST_FEED = 60.0  # mm/min
MAX_TEXT = 20000  # characters of limits text stored with the settings
# The bounds of each limit (exclusive low, inclusive high), the same wherever a limit comes
# from: typed (a trace's or truth file's motion settings, firmware/planner.py), pasted or
# read from the firmware (M503, printer.cfg) or a printer profile. Beyond them a value is
# no printer's (max_velocity: 1e307 made the feed Infinity, and /status a 500).
BOUNDS = {
    "max_feed_mm_min": (1.0, 1e6),  # mm/min (16,667 mm/s)
    "max_accel_mm_s2": (1.0, 1e6),  # mm/s^2
    "print_accel_mm_s2": (1.0, 1e6),  # mm/s^2
    "travel_accel_mm_s2": (1.0, 1e6),  # mm/s^2
    "junction_deviation_mm": (0.0, 10.0),  # mm
    "jerk_mm_s": (-1e-9, 1000.0),  # mm/s (0 allowed)
    "square_corner_velocity_mm_s": (0.0, 1000.0),  # mm/s
    "minimum_cruise_ratio": (-1e-9, 0.99),  # Klipper: 0 allowed, below 1
}


class LimitsError(ValueError):
    """A limits text that says nothing usable (names what was wrong)."""


@dataclass
class MotionLimits:
    """What one printer can do; a limit that is not known is absent (not zero)."""

    max_feed_mm_min: Dict[str, float] = field(default_factory=dict)
    max_accel_mm_s2: Dict[str, float] = field(default_factory=dict)
    print_accel_mm_s2: Optional[float] = None
    travel_accel_mm_s2: Optional[float] = None
    junction_deviation_mm: Optional[float] = None
    jerk_mm_s: Dict[str, float] = field(default_factory=dict)
    square_corner_velocity_mm_s: Optional[float] = None
    minimum_cruise_ratio: Optional[float] = None  # Klipper
    firmware: Optional[str] = None  # FIRMWARES: whose limits these are (None: not known)
    # where each limit came from, by key ("max_feed_mm_min.z": "M203")
    sources: Dict[str, str] = field(default_factory=dict)
    notes: List[Msg] = field(default_factory=list)  # what was assumed while reading

    def empty(self) -> bool:
        return not (
            self.max_feed_mm_min
            or self.max_accel_mm_s2
            or self.print_accel_mm_s2
            or self.travel_accel_mm_s2
            or self.junction_deviation_mm is not None
            or self.jerk_mm_s
            or self.square_corner_velocity_mm_s is not None
        )

    @staticmethod
    def from_feeds(feeds: Optional[Dict[str, float]], source: str) -> MotionLimits:
        """Axis max feeds (mm/min), e.g. OctoPrint's printer profile's axis speeds."""
        out = MotionLimits()
        for a, v in (feeds or {}).items():
            a = str(a).lower()
            try:
                v = float(v)
            except (TypeError, ValueError):
                continue
            if a in AXES and within("max_feed_mm_min", v):
                out.max_feed_mm_min[a] = v
                out.sources[f"max_feed_mm_min.{a}"] = source
        return out

    def combined(self, other: Optional[MotionLimits]) -> MotionLimits:
        """The lower of each limit of ``self`` and ``other`` (with its source)."""
        if other is None:
            return self
        out = MotionLimits(
            notes=list(self.notes) + list(other.notes), firmware=self.firmware or other.firmware
        )
        for key in ("max_feed_mm_min", "max_accel_mm_s2", "jerk_mm_s"):
            mine, theirs = getattr(self, key), getattr(other, key)
            for a in AXES:
                pick = _lower(mine.get(a), theirs.get(a))
                if pick is not None:
                    getattr(out, key)[a] = pick
                    src = self if pick == mine.get(a) else other
                    out.sources[f"{key}.{a}"] = src.sources.get(f"{key}.{a}", "")
        for key in (
            "print_accel_mm_s2",
            "travel_accel_mm_s2",
            "junction_deviation_mm",
            "square_corner_velocity_mm_s",
            "minimum_cruise_ratio",
        ):
            pick = _lower(getattr(self, key), getattr(other, key))
            if pick is not None:
                setattr(out, key, pick)
                src = self if pick == getattr(self, key) else other
                out.sources[key] = src.sources.get(key, "")
        return out

    def to_dict(self) -> Dict[str, Any]:
        """JSON form (notes as English text)."""
        return {
            "max_feed_mm_min": dict(self.max_feed_mm_min),
            "max_accel_mm_s2": dict(self.max_accel_mm_s2),
            "print_accel_mm_s2": self.print_accel_mm_s2,
            "travel_accel_mm_s2": self.travel_accel_mm_s2,
            "junction_deviation_mm": self.junction_deviation_mm,
            "jerk_mm_s": dict(self.jerk_mm_s),
            "square_corner_velocity_mm_s": self.square_corner_velocity_mm_s,
            "minimum_cruise_ratio": self.minimum_cruise_ratio,
            "firmware": self.firmware,
            "sources": dict(self.sources),
            "notes": [str(n) for n in self.notes],
        }


def _lower(a: Optional[float], b: Optional[float]) -> Optional[float]:
    vals = [v for v in (a, b) if v is not None]
    return min(vals) if vals else None


# ~~ reading ----------------------------------------------------------------------------------
_NUM = r"-?\d*\.?\d+(?:[eE][-+]?\d+)?"  # (an exponent too: 1e307 is read whole, then refused)
_GCODE = re.compile(
    r"(?:^|[\s:])(M20[1345]|M566)((?:\s+[A-Za-z]" + _NUM + r"(?::" + _NUM + r")*)+)"
    r"[^;]*(?:;(.*))?$"
)
_WORD = re.compile(r"([A-Za-z])(" + _NUM + r")")
_KLIPPER_KEYS = (
    "max_velocity",
    "max_accel",
    "max_z_velocity",
    "max_z_accel",
    "square_corner_velocity",
    "minimum_cruise_ratio",
    "max_accel_to_decel",
)
_CFG = re.compile(r"^\s*(" + "|".join(_KLIPPER_KEYS) + r")\s*[:=]\s*([-+0-9.eE]+)\s*$")
_SECTION = re.compile(r"^\s*\[([^\]]+)\]")
_SVL = re.compile(r"SET_VELOCITY_LIMIT\b(.*)$", re.IGNORECASE)
_MM_MIN = re.compile(r"mm\s*/\s*min|units\s*/\s*min|mm per min", re.IGNORECASE)
_MM_S = re.compile(r"(?:mm|units)\s*/\s*(?:s\b|sec)", re.IGNORECASE)


def settings_query(firmware: Optional[str]) -> List[str]:
    """The commands that ask ``firmware`` (its M115 name) for its settings: M503, and for
    Marlin M211 before it (Marlin's M503 leaves out the soft endstops, which keep every move
    inside the travel: :func:`narrowed_travel`)."""
    name = (firmware or "").lower()
    marlin = any(k in name for k in ("marlin", "prusa", "buddy"))
    return ["M211", "M503"] if marlin else ["M503"]


def firmware_feed_unit(firmware: Optional[str]) -> Optional[str]:
    """ "mm/min" for RepRapFirmware (its M203 takes mm/min), "mm/s" for Marlin, Prusa,
    Klipper and Smoothieware; None when the name says nothing."""
    name = (firmware or "").lower()
    if "reprapfirmware" in name or "rrf" in name or "duet" in name:
        return "mm/min"
    if any(k in name for k in ("marlin", "prusa", "klipper", "smoothie", "buddy")):
        return "mm/s"
    return None


def within(key: str, value: Optional[float]) -> bool:
    """Whether ``value`` is a finite number within the BOUNDS of the limit ``key``."""
    lo, hi = BOUNDS[key]
    return value is not None and math.isfinite(value) and lo < value <= hi


def out_of_bounds(limits: MotionLimits) -> Optional[Msg]:
    """The first limit of ``limits`` beyond its BOUNDS (with where it came from), else
    None."""
    for key, (lo, hi) in BOUNDS.items():
        value = getattr(limits, key)
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for axis, v in items:
            if v is None or within(key, v):
                continue
            name = f"{key}.{axis}" if axis else key
            return Msg(
                "%(name)s %(value)s (from %(source)s) is out of range (%(lo)s..%(hi)s)",
                name=name,
                value=f"{v:g}",
                source=limits.sources.get(name, "?"),
                lo=f"{max(lo, 0.0):g}",
                hi=f"{hi:g}",
            )
    return None


def _number(text: str) -> Optional[float]:
    return finite_text(text)


def firmware_kind(name: Optional[str]) -> Optional[str]:
    """Which planner a firmware's name (its ``M115`` FIRMWARE_NAME, or the name a user typed)
    means: ``klipper``, ``reprapfirmware`` (also Duet), ``marlin`` (also Prusa's firmware,
    which plans as Marlin); None when the name says none of them."""
    low = (name or "").strip().lower()
    if not low:
        return None
    if "klipper" in low:
        return "klipper"
    if "reprapfirmware" in low or "duet" in low or low in ("rrf", "reprap"):
        return "reprapfirmware"
    if "marlin" in low or "prusa" in low or "buddy" in low:
        return "marlin"
    return None


class _Reader:
    """The state of :func:`parse_limits` over the lines of one text."""

    def __init__(self, out: MotionLimits, fw_unit: Optional[str]):
        self.out = out
        self.fw_unit = fw_unit
        self.header_unit: Optional[str] = None
        self.section: Optional[str] = None
        self.klipper: Dict[str, float] = {}
        self.seen: Dict[str, bool] = {}  # what the lines show of the firmware

    def line(self, raw: str) -> None:
        line = raw.strip()
        if not line:
            return
        m = _SECTION.match(line)
        if m:
            self.section = m.group(1).strip().lower()
            return
        m = _CFG.match(line.split("#")[0])
        if m and self.section in (None, "printer"):
            v = _number(m.group(2))
            if v is not None and (v > 0 or v == 0 and m.group(1) == "minimum_cruise_ratio"):
                self.klipper[m.group(1)] = v
            return
        m = _SVL.search(line)
        if m:
            self._set_velocity_limit(m.group(1))
            return
        m = _GCODE.search(line)
        if not m:
            # a header such as "echo:; Maximum feedrates (units/s):" sets the next M203's unit
            if "feedrate" in line.lower() or "maximum speed" in line.lower():
                self.header_unit = (
                    "mm/min"
                    if _MM_MIN.search(line)
                    else "mm/s"
                    if _MM_S.search(line)
                    else self.header_unit
                )
                self.seen["marlin"] = self.seen.get("marlin") or "units/s" in line.lower()
            return
        if line.lower().startswith(("echo:", "recv: echo:")):
            self.seen["marlin"] = True
        code, words, comment = m.group(1), m.group(2), m.group(3) or ""
        vals = {k.upper(): _number(v) for k, v in _WORD.findall(words)}
        getattr(self, "_" + code.lower())(vals, comment)

    def _set_velocity_limit(self, words: str) -> None:
        for key, val in re.findall(r"(\w+)\s*=\s*([-+0-9.eE]+)", words):
            v = _number(val)
            name = {
                "velocity": "max_velocity",
                "accel": "max_accel",
                "square_corner_velocity": "square_corner_velocity",
                "minimum_cruise_ratio": "minimum_cruise_ratio",
                "accel_to_decel": "max_accel_to_decel",
            }.get(key.lower())
            if name and v is not None and (v > 0 or v == 0 and name == "minimum_cruise_ratio"):
                self.klipper[name] = v

    def _m203(self, vals, comment: str) -> None:
        out = self.out
        unit = (
            "mm/min"
            if _MM_MIN.search(comment)
            else "mm/s"
            if _MM_S.search(comment)
            else self.header_unit or self.fw_unit
        )
        if unit is None:
            unit = "mm/s"
            out.notes.append(
                Msg(
                    "M203 has no stated unit: read as mm/s (Marlin's); RepRapFirmware states mm/min"
                )
            )
        factor = 1.0 if unit == "mm/min" else 60.0
        for a in AXES:
            v = vals.get(a.upper())
            if v is not None and v > 0:
                out.max_feed_mm_min[a] = v * factor
                out.sources[f"max_feed_mm_min.{a}"] = f"M203 ({unit})"
        self.header_unit = None

    def _m201(self, vals, comment: str) -> None:
        for a in AXES:
            v = vals.get(a.upper())
            if v is not None and v > 0:
                self.out.max_accel_mm_s2[a] = v
                self.out.sources[f"max_accel_mm_s2.{a}"] = "M201"

    def _m204(self, vals, comment: str) -> None:
        out = self.out
        if vals.get("S") and vals["S"] > 0:
            out.print_accel_mm_s2 = out.travel_accel_mm_s2 = vals["S"]
            out.sources["print_accel_mm_s2"] = out.sources["travel_accel_mm_s2"] = "M204 S"
        if vals.get("P") and vals["P"] > 0:
            out.print_accel_mm_s2 = vals["P"]
            out.sources["print_accel_mm_s2"] = "M204 P"
        if vals.get("T") and vals["T"] > 0:
            out.travel_accel_mm_s2 = vals["T"]
            out.sources["travel_accel_mm_s2"] = "M204 T"

    def _m205(self, vals, comment: str) -> None:
        out = self.out
        if vals.get("J") is not None and vals["J"] > 0:
            out.junction_deviation_mm = vals["J"]
            out.sources["junction_deviation_mm"] = "M205 J"
            self.seen["marlin"] = True  # (RepRapFirmware's M205 has no J)
        for a in AXES:
            v = vals.get(a.upper())
            if v is not None and v >= 0:
                out.jerk_mm_s[a] = v
                out.sources[f"jerk_mm_s.{a}"] = "M205"

    def _m566(self, vals, comment: str) -> None:
        """RepRapFirmware's instantaneous speed changes, in mm/min."""
        self.seen["reprapfirmware"] = True
        for a in AXES:
            v = vals.get(a.upper())
            if v is not None and v >= 0:
                self.out.jerk_mm_s[a] = v / 60.0
                self.out.sources[f"jerk_mm_s.{a}"] = "M566 (mm/min)"

    def firmware(self) -> Optional[str]:
        """What the lines show of the firmware (None: nothing)."""
        if self.klipper:
            return "klipper"
        if self.seen.get("reprapfirmware"):
            return "reprapfirmware"
        if self.seen.get("marlin"):
            return "marlin"
        return None


def parse_limits(text: str, firmware: Optional[str] = None) -> MotionLimits:
    """The limits stated in ``text`` (see the module docstring); ``firmware`` is the
    firmware's name (M115), which decides M203's unit when the text does not. Raises
    LimitsError when the text states none of them, or one beyond its BOUNDS."""
    if not isinstance(text, str):
        raise LimitsError(Msg("the motion limits must be a text"))
    out = MotionLimits()
    rrf_text = re.search(r"reprapfirmware", text, re.IGNORECASE) is not None
    fw_unit = firmware_feed_unit(firmware) or ("mm/min" if rrf_text else None)
    reader = _Reader(out, fw_unit)
    for raw in text.splitlines():
        reader.line(raw)
    if reader.klipper:
        _apply_klipper(out, reader.klipper)
    bad = out_of_bounds(out)
    if bad is not None:
        raise LimitsError(bad)
    if out.empty():
        raise LimitsError(
            Msg(
                "no motion limits found: paste the printer's answer to M503 (M201, M203, M204, "
                "M205 lines) or Klipper's [printer] section (max_velocity, max_accel, "
                "max_z_velocity, max_z_accel)"
            )
        )
    out.firmware = (
        firmware_kind(firmware) or reader.firmware() or ("reprapfirmware" if rrf_text else None)
    )
    return out


_M92 = re.compile(r"(?:^|[\s:])M92((?:\s+[A-Za-z]-?\d*\.?\d+)+)")
_STEPPER = re.compile(r"^\s*(rotation_distance|microsteps|full_steps_per_rotation)\s*[:=]\s*(\S+)")


def steps_per_mm(text: str) -> Dict[str, float]:
    """The drives' resolution (steps per mm, by axis ``x``, ``y``, ``z``) that ``text``
    states, if any: Marlin's ``M92`` line (its answer to M503, the last one counts) or
    Klipper's ``[stepper_x]``..``[stepper_z]`` sections (``full_steps_per_rotation``
    (default 200) times ``microsteps`` over ``rotation_distance`` mm). Never raises: what
    is missing or unreadable is left out."""
    out: Dict[str, float] = {}
    if not isinstance(text, str):
        return out
    section: Optional[str] = None
    stepper: Dict[str, Dict[str, float]] = {}
    for raw in text.splitlines():
        m = _SECTION.match(raw)
        if m:
            section = m.group(1).strip().lower()
            continue
        m = _STEPPER.match(raw.split("#")[0])
        if m and section in ("stepper_x", "stepper_y", "stepper_z"):
            v = _number(m.group(2))
            if v is not None and v > 0:
                stepper.setdefault(section[-1], {})[m.group(1)] = v
            continue
        m = _M92.search(raw.split(";")[0])
        if m:
            for k, v in _WORD.findall(m.group(1)):
                value = _number(v)
                if k.lower() in AXES and value is not None and value > 0:
                    out[k.lower()] = value
    for axis, cfg in stepper.items():
        if "rotation_distance" in cfg and "microsteps" in cfg:
            full = cfg.get("full_steps_per_rotation", 200.0)
            out.setdefault(axis, full * cfg["microsteps"] / cfg["rotation_distance"])
    return out


_POSITION = re.compile(r"^\s*(position_min|position_max)\s*[:=]\s*(\S+)")
_M208 = re.compile(r"(?:^|[\s:])M208\b([^;]*)")
_M208_AXIS = re.compile(r"([XYZxyz])\s*(-?\d*\.?\d+)(?:\s*:\s*(-?\d*\.?\d+))?")
_M211_BOX = re.compile(r"Min:\s*(.*?)\s*Max:\s*(.*)$", re.IGNORECASE)
_RRF_REPORT = re.compile(r"Axis limits[^X]*(.*)$", re.IGNORECASE)


def travel_limits(text: str) -> Dict[str, Tuple[Optional[float], Optional[float]]]:
    """The printer's travel as the firmware states it (mm, per axis ``x``/``y``/``z``: (min,
    max), None where that end is not stated; axes not stated are left out): Klipper's
    ``position_min``/``position_max`` of ``[stepper_x]``.. (position_min defaults to 0 when
    position_max is stated), Marlin's answer to ``M211`` (``Min: X.. Y.. Z..  Max: X..``),
    RepRapFirmware's ``M208`` in ``config.g`` (``M208 X-5:230``, ``M208 S1 X-5`` the minima,
    ``M208 X230`` the maxima) or its reply ``Axis limits (mm) X-5.0:230.0, ...``. The last
    statement of each counts. Never raises."""
    out: Dict[str, List[Optional[float]]] = {}
    if not isinstance(text, str):
        return {}
    section: Optional[str] = None
    for raw in text.splitlines():
        m = _SECTION.match(raw)
        if m:
            section = m.group(1).strip().lower()
            continue
        if section in ("stepper_x", "stepper_y", "stepper_z"):
            m = _POSITION.match(raw.split("#")[0])
            if m:
                v = _number(m.group(2))
                if v is not None:
                    end = out.setdefault(section[-1], [None, None])
                    end[0 if m.group(1) == "position_min" else 1] = v
            continue
        line = raw.split(";")[0]
        m = _M211_BOX.search(line)
        if m:
            for i, part in enumerate(m.groups()):
                for k, v in _WORD.findall(part):
                    value = _number(v)
                    if k.lower() in AXES and value is not None:
                        out.setdefault(k.lower(), [None, None])[i] = value
            continue
        m = _M208.search(line) or _RRF_REPORT.search(line)
        if m:
            body = m.group(1)
            lower = re.search(r"\bS1\b", body) is not None
            for k, a, b in _M208_AXIS.findall(re.sub(r"\bS[01]\b", "", body)):
                first, second = _number(a), _number(b) if b else None
                end = out.setdefault(k.lower(), [None, None])
                if b:
                    end[0], end[1] = first, second
                else:
                    end[0 if lower else 1] = first
    result = {}
    for axis, (lo, hi) in out.items():
        if lo is None and hi is not None and _is_klipper(text):
            lo = 0.0  # (Klipper's default position_min)
        if lo is not None and hi is not None and lo >= hi:
            continue
        result[axis] = (lo, hi)
    return result


def _is_klipper(text: str) -> bool:
    return re.search(r"^\s*\[stepper_[xyz]\]", text, re.MULTILINE) is not None


def narrowed_travel(limits: Optional[Tuple[float, ...]], text: str) -> Optional[Tuple[float, ...]]:
    """The printer profile's ``limits`` (x0, x1, y0, y1, z0, z1 mm, or None) narrowed by the
    travel the firmware states in ``text`` (:func:`travel_limits`): each end the nearer of
    the two. An end the firmware states is used alone where the profile has none; None when
    neither gives a complete box."""
    stated = travel_limits(text)
    if limits is None:
        if not all(a in stated and None not in stated[a] for a in AXES):
            return None
        return tuple(v for a in AXES for v in stated[a])
    out = list(limits)
    for k, axis in enumerate(AXES):
        lo, hi = stated.get(axis, (None, None))
        if lo is not None:
            out[2 * k] = max(out[2 * k], lo)
        if hi is not None:
            out[2 * k + 1] = min(out[2 * k + 1], hi)
        if out[2 * k] >= out[2 * k + 1]:  # (the two disagree: the profile's holds)
            out[2 * k], out[2 * k + 1] = limits[2 * k], limits[2 * k + 1]
    return tuple(out)


def _apply_klipper(out: MotionLimits, cfg: Dict[str, float]) -> None:
    """Klipper's limits: ``max_velocity`` bounds the toolhead's speed (so each axis too),
    ``max_z_velocity`` the Z component (default: max_velocity); the same for accel. The
    square-corner velocity and the minimum cruise ratio not stated are Klipper's defaults."""
    v, a = cfg.get("max_velocity"), cfg.get("max_accel")
    vz, az = cfg.get("max_z_velocity", v), cfg.get("max_z_accel", a)
    for axis, vel, src in (
        ("x", v, "max_velocity"),
        ("y", v, "max_velocity"),
        ("z", vz, "max_z_velocity" if "max_z_velocity" in cfg else "max_velocity"),
    ):
        if vel is not None:
            out.max_feed_mm_min[axis] = vel * 60.0
            out.sources[f"max_feed_mm_min.{axis}"] = f"Klipper {src}"
    for axis, acc, src in (
        ("x", a, "max_accel"),
        ("y", a, "max_accel"),
        ("z", az, "max_z_accel" if "max_z_accel" in cfg else "max_accel"),
    ):
        if acc is not None:
            out.max_accel_mm_s2[axis] = acc
            out.sources[f"max_accel_mm_s2.{axis}"] = f"Klipper {src}"
    if a is not None:
        out.print_accel_mm_s2 = a
        out.sources["print_accel_mm_s2"] = "Klipper max_accel"
    if "square_corner_velocity" in cfg:
        out.square_corner_velocity_mm_s = cfg["square_corner_velocity"]
        out.sources["square_corner_velocity_mm_s"] = "Klipper square_corner_velocity"
    else:  # Klipper's own default (klippy/toolhead.py), which its planner then uses
        out.square_corner_velocity_mm_s = KLIPPER_DEFAULTS["square_corner_velocity"]
        out.sources["square_corner_velocity_mm_s"] = "Klipper default (not stated)"
    if "minimum_cruise_ratio" in cfg:
        out.minimum_cruise_ratio = cfg["minimum_cruise_ratio"]
        out.sources["minimum_cruise_ratio"] = "Klipper minimum_cruise_ratio"
    elif "max_accel_to_decel" in cfg and a:  # before Klipper 0.12.0-170 (2024)
        out.minimum_cruise_ratio = min(max(1.0 - cfg["max_accel_to_decel"] / a, 0.0), 0.99)
        out.sources["minimum_cruise_ratio"] = "Klipper max_accel_to_decel"
    else:
        out.minimum_cruise_ratio = KLIPPER_DEFAULTS["minimum_cruise_ratio"]
        out.sources["minimum_cruise_ratio"] = "Klipper default (not stated)"


# ~~ feasibility ------------------------------------------------------------------------------
@dataclass
class FeedChoice:
    """The feed a circle runs at and why it is lower than asked (``reasons``, empty when it
    is not); ``unknown``: plane axes whose max feed nobody stated."""

    feed_mm_min: float
    requested_mm_min: float
    reasons: List[Msg] = field(default_factory=list)
    unknown: List[str] = field(default_factory=list)

    @property
    def lowered(self) -> bool:
        return self.feed_mm_min < self.requested_mm_min


def circle_feed(
    plane: str,
    radius_mm: float,
    feed_mm_min: float,
    limits: Optional[MotionLimits],
    overshoot_deg: float = 20.0,
) -> FeedChoice:
    """The highest feed (mm/min, at most ``feed_mm_min``, whole mm/min) at which every axis
    of ``plane`` can follow a circle of ``radius_mm`` (see the module docstring). Raises
    LimitsError naming the binding limit when that is below MIN_TEST_FEED."""
    axes = PLANE_AXES[str(plane).upper()]
    limits = limits or MotionLimits()
    feed = float(feed_mm_min)
    best = feed
    reasons: List[Msg] = []
    candidates = []
    for a in axes:
        cap = limits.max_feed_mm_min.get(a)
        if cap is not None:
            candidates.append(
                (
                    cap,
                    Msg(
                        "the %(axis)s axis' max feed is %(cap)s mm/min (%(source)s)",
                        axis=a.upper(),
                        cap=f"{cap:g}",
                        source=limits.sources.get(f"max_feed_mm_min.{a}", "-"),
                    ),
                )
            )
    accels = [
        (limits.max_accel_mm_s2[a], f"max_accel_mm_s2.{a}", a.upper())
        for a in axes
        if a in limits.max_accel_mm_s2
    ]
    if limits.print_accel_mm_s2:
        accels.append((limits.print_accel_mm_s2, "print_accel_mm_s2", None))
    if accels:
        acc, key, axis = min(accels)
        r = float(radius_mm)
        ramp = 2.0 * r * math.radians(max(overshoot_deg, 0.0))
        v = math.sqrt(acc * min(r, ramp) if ramp > 0 else acc * r) * 60.0
        what = (
            Msg("the %(axis)s axis' max acceleration", axis=axis)
            if axis
            else Msg("the print acceleration")
        )
        candidates.append(
            (
                v,
                Msg(
                    "%(what)s of %(acc)s mm/s² (%(source)s) allows at most %(cap)s mm/min on a "
                    "%(radius)s mm circle (reached within the %(overshoot)s° overshoot)",
                    what=what,
                    acc=f"{acc:g}",
                    source=limits.sources.get(key, "-"),
                    cap=f"{math.floor(v):g}",
                    radius=f"{r:g}",
                    overshoot=f"{overshoot_deg:g}",
                ),
            )
        )
    for cap, _why in candidates:
        if cap < best - 1e-9:
            best = cap
    for cap, why in candidates:
        if cap < feed - 1e-9 and abs(cap - best) <= 1e-9:
            reasons.append(why)
    if best < feed - 1e-9:
        best = float(math.floor(best)) if best >= 1 else best
    if best < MIN_TEST_FEED:
        raise LimitsError(
            Msg(
                "a %(radius)s mm circle in %(plane)s cannot run at a usable feed: %(why)s, below "
                "the %(min)s mm/min a test needs. Check the printer's limits (M203, M201, "
                "M204)",
                radius=f"{float(radius_mm):g}",
                plane=str(plane).upper(),
                why=joined(reasons) if reasons else Msg("the feed asked is too low"),
                min=f"{MIN_TEST_FEED:g}",
            )
        )
    unknown = [a for a in axes if a not in limits.max_feed_mm_min]
    return FeedChoice(best, feed, reasons, unknown)


def require_known(choice: FeedChoice, plane: str) -> None:
    """Refuse (LimitsError) a vertical-plane test whose Z max feed nobody stated: Z is the
    slow axis of most printers (5-12 mm/s), far below a typical circle feed, and a capped
    axis distorts the circle's timing. (XY feeds of ~30 mm/s are within every printer's
    reach; unknown X/Y limits are only said in the program's header.)"""
    if "z" in choice.unknown:
        raise LimitsError(
            Msg(
                "the Z axis' max feed is not known, and a %(plane)s circle at %(feed)s mm/min "
                "needs Z to reach %(feed)s mm/min: give the printer's limits (its answer to "
                "M503, or Klipper's printer.cfg) or the axes' max feeds",
                plane=str(plane).upper(),
                feed=f"{choice.feed_mm_min:g}",
            )
        )


def describe(choice: FeedChoice) -> List[str]:
    """G-code comment lines (without ';') saying how the feed was chosen."""
    out = []
    if choice.lowered:
        out.append(
            f"feed lowered from {choice.requested_mm_min:g} to "
            f"{choice.feed_mm_min:g} mm/min: " + "; ".join(str(r) for r in choice.reasons)
        )
    if choice.unknown:
        out.append(
            "max feed not known for axis "
            + ", ".join(a.upper() for a in choice.unknown)
            + f": assumed it reaches {choice.feed_mm_min:g} mm/min"
        )
    return out


def axes_text(values: Dict[str, float]) -> str:
    return ", ".join(f"{a.upper()} {values[a]:g}" for a in AXES if a in values)


def limits_from_sequence(
    feeds: Optional[Sequence[float]], accels: Optional[Sequence[float]], source: str
) -> MotionLimits:
    """Limits given as X,Y,Z triples (feeds mm/min, accelerations mm/s^2), e.g. the CLI's
    ``--max-feed`` and ``--max-accel``."""
    out = MotionLimits.from_feeds(dict(zip(AXES, feeds or ())), source)
    for a, v in zip(AXES, accels or ()):
        if within("max_accel_mm_s2", v):
            out.max_accel_mm_s2[a] = float(v)
            out.sources[f"max_accel_mm_s2.{a}"] = source
    return out
