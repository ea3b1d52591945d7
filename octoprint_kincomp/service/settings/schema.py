"""KinComp's OctoPrint settings: defaults, version migration and validation (no OctoPrint import).

The settings hold the params document (see :mod:`params`) plus how the plugin applies it,
demo mode, and the live ballbar sensor (``sensor``: port, baud rate in bit/s, protocol, units,
sign, pattern and scale; see ``sensor/config.py``). ``validate_settings`` returns a
complete, checked copy or raises :class:`SettingsError` naming the field, so that the API can
answer 400 and keep the old values.
"""

from __future__ import annotations

import copy
import re
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from ...core.backlash import deadband_steps
from ...core.compensator import POLICIES, Options
from ...core.messages import Msg
from ...core.numbers import finite
from ...core.params import Params, ParamsError
from ...firmware.motion_limits import MAX_TEXT, LimitsError, parse_limits, steps_per_mm
from ...sensor.config import SensorConfig
from ...sensor.protocol_pattern import check_scale, compile_pattern
from ...sensor.sensor_error import SensorError
from . import software_update

SETTINGS_VERSION = 1
MODES = ("on_the_fly", "on_upload", "background")
APPLY_CHANGES = ("next_print", "immediately")


class SettingsError(ValueError):
    def __init__(self, field: str, message: str):
        self.field = field
        self.message = message  # a messages.Msg: translatable by the plugin
        super().__init__(f"{field}: {message}" if field else message)


class SettingsInvalid(SettingsError):
    """The stored settings are invalid (``reason``: the SettingsError); compensation and
    file jobs refuse to run until the user fixes them."""

    def __init__(self, reason: SettingsError):
        self.reason = reason
        super().__init__(
            reason.field,
            Msg(
                "the stored KinComp settings are invalid (%(reason)s); fix them in KinComp's "
                "settings first",
                reason=str(reason),
            ),
        )


def defaults() -> Dict[str, Any]:
    return {
        "enabled": False,
        "mode": "on_the_fly",
        "params": Params().to_dict(),
        "limits_policy": "warn",
        "chord_tol_mm": 0.01,
        "linearise_arcs": False,
        "decimals": 3,
        "home_mm": None,  # where G28 leaves X, Y, Z (mm); None (or a None entry): learned
        # the X/Y drives' steps per mm (the reversal dead band is a twentieth of a step);
        # None: read from the printer (M92 in its M503 answer, Klipper's [stepper_x/y]),
        # else a typical 80 (steps_for_deadband)
        "steps_per_mm": None,
        "pass_through_on_error": False,
        "apply_changes": "next_print",
        # live: in demo mode the virtual ballbar streams to KinComp as a live sensor
        "demo": {"enabled": False, "live": True},
        "sensor": sensor_defaults(),
        "software_update": software_update.default_settings(),
        "motion_limits": motion_limits_defaults(),
        # per printer: the OctoPrint printer profile whose set (PER_PROFILE keys) is in
        # force above ("" : none yet, the set is adopted by the active profile), every
        # profile's set by profile id, and the profile the runs recorded before profiles
        # belong to (see printer_profiles.py); set by KinComp only, never by a request
        "profile": "",
        "profiles": {},
        "legacy_profile": "",
    }


# what belongs to one printer: kept per printer profile, swapped when the profile changes
PER_PROFILE = ("params", "home_mm", "motion_limits", "steps_per_mm")
# set only by KinComp itself (a profile switch), dropped from what a request sends
INTERNAL_KEYS = ("profile", "profiles", "legacy_profile")


# the printer's motion limits as stated (firmware/motion_limits.py reads them): the firmware's
# answer to M503 (source "m503", captured by the plugin) or text the user pasted (source
# "pasted": M503 lines or Klipper's printer.cfg); firmware: its name (M203's unit)
MOTION_LIMIT_KEYS = ("text", "source", "firmware", "captured")
MOTION_LIMIT_SOURCES = ("", "m503", "pasted")


def motion_limits_defaults() -> Dict[str, Any]:
    return {"text": "", "source": "", "firmware": "", "captured": None}


