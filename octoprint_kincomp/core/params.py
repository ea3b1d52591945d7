"""KinComp parameter schema: one versioned, validated JSON document.

Units and signs are the contract of this module (and of every params file):

* ``squareness_um_per_m`` (um/m): ``xy`` positive means the machine's actual X grows with Y,
  ``actual_x = x + xy*1e-6*y``; ``xz``: ``actual_x = x + xz*1e-6*z``; ``yz``:
  ``actual_y = y + yz*1e-6*z``. Same sign as Marlin ``M852`` and Klipper's skew factors, the
  opposite of RepRapFirmware ``M556``.
* ``scale_ppm`` (ppm): positive means the axis travels too far,
  ``actual = (1 + s*1e-6) * commanded`` about the machine origin.
* ``backlash`` (um of lost motion on a reversal, >= 0) per axis ``x``/``y``/``z``: either one
  number, or a list of at most 64 ``{"at_mm": position, "um": value}`` points, linearly
  interpolated along the axis and held constant outside. ``fraction`` (0..1) scales what is applied,
  ``smoothing_mm`` spreads each take-up over that much following path length (0 = immediate
  take-up move).
* ``axis_errors`` (optional full HTM terms): per axis, the translation errors ``tx_um``,
  ``ty_um``, ``tz_um`` (um) and rotation errors ``rx_urad``, ``ry_urad``, ``rz_urad`` (urad,
  right-handed about +X/+Y/+Z) of that axis' carriage. Each is a constant or a list of
  polynomial coefficients ``[c0, c1, c2, ...]`` in the axis' own position q (mm):
  ``value(q) = c0 + c1*q + c2*q**2 ...`` (units um/mm**k or urad/mm**k).
* ``nozzle_offset_mm``: nozzle tip relative to the carriage reference point (mm); with rotation
  errors it produces Abbe errors.
* ``kinematics``: ``parallel`` (default, the paper's Ultimaker), ``bedslinger`` (serial chain:
  Y carries the bed, Z carries X, X carries the head) or ``corexy`` (serial chain Z, Y, X; all
  errors expressed in Cartesian space).
* ``servo_lag_ms`` (optional, ms): per-axis following lag ``T`` of a first-order servo
  (actual lags commanded by ``v*T``); used only when ``servo_precomp`` is true.

Every number is a JSON number (not true, not "1"), finite and within the sanity limit below
for its field; any such value, down to the smallest subnormal (5e-324), gives finite
derived quantities (firmware equivalents, ratios, the compensation: tests/core/
test_params_ranges.py checks the ends of every range).
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

from .messages import Msg
from .numbers import finite

SCHEMA_VERSION = 1
AXES = ("x", "y", "z")
PLANE_PAIRS = ("xy", "xz", "yz")
KINEMATICS = ("parallel", "bedslinger", "corexy")
HTM_TERMS = ("tx_um", "ty_um", "tz_um", "rx_urad", "ry_urad", "rz_urad")

# Sanity limits: anything beyond these is a typo or a unit mix-up, not a printer.
MAX_SQUARENESS_UM_PER_M = 50000.0
MAX_SCALE_PPM = 50000.0
MAX_BACKLASH_UM = 5000.0
MAX_SMOOTHING_MM = 100.0
MAX_TRANSLATION_UM = 5000.0
MAX_ROTATION_URAD = 50000.0
MAX_NOZZLE_OFFSET_MM = 500.0
MAX_POSITION_MM = 10000.0
MAX_SERVO_LAG_MS = 100.0
MAX_POLY_DEGREE = 5
# Backlash points per axis: every move walks the table, and the compiled kernel takes at most
# this many (engines/kernel.py MAX_POINTS; a test keeps the two equal).
MAX_BACKLASH_POINTS = 64


class ParamsError(ValueError):
    """A params document is invalid. ``field`` names the offending entry (dotted path)."""

    def __init__(self, field: str, message: str):
        self.field = field
        self.message = message  # a messages.Msg: translatable by the plugin
        super().__init__(f"{field}: {message}" if field else message)


@dataclass(frozen=True)
class BacklashAxis:
    """Backlash of one axis: lost motion in um, constant or interpolated along the axis."""

    points: Tuple[Tuple[float, float], ...] = ((0.0, 0.0),)  # ((at_mm, um), ...) sorted by at_mm

    @property
    def is_zero(self) -> bool:
        return all(um == 0.0 for _, um in self.points)

    @property
    def is_constant(self) -> bool:
        return len({um for _, um in self.points}) == 1

    @functools.cached_property
    def _segments(self) -> Tuple[Tuple[float, float, float, float, float], ...]:
        """Per pair of neighbouring points: (positions p0, p1 mm; backlash v0, v1 um; the
        slope (v1 - v0) / (p1 - p0) um/mm, computed once: the same double every time)."""
        return tuple(
            (p0, p1, v0, v1, (v1 - v0) / (p1 - p0))
            for (p0, v0), (p1, v1) in zip(self.points, self.points[1:])
        )

    def um_at(self, pos_mm: float) -> float:
        """Backlash (um) at axis position ``pos_mm``: linear between points, constant outside."""
        pts = self.points
        if len(pts) == 1 or pos_mm <= pts[0][0]:
            return pts[0][1]
        if pos_mm >= pts[-1][0]:
            return pts[-1][1]
        for p0, p1, v0, v1, slope in self._segments:
            if pos_mm < p1:
                # the compiled kernel computes the same (csrc/transform.c kk_um_at: the
                # quotient kept per segment, the same double)
                return slope * (pos_mm - p0) + v0
            if pos_mm == p1:
                return v1
        return pts[-1][1]  # pragma: no cover - loop always returns

    def to_json(self):
        if len(self.points) == 1:
            return self.points[0][1]
        return [{"at_mm": p, "um": v} for p, v in self.points]


@dataclass(frozen=True)
class Params:
    """Validated, immutable KinComp parameters (see the module docstring for units/signs)."""

    kinematics: str = "parallel"
    squareness_um_per_m: Dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(PLANE_PAIRS, 0.0)
    )
    scale_ppm: Dict[str, float] = field(default_factory=lambda: dict.fromkeys(AXES, 0.0))
    backlash: Dict[str, BacklashAxis] = field(
        default_factory=lambda: {k: BacklashAxis() for k in AXES}
    )
    backlash_fraction: float = 1.0
    backlash_smoothing_mm: float = 0.0
    axis_errors: Dict[str, Dict[str, Tuple[float, ...]]] = field(
        default_factory=lambda: {a: dict.fromkeys(HTM_TERMS, (0.0,)) for a in AXES}
    )
    nozzle_offset_mm: Dict[str, float] = field(default_factory=lambda: dict.fromkeys(AXES, 0.0))
    servo_lag_ms: Dict[str, float] = field(default_factory=lambda: dict.fromkeys(AXES, 0.0))
    servo_precomp: bool = False
    meta: Dict[str, Any] = field(default_factory=dict)

    # -- derived facts -------------------------------------------------------------------
    @property
    def has_backlash(self) -> bool:
        return self.backlash_fraction > 0 and any(not self.backlash[a].is_zero for a in AXES)

    @property
    def has_servo_precomp(self) -> bool:
        return self.servo_precomp and any(self.servo_lag_ms[a] != 0.0 for a in AXES)

    def to_dict(self) -> Dict[str, Any]:
        d: Dict[str, Any] = {
            "version": SCHEMA_VERSION,
            "kinematics": self.kinematics,
            "squareness_um_per_m": dict(self.squareness_um_per_m),
            "scale_ppm": dict(self.scale_ppm),
            "backlash": {a: self.backlash[a].to_json() for a in AXES},
        }
        d["backlash"]["fraction"] = self.backlash_fraction
        d["backlash"]["smoothing_mm"] = self.backlash_smoothing_mm
        errs = {}
        for a in AXES:
            terms = {
                t: (c[0] if len(c) == 1 else list(c))
                for t, c in self.axis_errors[a].items()
                if any(v != 0.0 for v in c)
            }
            if terms:
                errs[a] = terms
        if errs:
            d["axis_errors"] = errs
        if any(self.nozzle_offset_mm[a] != 0.0 for a in AXES):
            d["nozzle_offset_mm"] = dict(self.nozzle_offset_mm)
        if any(self.servo_lag_ms[a] != 0.0 for a in AXES) or self.servo_precomp:
            d["servo_lag_ms"] = dict(self.servo_lag_ms)
            d["servo_precomp"] = self.servo_precomp
        if self.meta:
            d["meta"] = copy.deepcopy(self.meta)
        return d

    def model_dict(self) -> Dict[str, Any]:
        """The part of :meth:`to_dict` that affects compensation (no ``meta``)."""
        d = self.to_dict()
        d.pop("meta", None)
        return d

    def hash(self) -> str:
        """Short, stable hash of everything that affects compensation (12 hex chars)."""
        blob = json.dumps(self.model_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode("utf-8")).hexdigest()[:12]

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=False) + "\n"

    def replace(self, **changes) -> Params:
        """A copy with some top-level fields replaced (re-validated)."""
        d = self.to_dict()
        d.update(changes)
        return Params.from_dict(d)

    @staticmethod
    def from_dict(data: Any) -> Params:
        return _parse(data)

    @staticmethod
    def from_json(text: str) -> Params:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ParamsError(
                "",
                Msg("not valid JSON (%(error)s at line %(line)s)", error=exc.msg, line=exc.lineno),
            ) from None
        return _parse(data)

    @staticmethod
    def load(path: str) -> Params:
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as exc:
            raise ParamsError(
                "",
                Msg(
                    "cannot read params file %(path)s: %(error)s",
                    path=repr(path),
                    error=exc.strerror,
                ),
            ) from None
        return Params.from_json(text)


def default_params() -> Params:
    return Params()


# ---------------------------------------------------------------------------------------
# validation


def _number(
    value: Any,
    field: str,
    limit: Optional[float] = None,
    lo: Optional[float] = None,
    hi: Optional[float] = None,
) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamsError(
            field, Msg("must be a number, got %(value)s", value=json.dumps(value)[:40])
        )
    v = finite(value)
    if v is None:
        raise ParamsError(field, Msg("must be a finite number (NaN/Infinity are not allowed)"))
    if limit is not None and abs(v) > limit:
        raise ParamsError(
            field,
            Msg(
                "%(value)s is out of range (must be between -%(limit)s and %(limit)s)",
                value=f"{v:g}",
                limit=f"{limit:g}",
            ),
        )
    if lo is not None and v < lo:
        raise ParamsError(
            field,
            Msg(
                "%(value)s is out of range (must be at least %(lo)s)", value=f"{v:g}", lo=f"{lo:g}"
            ),
        )
    if hi is not None and v > hi:
        raise ParamsError(
            field,
            Msg("%(value)s is out of range (must be at most %(hi)s)", value=f"{v:g}", hi=f"{hi:g}"),
        )
    return v


def _object(value: Any, field: str, allowed) -> Dict[str, Any]:
    if not isinstance(value, dict):
        raise ParamsError(field, Msg("must be an object"))
    for key in value:
        if key not in allowed:
            raise ParamsError(
                f"{field}.{key}" if field else str(key),
                Msg("unknown key (allowed: %(allowed)s)", allowed=", ".join(allowed)),
            )
    return value


def _axis_map(value: Any, field: str, keys, limit: float) -> Dict[str, float]:
    obj = _object(value, field, keys)
    return {k: _number(obj.get(k, 0.0), f"{field}.{k}", limit) for k in keys}


def _backlash_axis(value: Any, field: str) -> BacklashAxis:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return BacklashAxis(((0.0, _number(value, field, lo=0.0, hi=MAX_BACKLASH_UM)),))
    if not isinstance(value, list) or not value:
        raise ParamsError(
            field, Msg("must be a number (µm) or a non-empty list of {at_mm, um} points")
        )
    if len(value) > MAX_BACKLASH_POINTS:
        raise ParamsError(
            field,
            Msg("at most %(n)s points, got %(count)s", n=MAX_BACKLASH_POINTS, count=len(value)),
        )
    pts = []
    for i, item in enumerate(value):
        f = f"{field}[{i}]"
        obj = _object(item, f, ("at_mm", "um"))
        if "at_mm" not in obj or "um" not in obj:
            raise ParamsError(f, Msg("each point needs both 'at_mm' and 'um'"))
        pts.append(
            (
                _number(obj["at_mm"], f + ".at_mm", MAX_POSITION_MM),
                _number(obj["um"], f + ".um", lo=0.0, hi=MAX_BACKLASH_UM),
            )
        )
    pts.sort()
    for (p0, _), (p1, _) in zip(pts, pts[1:]):
        if p1 == p0:
            raise ParamsError(field, Msg("two points at the same position %(at)s mm", at=f"{p0:g}"))
    return BacklashAxis(tuple(pts))


def _poly(value: Any, field: str, limit: float) -> Tuple[float, ...]:
    if isinstance(value, list):
        if not value or len(value) > MAX_POLY_DEGREE + 1:
            raise ParamsError(field, Msg("needs 1..%(n)s coefficients", n=MAX_POLY_DEGREE + 1))
        coeffs = tuple(_number(v, f"{field}[{i}]") for i, v in enumerate(value))
    else:
        coeffs = (_number(value, field),)
    # Bound the term over a generous 1 m travel so that nothing absurd gets through.
    worst = sum(abs(c) * 1000.0**k for k, c in enumerate(coeffs))
    if worst > limit:
        raise ParamsError(
            field,
            Msg(
                "reaches %(value)s over 1 m of travel (limit %(limit)s)",
                value=f"{worst:g}",
                limit=f"{limit:g}",
            ),
        )
    return coeffs


def _parse(data: Any) -> Params:
    top_keys = (
        "version",
        "kinematics",
        "squareness_um_per_m",
        "scale_ppm",
        "backlash",
        "axis_errors",
        "nozzle_offset_mm",
        "servo_lag_ms",
        "servo_precomp",
        "meta",
    )
    obj = _object(data, "", top_keys)
    version = obj.get("version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        raise ParamsError(
            "version",
            Msg(
                "unsupported params version %(version)s (this KinComp reads version %(supported)s)",
                version=repr(version),
                supported=SCHEMA_VERSION,
            ),
        )
    kin = obj.get("kinematics", "parallel")
    if kin not in KINEMATICS:
        raise ParamsError(
            "kinematics", Msg("must be one of %(choices)s", choices=", ".join(KINEMATICS))
        )
    sq = _axis_map(
        obj.get("squareness_um_per_m", {}),
        "squareness_um_per_m",
        PLANE_PAIRS,
        MAX_SQUARENESS_UM_PER_M,
    )
    sc = _axis_map(obj.get("scale_ppm", {}), "scale_ppm", AXES, MAX_SCALE_PPM)

    bl = _object(obj.get("backlash", {}), "backlash", AXES + ("fraction", "smoothing_mm"))
    backlash = {a: _backlash_axis(bl.get(a, 0.0), f"backlash.{a}") for a in AXES}
    fraction = _number(bl.get("fraction", 1.0), "backlash.fraction", lo=0.0, hi=1.0)
    smoothing = _number(
        bl.get("smoothing_mm", 0.0), "backlash.smoothing_mm", lo=0.0, hi=MAX_SMOOTHING_MM
    )

    errs_in = _object(obj.get("axis_errors", {}), "axis_errors", AXES)
    axis_errors = {}
    for a in AXES:
        terms = _object(errs_in.get(a, {}), f"axis_errors.{a}", HTM_TERMS)
        axis_errors[a] = {
            t: _poly(
                terms.get(t, 0.0),
                f"axis_errors.{a}.{t}",
                MAX_TRANSLATION_UM if t.endswith("_um") else MAX_ROTATION_URAD,
            )
            for t in HTM_TERMS
        }
    nozzle = _axis_map(
        obj.get("nozzle_offset_mm", {}), "nozzle_offset_mm", AXES, MAX_NOZZLE_OFFSET_MM
    )
    servo = _axis_map(obj.get("servo_lag_ms", {}), "servo_lag_ms", AXES, MAX_SERVO_LAG_MS)
    precomp = obj.get("servo_precomp", False)
    if not isinstance(precomp, bool):
        raise ParamsError("servo_precomp", Msg("must be true or false"))
    meta = obj.get("meta", {})
    if not isinstance(meta, dict):
        raise ParamsError("meta", Msg("must be an object"))
    try:
        json.dumps(meta, allow_nan=False)
    except ValueError:
        raise ParamsError("meta", Msg("must contain finite JSON values only")) from None
    return Params(
        kinematics=kin,
        squareness_um_per_m=sq,
        scale_ppm=sc,
        backlash=backlash,
        backlash_fraction=fraction,
        backlash_smoothing_mm=smoothing,
        axis_errors=axis_errors,
        nozzle_offset_mm=nozzle,
        servo_lag_ms=servo,
        servo_precomp=precomp,
        meta=copy.deepcopy(meta),
    )


def backlash_points_for_ends(
    minus_end_mm: float, minus_um: float, plus_end_mm: float, plus_um: float
) -> List[Dict[str, float]]:
    """Backlash points from per-side values measured at the -end and +end of a circle."""
    return [{"at_mm": minus_end_mm, "um": minus_um}, {"at_mm": plus_end_mm, "um": plus_um}]
