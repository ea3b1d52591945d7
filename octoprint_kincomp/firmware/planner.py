"""Lookahead motion planner: where a firmware really puts the head, as a function of time.

Units: mm, s, mm/s, mm/s^2; feeds in the G-code and ``max_feed_mm_min`` in mm/min.

What it models (each firmware's planner as its source has it; docs/marlin.md, docs/klipper.md
and docs/reprapfirmware.md say what KinComp relies on and how it was checked):

* every move runs a trapezoidal velocity profile: accelerate from its entry speed, cruise at
  its nominal speed, decelerate to its exit speed (a short move may never reach its nominal
  speed: triangle profile);
* the nominal speed is the programmed feed, lowered so that no axis exceeds its own maximum
  (``max_feed_mm_min`` per axis: Marlin's and RepRapFirmware's ``M203``, Klipper's
  ``max_velocity`` and ``max_z_velocity``) and, on Klipper, the toolhead's
  ``max_velocity_mm_s`` along the path;
* each move's own acceleration is ``accel_mm_s2`` (Marlin: ``M204 T``, the travel
  acceleration of a move without E; Klipper: ``max_accel``; RepRapFirmware: ``M204 T``, only
  for moves of X or Y) lowered so that no axis exceeds its ``max_accel_mm_s2`` (``M201``,
  Klipper's ``max_z_accel``): a move with Z accelerates at most ``max_z_accel L / |dz|``;
* the speed at a junction between two moves is the firmware's own (``planner`` and
  :mod:`.junctions`): Marlin's junction deviation ``junction_deviation_mm`` with its
  small-segment limit, or Marlin's classic jerk (``jerk_mm_s``, when no junction deviation
  is given); Klipper's square-corner velocity with each move's own acceleration and its
  centripetal limit; RepRapFirmware's per-drive jerk (``M566``) that never joins an X/Y move
  to a Z-only one; a reversal stops;
* Klipper's lookahead with its ``minimum_cruise_ratio`` (default 0.5); the others' lookahead
  plans every stop-to-stop run whole (a firmware's block buffer of 16 moves covers the
  braking distance of these tests);
* full stops: at ``M400``, ``M0``/``M1``, the pause commands of KinComp's programs
  (Klipper's ``PAUSE``, RepRapFirmware's ``M226`` and ``M291 S2``/``S3``), before and after
  every ``G4`` dwell, at homing and at the start and end of the program;
* ``constant_speed``: every move at its nominal speed from the first instant (no
  acceleration), the simulator's former behaviour, kept as an explicit option.

Left out: S-curve (jerk-limited) acceleration and input shaping (they change how a move's
speed changes within it, not its trapezoid), Marlin's minimum planner speed (0.05 mm/s at a
stop, taken as 0) and its slow-down when the block buffer runs low (``SLOWDOWN``: a serial
line too slow for the moves), the extruder's own limits (test programs do not extrude).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from ..core.gcode import parse_command
from ..core.gcode_table import STOP, classify
from ..core.messages import Msg
from ..core.params import AXES, ParamsError
from . import junctions
from .interpreter import Dwell, FirmwareInterpreter, Home, Move
from .motion_limits import BOUNDS, FIRMWARES, KLIPPER_DEFAULTS, MotionLimits

DEFAULT_ACCEL = 1500.0  # mm/s^2, a typical desktop printer's print acceleration
DEFAULT_JD = 0.013  # mm, Marlin's default junction deviation
DEFAULT_MAX_FEED = {"x": 18000.0, "y": 18000.0, "z": 2400.0}  # mm/min (300, 300, 40 mm/s)
KLIPPER_SCV = KLIPPER_DEFAULTS["square_corner_velocity"]  # mm/s, when printer.cfg does not say
KLIPPER_MCR = KLIPPER_DEFAULTS["minimum_cruise_ratio"]
# mm/s: RepRapFirmware 3.5's instantaneous speed changes when config.g sets no M566
RRF_JERK = {"x": 15.0, "y": 15.0, "z": 10.0}
SQRT2_1 = math.sqrt(2.0) - 1.0


@dataclass
class MotionSettings:
    """Planner settings of one printer (see the module docstring). ``planner`` is the
    firmware whose planner runs (``marlin``, ``klipper``, ``reprapfirmware``); None: Klipper
    when a square-corner velocity is given, else Marlin (traces of before it was recorded)."""

    accel_mm_s2: float = DEFAULT_ACCEL
    junction_deviation_mm: Optional[float] = DEFAULT_JD
    square_corner_velocity_mm_s: Optional[float] = None  # Klipper; replaces the JD
    max_feed_mm_min: Dict[str, float] = field(default_factory=lambda: dict(DEFAULT_MAX_FEED))
    max_accel_mm_s2: Optional[Dict[str, float]] = None
    constant_speed: bool = False
    small_segments: bool = True  # Marlin's JD_HANDLE_SMALL_SEGMENTS
    estimated: bool = False  # found from a trace's own transients, not given
    planner: Optional[str] = None
    jerk_mm_s: Optional[Dict[str, float]] = None  # Marlin's classic jerk, RRF's M566
    minimum_cruise_ratio: Optional[float] = None  # Klipper (None: its default 0.5)
    max_velocity_mm_s: Optional[float] = None  # Klipper's max_velocity along the path

    KEYS = (
        "motion",
        "planner",
        "accel_mm_s2",
        "junction_deviation_mm",
        "square_corner_velocity_mm_s",
        "minimum_cruise_ratio",
        "max_velocity_mm_s",
        "jerk_mm_s",
        "max_feed_mm_min",
        "max_accel_mm_s2",
    )

    @property
    def firmware(self) -> str:
        """The firmware whose planner runs (see the class docstring)."""
        if self.planner:
            return self.planner
        return "klipper" if self.square_corner_velocity_mm_s is not None else "marlin"

    @property
    def klipper(self) -> bool:
        return self.firmware == "klipper"

    @property
    def classic_jerk(self) -> bool:
        """Marlin with classic jerk (``M205 X Y Z``) instead of junction deviation."""
        return self.firmware == "marlin" and not self.junction_deviation_mm and bool(self.jerk_mm_s)

    @property
    def scv(self) -> float:
        """Klipper's square-corner velocity (mm/s), its default when not given."""
        v = self.square_corner_velocity_mm_s
        return KLIPPER_SCV if v is None else float(v)

    @property
    def mcr(self) -> float:
        """Klipper's minimum cruise ratio, its default when not given."""
        return (
            KLIPPER_MCR if self.minimum_cruise_ratio is None else float(self.minimum_cruise_ratio)
        )

    @property
    def corner_speed_90(self) -> float:
        """Junction speed (mm/s) of a 90 degree corner of X into Y at the base acceleration
        (the program's feed-in corners)."""
        fw = self.firmware
        if fw == "klipper":
            return self.scv
        if fw == "reprapfirmware" or self.classic_jerk:
            jerk = self.jerks()
            return float(min(jerk[0], jerk[1]))
        s = math.sqrt(0.5)
        return math.sqrt(self.accel_mm_s2 * (self.junction_deviation_mm or 0.0) * s / (1 - s))

    def caps(self) -> np.ndarray:
        return np.array(
            [float(self.max_feed_mm_min.get(a, math.inf) or math.inf) / 60.0 for a in AXES]
        )

    def axis_accels(self) -> Optional[np.ndarray]:
        if not self.max_accel_mm_s2:
            return None
        return np.array([float(self.max_accel_mm_s2.get(a, math.inf) or math.inf) for a in AXES])

    def jerks(self) -> np.ndarray:
        """The axes' jerk (mm/s): given, RepRapFirmware's defaults, else none (inf)."""
        given = self.jerk_mm_s or (RRF_JERK if self.firmware == "reprapfirmware" else {})
        return np.array([float(given.get(a, math.inf)) for a in AXES])

    # -- documents ------------------------------------------------------------------------
    def metadata(self) -> Dict[str, str]:
        """``# key: value`` lines of a trace (what the analysis reads back)."""
        if self.constant_speed:
            return {"motion": "constant_speed"}
        fw = self.firmware
        out = {
            "motion": "planner" + (" (estimated)" if self.estimated else ""),
            "planner": fw,
            "accel_mm_s2": f"{self.accel_mm_s2:g}",
        }
        if fw == "klipper":
            out["square_corner_velocity_mm_s"] = f"{self.scv:g}"
            out["minimum_cruise_ratio"] = f"{self.mcr:g}"
            if self.max_velocity_mm_s:
                out["max_velocity_mm_s"] = f"{self.max_velocity_mm_s:g}"
        elif fw == "marlin" and not self.classic_jerk:
            out["junction_deviation_mm"] = f"{self.junction_deviation_mm:g}"
        else:
            out["jerk_mm_s"] = ",".join(f"{v:g}" for v in self.jerks())
        out["max_feed_mm_min"] = ",".join(f"{self.max_feed_mm_min.get(a, 0):g}" for a in AXES)
        if self.max_accel_mm_s2:
            out["max_accel_mm_s2"] = ",".join(f"{self.max_accel_mm_s2.get(a, 0):g}" for a in AXES)
        return out

    def as_dict(self) -> Dict[str, object]:
        """JSON form for diagnostics."""
        d: Dict[str, object] = {
            "motion": "constant_speed" if self.constant_speed else "planner",
            "estimated": self.estimated,
        }
        if not self.constant_speed:
            d["planner"] = self.firmware
            d["accel_mm_s2"] = self.accel_mm_s2
            if self.klipper:
                d["square_corner_velocity_mm_s"] = self.scv
                d["minimum_cruise_ratio"] = self.mcr
            elif self.firmware == "marlin" and not self.classic_jerk:
                d["junction_deviation_mm"] = self.junction_deviation_mm
            else:
                d["jerk_mm_s"] = dict(zip(AXES, self.jerks().tolist()))
            d["corner_speed_90_mm_s"] = self.corner_speed_90
        d["max_feed_mm_min"] = dict(self.max_feed_mm_min)
        return d

    @staticmethod
    def from_metadata(meta: Dict[str, str]) -> Optional[MotionSettings]:
        """Settings recorded in a trace's metadata; None when it records none (old traces,
        other loggers). Raises ValueError (with the key) for malformed values."""
        kind = meta.get("motion", "").strip().lower()
        if not kind and "accel_mm_s2" not in meta:
            return None
        if kind == "constant_speed":
            return MotionSettings(
                constant_speed=True,
                max_feed_mm_min=_axis_triple(
                    meta.get("max_feed_mm_min"), "max_feed_mm_min", DEFAULT_MAX_FEED
                ),
            )
        d: Dict[str, object] = {}
        for key in (
            "planner",
            "accel_mm_s2",
            "junction_deviation_mm",
            "square_corner_velocity_mm_s",
            "minimum_cruise_ratio",
            "max_velocity_mm_s",
        ):
            if key in meta:
                d[key] = meta[key]
        d["max_feed_mm_min"] = _axis_triple(
            meta.get("max_feed_mm_min"), "max_feed_mm_min", DEFAULT_MAX_FEED
        )
        if "max_accel_mm_s2" in meta:
            d["max_accel_mm_s2"] = _axis_triple(meta["max_accel_mm_s2"], "max_accel_mm_s2", {})
        if "jerk_mm_s" in meta:
            d["jerk_mm_s"] = _axis_triple(meta["jerk_mm_s"], "jerk_mm_s", {}, zero=True)
        s = MotionSettings.from_dict(d)
        s.estimated = "estimated" in kind
        return s

    @staticmethod
    def from_dict(d: Dict[str, object]) -> MotionSettings:
        """From a truth file / printer profile; raises ParamsError naming the field."""
        s = MotionSettings()
        if d.get("motion", "planner") == "constant_speed" or d.get("constant_speed") is True:
            s.constant_speed = True
        if d.get("planner") is not None:
            s.planner = str(d["planner"]).strip().lower()
            if s.planner not in FIRMWARES:
                raise ParamsError(
                    "planner", Msg("must be one of %(choices)s", choices=", ".join(FIRMWARES))
                )
        if "accel_mm_s2" in d:
            s.accel_mm_s2 = _positive(d["accel_mm_s2"], "accel_mm_s2", *BOUNDS["max_accel_mm_s2"])
        if d.get("square_corner_velocity_mm_s") is not None:
            s.square_corner_velocity_mm_s = _positive(
                d["square_corner_velocity_mm_s"],
                "square_corner_velocity_mm_s",
                *BOUNDS["square_corner_velocity_mm_s"],
            )
            s.junction_deviation_mm = None
        elif d.get("junction_deviation_mm") is not None:
            s.junction_deviation_mm = _positive(
                d["junction_deviation_mm"],
                "junction_deviation_mm",
                *BOUNDS["junction_deviation_mm"],
            )
        _klipper_keys(s, d)
        if d.get("max_feed_mm_min") is not None:
            s.max_feed_mm_min = _axes(d["max_feed_mm_min"], "max_feed_mm_min", "max_feed_mm_min")
            for a in AXES:
                s.max_feed_mm_min.setdefault(a, DEFAULT_MAX_FEED[a])
        if d.get("max_accel_mm_s2"):
            s.max_accel_mm_s2 = _axes(d["max_accel_mm_s2"], "max_accel_mm_s2", "max_accel_mm_s2")
        if d.get("jerk_mm_s"):
            s.jerk_mm_s = _axes(d["jerk_mm_s"], "jerk_mm_s", "jerk_mm_s")
            if s.firmware == "marlin" and "junction_deviation_mm" not in d:
                s.junction_deviation_mm = None  # Marlin with classic jerk
        return s

    def with_(self, **changes) -> MotionSettings:
        return replace(self, **changes)