# the sensor settings the plugin stores (SensorConfig's others keep their defaults)
SENSOR_KEYS = (
    "enabled",
    "port",
    "baudrate",
    "protocol",
    "units",
    "positive",
    "pattern",
    "scale",
    "range",
    "sample_rate_hz",
)
# the JSON types of the sensor settings (SensorConfig checks ranges and choices)
SENSOR_TEXTS = ("port", "protocol", "units", "positive", "pattern", "range")
SENSOR_NUMBERS = ("baudrate", "scale", "sample_rate_hz")
# objects updated key by key (a form may send only some keys)
MERGED = ("demo", "sensor", "motion_limits")


def sensor_defaults() -> Dict[str, Any]:
    """No live sensor: tests are measured by uploading a trace."""
    cfg = SensorConfig().to_dict()
    return dict({k: cfg[k] for k in SENSOR_KEYS if k != "enabled"}, enabled=False)


SETTING_KEYS = tuple(defaults())


def migrate(settings: Dict[str, Any], current: Optional[int]) -> Dict[str, Any]:
    """Bring stored settings from version ``current`` (None: before versioning) to
    SETTINGS_VERSION. Version 0 stored squareness/scale as flat keys (``skew_xy`` in um/m,
    ``scale_x`` in ppm); they move into the params document."""
    out = copy.deepcopy(settings)
    if current is None or current < 1:
        params = out.get("params") or {}
        sq = params.setdefault("squareness_um_per_m", {})
        sc = params.setdefault("scale_ppm", {})
        for pair in ("xy", "xz", "yz"):
            if f"skew_{pair}" in out:
                sq[pair] = out.pop(f"skew_{pair}")
        for axis in "xyz":
            if f"scale_{axis}" in out:
                sc[axis] = out.pop(f"scale_{axis}")
        out["params"] = params
    return out


