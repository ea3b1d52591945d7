"""The checks of KinComp's settings values, one function per kind of value (no OctoPrint
import). Each takes ``(value, field)`` and returns the checked value or raises
:class:`SettingsError` naming ``field``; the declaration of the settings
(``schema.py``) says which check each setting has.
"""

from __future__ import annotations

import copy
from typing import Any, Dict, List, Optional, Sequence

from ...core.messages import Msg
from ...core.numbers import finite
from ...core.params import Params, ParamsError
from ...firmware.motion_limits import MAX_TEXT, LimitsError, parse_limits
from ...sensor.config import SensorConfig
from ...sensor.protocol_pattern import check_scale, compile_pattern
from ...sensor.sensor_error import SensorError
from . import software_update


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


def sensor_defaults() -> Dict[str, Any]:
    """No live sensor: tests are measured by uploading a trace."""
    cfg = SensorConfig().to_dict()
    return dict({k: cfg[k] for k in SENSOR_KEYS if k != "enabled"}, enabled=False)


def check_bool(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise SettingsError(field, Msg("must be true or false"))
    return value


def check_choice(value: Any, field: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise SettingsError(field, Msg("must be one of %(choices)s", choices=", ".join(allowed)))
    return value


def check_number(value: Any, field: str, lo: float, hi: float) -> float:
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


def check_decimals(dec: Any, field: str) -> int:
    if isinstance(dec, bool) or not isinstance(dec, int) or not 3 <= dec <= 6:
        raise SettingsError(field, Msg("must be an integer within 3..6"))
    return dec


def check_home(home: Any, field: str) -> Optional[List[Optional[float]]]:
    if home is None:
        return None
    if not isinstance(home, list) or len(home) != 3:
        raise SettingsError(
            field, Msg("must be a list of three numbers (mm) or null (learned from the printer)")
        )
    return [
        None if v is None else check_number(v, f"{field}[{i}]", -10000, 10000)
        for i, v in enumerate(home)
    ]


def check_steps(value: Any, field: str) -> Optional[float]:
    """The drives' steps per mm, or None (from the printer, else the default)."""
    return None if value is None else check_number(value, field, 1.0, 100000.0)


def check_demo(demo: Any, field: str) -> Dict[str, bool]:
    if not isinstance(demo, dict) or set(demo) - {"enabled", "live"}:
        raise SettingsError(field, Msg("must be an object with 'enabled' and 'live'"))
    return {
        "enabled": check_bool(demo.get("enabled", False), f"{field}.enabled"),
        "live": check_bool(demo.get("live", True), f"{field}.live"),
    }


def check_software_update(value: Any, field: str) -> Dict[str, Any]:
    try:
        return software_update.validate(value)
    except software_update.UpdateSettingsError as exc:
        raise SettingsError(exc.field, exc.message) from None


def check_params(value: Any, field: str) -> Dict[str, Any]:
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
    out["source"] = check_choice(out["source"], "motion_limits.source", MOTION_LIMIT_SOURCES)
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
    enabled = check_bool(out.pop("enabled"), "sensor.enabled")
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


def check_profile_id(value: Any, field: str) -> str:
    if not isinstance(value, str) or len(value) > 200:
        raise SettingsError(field, Msg("must be a printer profile id (a text)"))
    return value