def _klipper_keys(s: MotionSettings, d: Dict[str, object]) -> None:
    if d.get("minimum_cruise_ratio") is not None:
        s.minimum_cruise_ratio = _positive(
            d["minimum_cruise_ratio"], "minimum_cruise_ratio", *BOUNDS["minimum_cruise_ratio"]
        )
    if d.get("max_velocity_mm_s") is not None:
        lo, hi = BOUNDS["max_feed_mm_min"]
        s.max_velocity_mm_s = _positive(
            d["max_velocity_mm_s"], "max_velocity_mm_s", lo / 60, hi / 60
        )
    if s.firmware == "klipper":
        s.junction_deviation_mm = None


def _positive(v, name: str, lo: float, hi: float) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError, OverflowError):
        raise ParamsError(name, Msg("must be a number")) from None
    if not (lo < x <= hi) or not math.isfinite(x):
        raise ParamsError(
            name, Msg("must be within %(lo)s..%(hi)s", lo=f"{max(lo, 0.0):g}", hi=f"{hi:g}")
        )
    return x


def _axes(v, name: str, bounds: str) -> Dict[str, float]:
    return {a: _positive(x, f"{name}.{a}", *BOUNDS[bounds]) for a, x in _axis_map(v, name).items()}


def _axis_map(v, name: str) -> Dict[str, object]:
    if isinstance(v, dict):
        bad = [k for k in v if k not in AXES]
        if bad:
            raise ParamsError(f"{name}.{bad[0]}", Msg("unknown axis (allowed: x, y, z)"))
        return dict(v)
    if isinstance(v, (list, tuple)) and len(v) == 3:
        return dict(zip(AXES, v))
    raise ParamsError(name, Msg('expected {"x": .., "y": .., "z": ..}'))