def _bool(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise SettingsError(field, Msg("must be true or false"))
    return value


def _choice(value: Any, field: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise SettingsError(field, Msg("must be one of %(choices)s", choices=", ".join(allowed)))
    return value


def _number(value: Any, field: str, lo: float, hi: float) -> float:
    value = finite(value)
    if value is None:
        raise SettingsError(field, Msg("must be a finite number"))
    if not lo <= value <= hi:
        raise SettingsError(
            field,
            Msg(
                "%(value)s is out of range (%(lo)s..%(hi)s)",
                value=f"{value:g}",
                lo=f"{lo:g}",
                hi=f"{hi:g}",
            ),
        )
    return value


def merge_params(base: Dict[str, Any], update: Dict[str, Any]) -> Dict[str, Any]:
    """``base`` params document with ``update`` merged in: objects merge key by key, any
    other value (a number, a backlash table) replaces, ``None`` removes the key (its default
    applies). So ``{"scale_ppm": {"x": 100}}`` changes X scale and keeps everything else."""
    out = copy.deepcopy(base)
    for key, value in update.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_params(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def validate_settings(
    data: Dict[str, Any], base: Optional[Dict[str, Any]] = None, replace_params: bool = False
) -> Dict[str, Any]:
    """``base`` (the current settings, default: defaults) updated with ``data``, checked.

    A ``params`` object is merged into the current parameters (:func:`merge_params`), so a
    partial update never resets the terms it does not mention; ``replace_params`` takes it
    as the complete document instead (applying a calibration's proposal). Unknown keys are
    refused (a typo must not be silently dropped).

    The one schema for every way in: API bodies, OctoPrint's settings dialog and what
    config.yaml holds (read at start-up and on every use). Each key is checked by its entry
    in :data:`CHECKS`; whatever a value is (a list where a text belongs, nesting, 1e-310)
    the answer is the checked settings or a :class:`SettingsError` naming the field, never
    another exception: a check failing in an unforeseen way is reported against its key."""
    if not isinstance(data, dict):
        raise SettingsError("", Msg("settings must be an object"))
    out = copy.deepcopy(base) if base is not None else defaults()
    for key in data:
        if key not in SETTING_KEYS:
            raise SettingsError(key, Msg("unknown setting"))
    data = copy.deepcopy(data)
    if (
        not replace_params
        and isinstance(data.get("params"), dict)
        and isinstance(out.get("params"), dict)
    ):
        data["params"] = merge_params(out["params"], data["params"])
    for key in MERGED:
        if isinstance(data.get(key), dict) and isinstance(out.get(key), dict):
            data[key] = dict(out[key], **data[key])
    out.update(data)
    for key, check in CHECKS.items():
        try:
            out[key] = check(out[key], key)
        except SettingsError:
            raise
        except (
            TypeError,
            ValueError,
            ArithmeticError,
            LookupError,
            AttributeError,
            RecursionError,
        ) as exc:
            raise SettingsError(
                key, Msg("invalid value (%(error)s)", error=str(exc)[:80] or type(exc).__name__)
            ) from None
    return out


def _decimals(dec: Any, field: str) -> int:
    if isinstance(dec, bool) or not isinstance(dec, int) or not 3 <= dec <= 6:
        raise SettingsError(field, Msg("must be an integer within 3..6"))
    return dec


def _home(home: Any, field: str) -> Optional[List[Optional[float]]]:
    if home is None:
        return None
    if not isinstance(home, list) or len(home) != 3:
        raise SettingsError(
            field, Msg("must be a list of three numbers (mm) or null (learned from the printer)")
        )
    return [
        None if v is None else _number(v, f"{field}[{i}]", -10000, 10000)
        for i, v in enumerate(home)
    ]


def _steps(value: Any, field: str) -> Optional[float]:
    """The drives' steps per mm, or None (from the printer, else the default)."""
    return None if value is None else _number(value, field, 1.0, 100000.0)


def _demo(demo: Any, field: str) -> Dict[str, bool]:
    if not isinstance(demo, dict) or set(demo) - {"enabled", "live"}:
        raise SettingsError(field, Msg("must be an object with 'enabled' and 'live'"))
    return {
        "enabled": _bool(demo.get("enabled", False), f"{field}.enabled"),
        "live": _bool(demo.get("live", True), f"{field}.live"),
    }


def _software_update(value: Any, field: str) -> Dict[str, Any]:
    try:
        return software_update.validate(value)
    except software_update.UpdateSettingsError as exc:
        raise SettingsError(exc.field, exc.message) from None


def _params(value: Any, field: str) -> Dict[str, Any]:
    try:
        return Params.from_dict(value).to_dict()
    except ParamsError as exc:
        raise SettingsError(f"{field}.{exc.field}" if exc.field else field, exc.message) from None


def validate_motion_limits(value: Any) -> Dict[str, Any]:
    """The stated motion limits, checked: a text that states none is refused (naming
    ``motion_limits.text``), an empty text means "not known"."""
    if not isinstance(value, dict):
        raise SettingsError("motion_limits", Msg("must be an object"))
    for key in value:
        if key not in MOTION_LIMIT_KEYS:
            raise SettingsError(f"motion_limits.{key}", Msg("unknown setting"))
    out = dict(motion_limits_defaults(), **value)
    for key in ("text", "firmware"):
        if not isinstance(out[key], str):
            raise SettingsError(f"motion_limits.{key}", Msg("must be a text"))
    if len(out["text"]) > MAX_TEXT:
        raise SettingsError(
            "motion_limits.text", Msg("is longer than %(n)s characters", n=MAX_TEXT)
        )
    out["source"] = _choice(out["source"], "motion_limits.source", MOTION_LIMIT_SOURCES)
    if out["captured"] is not None and not isinstance(out["captured"], str):
        raise SettingsError("motion_limits.captured", Msg("must be a date text or null"))
    if out["text"].strip():
        try:
            parse_limits(out["text"], out["firmware"])
        except LimitsError as exc:
            raise SettingsError("motion_limits.text", exc.args[0]) from None
        if not out["source"]:
            out["source"] = "pasted"
    else:
        out.update(text="", source="", captured=None)
    return out


def validate_sensor(value: Any) -> Dict[str, Any]:
    """The sensor settings checked (complete: missing keys get their defaults); the field
    at fault is named ``sensor.<key>``."""
    if not isinstance(value, dict):
        raise SettingsError("sensor", Msg("must be an object"))
    for key in value:
        if key not in SENSOR_KEYS:
            raise SettingsError(f"sensor.{key}", Msg("unknown setting"))
    out = dict(sensor_defaults(), **value)
    enabled = _bool(out.pop("enabled"), "sensor.enabled")
    for key in SENSOR_TEXTS:
        if not isinstance(out[key], str):
            raise SettingsError(f"sensor.{key}", Msg("must be a text"))
    for key in SENSOR_NUMBERS:
        if isinstance(out[key], bool) or not isinstance(out[key], (int, float)):
            raise SettingsError(f"sensor.{key}", Msg("must be a number"))
    out["port"] = out["port"].strip()
    try:
        cfg = SensorConfig.from_dict(out)
        cfg.scale = check_scale(cfg.scale)  # kept for the pattern protocol: checked always
        if cfg.pattern:
            compile_pattern(cfg.pattern)
    except SensorError as exc:
        raise SettingsError(f"sensor.{exc.field}" if exc.field else "sensor", exc.message) from None
    if enabled and not cfg.port:
        raise SettingsError(
            "sensor.port", Msg("choose the sensor's port (or switch live capture off)")
        )
    return dict({k: getattr(cfg, k) for k in SENSOR_KEYS if k != "enabled"}, enabled=enabled)


def _profile_id(value: Any, field: str) -> str:
    if not isinstance(value, str) or len(value) > 200:
        raise SettingsError(field, Msg("must be a printer profile id (a text)"))
    return value


def _profiles(value: Any, field: str) -> Dict[str, Dict[str, Any]]:
    """Each printer profile's set: an object of PER_PROFILE keys (a missing key: its
    default; no ``params``: the profile has no calibration), each checked as on top."""
    if not isinstance(value, dict):
        raise SettingsError(field, Msg("must be an object"))
    out: Dict[str, Dict[str, Any]] = {}
    for pid, entry in value.items():
        _profile_id(pid, field)
        where = f"{field}.{pid}"
        if not isinstance(entry, dict):
            raise SettingsError(where, Msg("must be an object"))
        checked = {}
        for key, item in entry.items():
            if key not in PER_PROFILE:
                raise SettingsError(f"{where}.{key}", Msg("unknown setting"))
            checked[key] = CHECKS[key](item, f"{where}.{key}")
        out[pid] = checked
    return out


# key -> check(value, field): the checked value, or SettingsError naming the field. Every
# key of the defaults has one (a test keeps them equal); the order is the order of checking.
CHECKS: Dict[str, Callable[[Any, str], Any]] = {
    "enabled": _bool,
    "mode": lambda v, f: _choice(v, f, MODES),
    "limits_policy": lambda v, f: _choice(v, f, POLICIES),
    "chord_tol_mm": lambda v, f: _number(v, f, 0.0005, 1.0),
    "linearise_arcs": _bool,
    "decimals": _decimals,
    "home_mm": _home,
    "steps_per_mm": _steps,
    "pass_through_on_error": _bool,
    "apply_changes": lambda v, f: _choice(v, f, APPLY_CHANGES),
    "demo": _demo,
    "sensor": lambda v, f: validate_sensor(v),
    "motion_limits": lambda v, f: validate_motion_limits(v),
    "software_update": _software_update,
    "params": _params,
    "profile": lambda v, f: _profile_id(v, f),
    "legacy_profile": lambda v, f: _profile_id(v, f),
    "profiles": lambda v, f: _profiles(v, f),
}


def engine_config(
    settings: Dict[str, Any], limits: Optional[Tuple[float, ...]]
) -> Tuple[Params, Options]:
    """The Params and compensator Options the settings describe."""
    params = Params.from_dict(settings["params"])
    options = Options(
        chord_tol_mm=float(settings["chord_tol_mm"]),
        linearise_arcs=bool(settings.get("linearise_arcs", False)),
        limits=limits,
        policy=settings["limits_policy"],
        decimals=int(settings["decimals"]),
        home_mm=home_position(settings),
        steps_per_mm=steps_for_deadband(settings),
    )
    return params, options


def steps_for_deadband(settings: Dict[str, Any]) -> Optional[float]:
    """The steps per mm the reversal dead band is derived from: the setting, else what the
    printer states (M92 in the stored M503 answer, Klipper's ``[stepper_x]``/``[stepper_y]``;
    :func:`..core.backlash.deadband_steps` picks the value); None when neither says (the
    compensator then takes a typical 80 steps/mm)."""
    if settings.get("steps_per_mm") is not None:
        return float(settings["steps_per_mm"])
    text = (settings.get("motion_limits") or {}).get("text") or ""
    return deadband_steps(steps_per_mm(text))


def home_position(settings: Dict[str, Any]) -> Tuple[Optional[float], ...]:
    """Where G28 leaves X, Y, Z (mm), None for an axis whose home is not set: the plugin then
    learns it from the printer (M114 after G28), files leave it unknown."""
    home = settings.get("home_mm")
    if home is None:
        return (None, None, None)
    return tuple(None if v is None else float(v) for v in home)


def _path(field: str) -> List[Any]:
    """``"params.backlash.x[1].um"`` -> ``["params", "backlash", "x", 1, "um"]``."""
    out: List[Any] = []
    for part in field.split("."):
        m = re.fullmatch(r"([^\[]*)((?:\[\d+\])*)", part)
        if m is None:
            return out
        if m.group(1):
            out.append(m.group(1))
        out.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return out


def _lookup(doc: Any, path: List[Any]) -> Tuple[bool, Any]:
    for key in path:
        if isinstance(doc, dict) and isinstance(key, str) and key in doc:
            doc = doc[key]
        elif isinstance(doc, list) and isinstance(key, int) and key < len(doc):
            doc = doc[key]
        else:
            return False, None
    return True, doc


MAX_REPAIRS = 100


def repaired(stored: Dict[str, Any]) -> Tuple[Dict[str, Any], List[SettingsError]]:
    """Valid settings for showing and editing invalid stored ones: each invalid value in
    ``stored`` replaced by its default (or dropped where it has none, e.g. an unknown key
    or a bad backlash point), one after the other; and the problems found, first first.
    (Only a view: the stored document itself stays as it is.)"""
    doc = copy.deepcopy(stored)
    problems: List[SettingsError] = []
    base = defaults()
    for _ in range(MAX_REPAIRS):
        try:
            return validate_settings(doc, base), problems
        except SettingsError as exc:
            problems.append(exc)
            path = _path(exc.field)
            while path:
                there, parent = _lookup(doc, path[:-1])
                key = path[-1]
                holds = there and (
                    (isinstance(parent, dict) and key in parent)
                    or (isinstance(parent, list) and isinstance(key, int) and key < len(parent))
                )
                found, default = _lookup(base, path)
                if found and (holds or isinstance(parent, dict)):
                    parent[key] = copy.deepcopy(default)
                    break
                if holds:
                    del parent[key]
                    break
                path = path[:-1]
            if not path:
                break
    return defaults(), problems


def limits_from_profile(profile: Optional[Dict[str, Any]]) -> Optional[Tuple[float, ...]]:
    """Machine limits (x0, x1, y0, y1, z0, z1 mm) from an OctoPrint printer profile."""
    if not profile:
        return None
    vol = profile.get("volume") or {}
    box = vol.get("custom_box")
    if isinstance(box, dict) and all(
        k in box for k in ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
    ):
        lim = tuple(float(box[k]) for k in ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max"))
    else:
        try:
            w, d, h = float(vol["width"]), float(vol["depth"]), float(vol["height"])
        except (KeyError, TypeError, ValueError):
            return None
        if vol.get("origin") == "center":
            lim = (-w / 2, w / 2, -d / 2, d / 2, 0.0, h)
        else:
            lim = (0.0, w, 0.0, d, 0.0, h)
    if lim[0] >= lim[1] or lim[2] >= lim[3] or lim[4] >= lim[5]:
        return None
    return lim


def max_feeds_from_profile(profile: Optional[Dict[str, Any]]) -> Optional[Dict[str, float]]:
    """Axis max feeds (mm/min) from the printer profile's axes section."""
    if not profile:
        return None
    axes = profile.get("axes") or {}
    out = {}
    for a in "xyz":
        try:
            out[a] = float(axes[a]["speed"])
        except (KeyError, TypeError, ValueError):
            pass
    return out or None