def _axis_triple(
    text: Optional[str], key: str, default: Dict[str, float], zero: bool = False
) -> Dict[str, float]:
    """Three comma-separated numbers (X,Y,Z) of a metadata value, positive (or, ``zero``,
    not negative); ValueError(key) otherwise."""
    if text is None:
        return dict(default)
    parts = str(text).split(",")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError(key) from None
    if len(vals) != 3 or not all(math.isfinite(v) and (v > 0 or zero and v == 0) for v in vals):
        raise ValueError(key)
    return dict(zip(AXES, vals))


def settings_from_limits(
    limits: Optional[MotionLimits], firmware: Optional[str]
) -> Optional[MotionSettings]:
    """The planner settings of a printer whose firmware (``marlin``, ``klipper``,
    ``reprapfirmware``) states ``limits`` (its answer to M503, Klipper's printer.cfg); None
    when the firmware or the acceleration a test's moves run at is not known (the analysis
    then estimates the motion from the trace). Marlin's and RepRapFirmware's acceleration of
    a move without E is ``M204 T`` (else ``P``, ``S``); Marlin plans with junction deviation
    when ``M205`` states ``J``, with classic jerk when it states only ``X``/``Y``/``Z``;
    RepRapFirmware's junctions need ``M566`` (else its defaults)."""
    if limits is None or firmware not in FIRMWARES:
        return None
    if firmware == "klipper":
        accel = limits.print_accel_mm_s2 or limits.travel_accel_mm_s2
    else:
        accel = limits.travel_accel_mm_s2 or limits.print_accel_mm_s2
        if firmware == "reprapfirmware" and accel is None and limits.max_accel_mm_s2:
            accel = max(limits.max_accel_mm_s2.get(a, 0.0) for a in ("x", "y")) or None
    if not accel:
        return None
    s = MotionSettings(accel_mm_s2=float(accel), planner=firmware)
    s.max_feed_mm_min = dict(DEFAULT_MAX_FEED, **limits.max_feed_mm_min)
    s.max_accel_mm_s2 = dict(limits.max_accel_mm_s2) or None
    if firmware == "klipper":
        s.junction_deviation_mm = None
        s.square_corner_velocity_mm_s = limits.square_corner_velocity_mm_s or KLIPPER_SCV
        s.minimum_cruise_ratio = limits.minimum_cruise_ratio
        v = limits.max_feed_mm_min.get("x")
        s.max_velocity_mm_s = v / 60.0 if v else None
    elif firmware == "marlin":
        if limits.junction_deviation_mm:
            s.junction_deviation_mm = limits.junction_deviation_mm
        elif limits.jerk_mm_s:
            s.junction_deviation_mm = None
            s.jerk_mm_s = dict(limits.jerk_mm_s)
    else:
        s.junction_deviation_mm = None
        s.jerk_mm_s = dict(RRF_JERK, **limits.jerk_mm_s)
    return s


# ---------------------------------------------------------------------------------------
# program -> events


@dataclass(frozen=True)
class Stop:
    """A full stop without waiting (M400, M0, M1, a pause)."""

    lineno: int


_QUOTED = re.compile(r'"[^"]*"')
_BLOCKING = re.compile(r"(?:^|\s)[Ss]\s*0*[23](?:\.0*)?(?=\s|$)")


def pauses(line: str) -> bool:
    """Whether ``line`` is a pause of the firmware that KinComp's programs write besides
    ``M0``/``M1``: Klipper's ``PAUSE`` (a command word, not a G-code), RepRapFirmware's
    ``M226`` and its blocking message box ``M291 S2``/``S3``. Each waits for the moves."""
    body = line.split(";", 1)[0].strip()
    if body.split(None, 1)[:1] == ["PAUSE"] or body.upper() == "PAUSE":
        return True
    cmd = parse_command(body)
    if cmd is None or cmd.kind != "M" or cmd.number not in (226, 291):
        return False
    if cmd.number == 226:
        return True
    words = _QUOTED.sub(" ", cmd.body)  # (its message texts are quoted)
    return _BLOCKING.search(words) is not None


def program_events(lines: Iterable[str], start: Sequence[float]) -> Iterator[object]:
    """Move, Dwell, Home and Stop events of G-code ``lines`` on an ideal firmware starting at
    ``start`` (machine frame, mm)."""
    fw = FirmwareInterpreter(start=tuple(start))
    for line in lines:
        evs = fw.execute(line)
        if evs:
            yield from evs
            continue
        cmd = parse_command(line)
        if cmd is not None and classify(cmd.kind, cmd.number, cmd.sub).cls == STOP:
            yield Stop(fw.lineno)
        elif pauses(line):
            yield Stop(fw.lineno)


# ---------------------------------------------------------------------------------------
# planning


@dataclass
class Plan:
    """A planned program: blocks (moves and waits) with their trapezoids, sampled on demand.

    Arrays per block: start time ``t0`` (s), start point ``p0`` (mm), unit direction ``u``,
    length ``L`` (mm), entry/cruise/exit speeds ``v0/vc/v1`` (mm/s), acceleration ``a``
    (mm/s^2), phase durations ``ta/tc/td`` (s; a wait is a cruise at speed 0), source line,
    programmed speed ``f`` (mm/s).
    """

    t0: np.ndarray
    p0: np.ndarray
    u: np.ndarray
    L: np.ndarray
    v0: np.ndarray
    vc: np.ndarray
    v1: np.ndarray
    a: np.ndarray
    ta: np.ndarray
    tc: np.ndarray
    td: np.ndarray
    line: np.ndarray
    f: np.ndarray  # programmed speed (mm/s, before the axis caps)
    vn: np.ndarray  # nominal speed (mm/s, the programmed one within the axis caps)
    end: np.ndarray  # final position
    settings: MotionSettings

    @property
    def duration(self) -> float:
        if not len(self.t0):
            return 0.0
        return float(self.t0[-1] + self.ta[-1] + self.tc[-1] + self.td[-1])

    def block_at(self, ts: np.ndarray) -> np.ndarray:
        i = np.searchsorted(self.t0, ts, side="right") - 1
        return np.clip(i, 0, max(0, len(self.t0) - 1))

    def line_at(self, ts: np.ndarray) -> np.ndarray:
        return self.line[self.block_at(ts)]

    def sample(self, ts) -> Tuple[np.ndarray, np.ndarray]:
        """Commanded positions (n, 3) in mm and velocities (n, 3) in mm/s at times ``ts``."""
        ts = np.asarray(ts, dtype=float)
        if not len(self.t0):
            pos = np.broadcast_to(self.end, ts.shape + (3,)).copy()
            return pos, np.zeros_like(pos)
        i = self.block_at(ts)
        tau = np.maximum(ts - self.t0[i], 0.0)
        ta, tc, td = self.ta[i], self.tc[i], self.td[i]
        v0, vc, v1, a = self.v0[i], self.vc[i], self.v1[i], self.a[i]
        t1 = np.minimum(tau, ta)
        t2 = np.clip(tau - ta, 0.0, tc)
        t3 = np.clip(tau - ta - tc, 0.0, td)
        s = v0 * t1 + 0.5 * a * t1 * t1
        s = s + np.where(tau > ta, vc * t2, 0.0)
        s = s + np.where(tau > ta + tc, vc * t3 - 0.5 * a * t3 * t3, 0.0)
        # the phase's velocity (a block's dc/da are exact; s never exceeds L)
        v = np.where(
            tau < ta, v0 + a * t1, np.where(tau < ta + tc, vc, np.maximum(vc - a * t3, v1))
        )
        s = np.minimum(s, self.L[i])
        after = ts >= self.duration
        v = np.where(after, 0.0, v)
        u = self.u[i]
        pos = self.p0[i] + u * s[..., None]
        pos[after] = self.end
        return pos, u * v[..., None]

    def blocks_of_lines(self, lines: Sequence[int]) -> np.ndarray:
        return np.nonzero(np.isin(self.line, np.asarray(lines)))[0]

    def block_span(self, k: int) -> Tuple[float, float]:
        return float(self.t0[k]), float(self.t0[k] + self.ta[k] + self.tc[k] + self.td[k])


@dataclass
class Blocks:
    """A program's blocks before planning (what does not depend on the settings)."""

    p0: np.ndarray
    p1: np.ndarray
    feed: np.ndarray  # mm/min; 0 for a wait
    line: np.ndarray
    wait: np.ndarray  # s of dwell for a wait block, 0 for a move after a stop, -1 otherwise
    end: np.ndarray

    def plan(self, settings: Optional[MotionSettings] = None) -> Plan:
        return _plan_arrays(
            self.p0,
            self.p1,
            self.feed,
            self.line,
            self.wait,
            self.end,
            settings or MotionSettings(),
        )


def program_blocks(events: Iterable[object], start: Sequence[float]) -> Blocks:
    """Moves, waits and stops of a program's events (see :func:`program_events`)."""
    p0s: List[Tuple[float, float, float]] = []
    p1s: List[Tuple[float, float, float]] = []
    feeds: List[float] = []
    lines: List[int] = []
    waits: List[float] = []
    pos = tuple(float(v) for v in start)
    stop_next = True
    for ev in events:
        if isinstance(ev, Move):
            if math.dist(ev.start, ev.end) == 0.0:
                pos = ev.end
                continue
            if math.dist(ev.start, pos) > 1e-9:  # position jumped (homing, ...)
                stop_next = True
            p0s.append(tuple(ev.start))
            p1s.append(tuple(ev.end))
            feeds.append(ev.feed)
            lines.append(ev.lineno)
            waits.append(0.0 if stop_next else -1.0)
            stop_next = False
            pos = ev.end
        elif isinstance(ev, Dwell):
            stop_next = True
            if ev.seconds > 0.0:
                p0s.append(pos)
                p1s.append(pos)
                feeds.append(0.0)
                lines.append(ev.lineno)
                waits.append(float(ev.seconds))
        elif isinstance(ev, (Stop, Home)):
            stop_next = True
    return Blocks(
        np.array(p0s, dtype=float).reshape(-1, 3),
        np.array(p1s, dtype=float).reshape(-1, 3),
        np.array(feeds, dtype=float),
        np.array(lines, dtype=int),
        np.array(waits, dtype=float),
        np.array(pos, dtype=float),
    )


def plan_events(
    events: Iterable[object], start: Sequence[float], settings: Optional[MotionSettings] = None
) -> Plan:
    """Plan a program's events (see :func:`program_events`)."""
    return program_blocks(events, start).plan(settings)


def _block_limits(U, L, feed, is_wait, s: MotionSettings) -> Tuple[np.ndarray, np.ndarray]:
    """Each block's nominal speed (mm/s) and its own acceleration (mm/s^2): the programmed
    feed and the base acceleration, lowered so that no axis (and, on Klipper, the path)
    exceeds its maximum. RepRapFirmware applies ``M204`` only to moves of X or Y."""
    absu = np.abs(U)
    caps = s.caps()
    with np.errstate(divide="ignore"):
        cap_speed = np.min(
            np.where(absu > 1e-12, caps[None, :] / np.maximum(absu, 1e-300), np.inf), axis=1
        )
    vn = np.minimum(feed / 60.0, cap_speed)
    if s.klipper and s.max_velocity_mm_s:
        vn = np.minimum(vn, float(s.max_velocity_mm_s))
    vn[is_wait] = 0.0
    acc = np.full(len(L), float(s.accel_mm_s2))
    if s.firmware == "reprapfirmware":
        acc = np.where(np.any(absu[:, :2] > 1e-12, axis=1), acc, np.inf)
    acc = junctions._axis_capped(acc, U, s.axis_accels())
    if s.firmware == "reprapfirmware":  # a move of nothing but Z with no M201 Z
        acc = np.where(np.isfinite(acc), acc, float(s.accel_mm_s2))
    return vn, acc


def _junction_v2(U, L, acc, vn, stop, is_wait, s: MotionSettings) -> np.ndarray:
    """Maximum squared speed at the start of each block (0 after a stop)."""
    n = len(U)
    J = np.zeros(n)
    if n < 2:
        return J
    fw = s.firmware
    if fw == "klipper":
        v2 = junctions.klipper(U, L, acc, s.scv, float(s.accel_mm_s2))
    elif fw == "reprapfirmware":
        v2 = junctions.rrf(U, s.jerks())
    elif s.classic_jerk:
        v2 = junctions.marlin_jerk(U, vn, s.jerks())
    else:
        v2 = junctions.marlin_jd(
            U, L, acc, float(s.junction_deviation_mm or 0.0), s.axis_accels(), s.small_segments
        )
    vn2 = vn * vn
    J[1:] = np.minimum(v2, np.minimum(vn2[:-1], vn2[1:]))
    J[stop] = 0.0
    J[is_wait] = 0.0
    J[1:][is_wait[:-1]] = 0.0
    return J


def _plan_arrays(P0, P1, feed, line, wait, end, s: MotionSettings) -> Plan:
    n = len(P0)
    is_wait = feed == 0.0
    D = P1 - P0
    L = np.linalg.norm(D, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        U = np.where(L[:, None] > 0, D / np.where(L > 0, L, 1.0)[:, None], 0.0)
    vn, acc = _block_limits(U, L, feed, is_wait, s)
    vn2 = vn * vn
    if s.constant_speed or n == 0:
        v0 = vn.copy()
        v1 = vn.copy()
        vc = vn.copy()
        a = np.zeros(n)
        ta = np.zeros(n)
        td = np.zeros(n)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = np.where(is_wait, np.maximum(wait, 0.0), L / np.where(vn > 0, vn, 1.0))
    else:
        J = _junction_v2(U, L, acc, vn, wait >= 0.0, is_wait, s)
        c = 2.0 * acc * L  # v^2 gained over a whole move
        if s.klipper:
            mcr_accel = float(s.accel_mm_s2) * (1.0 - s.mcr)
            v0sq, vcsq, v1sq = junctions.klipper_lookahead(J, acc, L, vn2, mcr_accel, is_wait)
        else:
            v0sq, v1sq = junctions.forward_backward(J, c)
            vcsq = np.minimum(vn2, (c + v0sq + v1sq) * 0.5)
        vcsq = np.maximum(vcsq, np.maximum(v0sq, v1sq))
        v0, v1, vc = np.sqrt(v0sq), np.sqrt(v1sq), np.sqrt(vcsq)
        a = np.where(is_wait, 0.0, acc)
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = np.where(is_wait, 0.0, (vc - v0) / acc)
            td = np.where(is_wait, 0.0, (vc - v1) / acc)
            da = (vcsq - v0sq) / (2 * acc)
            dd = (vcsq - v1sq) / (2 * acc)
            dc = np.maximum(L - da - dd, 0.0)
            tc = np.where(is_wait, np.maximum(wait, 0.0), dc / np.where(vc > 0, vc, 1.0))
    dur = ta + tc + td
    t0 = np.concatenate([[0.0], np.cumsum(dur)[:-1]]) if n else np.zeros(0)
    return Plan(
        t0=t0,
        p0=P0,
        u=U,
        L=L,
        v0=v0,
        vc=vc,
        v1=v1,
        a=a,
        ta=ta,
        tc=tc,
        td=td,
        line=line,
        f=feed / 60.0,
        vn=vn,
        end=end,
        settings=s,
    )


def program_blocks_of(text_or_lines, start: Sequence[float]) -> Blocks:
    lines = text_or_lines.splitlines() if isinstance(text_or_lines, str) else text_or_lines
    return program_blocks(program_events(lines, start), start)


def plan_program(
    text_or_lines, start: Sequence[float], settings: Optional[MotionSettings] = None
) -> Plan:
    return program_blocks_of(text_or_lines, start).plan(settings)
