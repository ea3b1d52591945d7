"""KinComp's settings, each declared once (no OctoPrint import).

:data:`SETTINGS` declares every setting: its key, default, check, where it belongs (the
printer profile's set, or KinComp's own bookkeeping) and, for those the settings page shows
as a plain field, its form (kind, label, unit, help, choices, the element's id). Everything
else is derived from it: :func:`defaults`, the checks (:data:`CHECKS`, in declaration order),
what belongs to a printer profile (:data:`PER_PROFILE`), what only KinComp sets
(:data:`INTERNAL_KEYS`), the objects merged key by key (:data:`MERGED`) and the settings
page's fields (:func:`form_fields`, which the template renders and the page's script reads).
A new plain setting is one :class:`Setting` here (and the German of its texts).

The settings hold the params document (see ``core/params.py``) plus how the plugin applies
it, demo mode, the live ballbar sensor (``sensor``: see ``sensor/config.py``) and the
printer's stated motion limits. :func:`validate_settings` returns a complete, checked copy
or raises :class:`SettingsError` naming the field, so that the API can answer 400 and keep
the old values.
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

from ...core.backlash import deadband_steps
from ...core.compensator import POLICIES, Options
from ...core.messages import Msg
from ...core.params import Params
from ...firmware.motion_limits import narrowed_travel, steps_per_mm
from ..notify import N_
from . import software_update
from .checks import (
    SettingsError,
    SettingsInvalid,
    check_bool,
    check_choice,
    check_decimals,
    check_demo,
    check_home,
    check_number,
    check_params,
    check_profile_id,
    check_software_update,
    check_steps,
    merge_params,
    motion_limits_defaults,
    sensor_defaults,
    validate_motion_limits,
    validate_sensor,
)

__all__ = ["SettingsError", "SettingsInvalid"]  # (raised by validate_settings)

SETTINGS_VERSION = 1
MODES = ("on_the_fly", "on_upload", "background")
APPLY_CHANGES = ("next_print", "immediately")


@dataclass(frozen=True)
class Field:
    """A plain field of the settings page: ``path`` in the settings document (``demo.enabled``,
    ``params.scale_ppm.x``), ``kind`` ``bool`` (a checkbox), ``choice`` (a list of
    ``choices``: (value, label)), ``number`` or ``optional_number`` (a text field; empty means
    None: ``placeholder`` says what then applies); ``label``, ``unit``, ``help`` in English
    (translated where shown); ``dom_id`` the element's id; ``section`` the page's fieldset."""

    path: str
    kind: str
    label: str
    section: str
    dom_id: str
    unit: str = ""
    help: str = ""
    choices: Tuple[Tuple[str, str], ...] = ()
    placeholder: str = ""

    def as_dict(self, translate: Callable[[str], str]) -> Dict[str, Any]:
        """The field for the page, its texts through ``translate``."""
        return {
            "path": self.path,
            "kind": self.kind,
            "label": translate(self.label),
            "section": self.section,
            "id": self.dom_id,
            "unit": self.unit,
            "help": translate(self.help) if self.help else "",
            "choices": [{"value": v, "label": translate(t)} for v, t in self.choices],
            "placeholder": translate(self.placeholder) if self.placeholder else "",
        }


@dataclass(frozen=True)
class Setting:
    """One setting: ``key`` in the settings document, its ``default`` (a JSON value, copied
    for each use), its ``check`` ((value, field) -> the checked value, or SettingsError
    naming the field), ``scope`` (``global``; ``profile``: kept per printer profile and
    swapped when the profile changes; ``internal``: set by KinComp only, dropped from what a
    request sends), ``merged`` (an object updated key by key: a form may send only some
    keys) and the plain ``fields`` the settings page shows of it."""

    key: str
    default: Any
    check: Callable[[Any, str], Any]
    scope: str = "global"
    merged: bool = False
    fields: Tuple[Field, ...] = ()


def _choice_check(allowed):
    return lambda v, f: check_choice(v, f, allowed)


def _range_check(lo, hi):
    return lambda v, f: check_number(v, f, lo, hi)


def _axes_fields(group, letters, unit, section, hints=None):
    """Fields of ``params.<group>.<letter>`` (the squareness and scale terms, labelled by
    their axes; their bounds are the params document's own, ``core/params.py``)."""
    hints = hints or {}
    return tuple(
        Field(
            f"params.{group}.{k}",
            "number",
            k.upper(),
            section,
            f"kincomp_{group[:2]}_{k}",
            unit=unit,
            help=hints.get(k, ""),
        )
        for k in letters
    )


_PARAMS_FIELDS = (
    _axes_fields(
        "squareness_um_per_m",
        ("xy", "xz", "yz"),
        "µm/m",
        "squareness",
        {
            "xy": N_("Positive: X grows with Y (the Y axis leans toward +X)."),
            "xz": N_("Positive: X grows with Z."),
            "yz": N_("Positive: Y grows with Z."),
        },
    )
    + _axes_fields("scale_ppm", "xyz", "ppm", "scale")
    + (
        Field(
            "params.backlash.fraction",
            "number",
            N_("Fraction applied"),
            "backlash",
            "kincomp_bl_fraction",
            help=N_("0 to 1: how much of the measured backlash to take up (1 = all of it)."),
        ),
        Field(
            "params.backlash.smoothing_mm",
            "number",
            N_("Smoothing"),
            "backlash",
            "kincomp_bl_smoothing",
            unit="mm",
            help=N_(
                "Spread each take-up over this much following travel instead of one jump "
                "(0 = immediate)."
            ),
        ),
    )
)

SETTINGS: Tuple[Setting, ...] = (
    Setting(
        "enabled",
        False,
        check_bool,
        fields=(
            Field(
                "enabled",
                "bool",
                N_("Compensate moves"),
                "general",
                "kincomp_enabled",
                help=N_(
                    "When on, KinComp rewrites every move sent to the printer (or every "
                    "uploaded file, see mode)."
                ),
            ),
        ),
    ),
    Setting(
        "mode",
        "on_the_fly",
        _choice_check(MODES),
        fields=(
            Field(
                "mode",
                "choice",
                N_("Mode"),
                "general",
                "kincomp_mode",
                help=N_(
                    "Files compensated on upload carry a marker and are never compensated a "
                    "second time when printed."
                ),
                choices=(
                    ("on_the_fly", N_("On the fly (every line as it is sent)")),
                    ("on_upload", N_("On upload (files are compensated when stored)")),
                    ("background", N_("In the background (a compensated copy of each upload)")),
                ),
            ),
        ),
    ),
    Setting(
        "limits_policy",
        "clamp",
        _choice_check(POLICIES),
        fields=(
            Field(
                "limits_policy",
                "choice",
                N_("Bed limits"),
                "moves",
                "kincomp_limits",
                help=N_(
                    "The bed volume is the printer profile's, narrowed by the travel the "
                    "firmware states. A point the file itself puts on or past its edge marks "
                    "where the travel ends there."
                ),
                choices=(
                    ("clamp", N_("Keep compensated moves inside the bed volume and report it")),
                    ("warn", N_("Warn when a compensated move leaves the bed volume")),
                    ("error", N_("Stop (pause the print) instead")),
                ),
            ),
        ),
    ),
    Setting(
        "chord_tol_mm",
        0.01,
        _range_check(0.0005, 1.0),
        fields=(
            Field(
                "chord_tol_mm",
                "number",
                N_("Arc chord tolerance"),
                "moves",
                "kincomp_chord",
                unit="mm",
                help=N_(
                    "Compensated arcs (G2/G3) stay within this distance of the true arc: kept "
                    "as arcs where one fits, else split or cut into straight segments."
                ),
            ),
        ),
    ),
    Setting(
        "linearise_arcs",
        False,
        check_bool,
        fields=(
            Field(
                "linearise_arcs",
                "bool",
                N_("Write arcs as straight segments (for firmware without G2/G3 support)"),
                "moves",
                "kincomp_linearise_arcs",
            ),
        ),
    ),
    Setting("decimals", 3, check_decimals),
    # where G28 leaves X, Y, Z (mm); None (or a None entry): learned
    Setting("home_mm", None, check_home, scope="profile"),
    # the X/Y drives' steps per mm (the reversal dead band is a twentieth of a step); None:
    # read from the printer (M92 in its M503 answer, Klipper's [stepper_x/y]), else a
    # typical 80 (steps_for_deadband)
    Setting(
        "steps_per_mm",
        None,
        check_steps,
        scope="profile",
        fields=(
            Field(
                "steps_per_mm",
                "optional_number",
                N_("Steps per mm (X/Y)"),
                "moves",
                "kincomp_steps_per_mm",
                placeholder=N_("from the printer"),
                help=N_(
                    "A retreat of less than a twentieth of a step gets no backlash take-up "
                    "(the drive would not move for it). Empty: read from the printer (M92 in "
                    "its answer to M503, or Klipper's [stepper_x] pasted with the motion "
                    "limits), else 80 steps/mm."
                ),
            ),
        ),
    ),
    Setting(
        "pass_through_on_error",
        False,
        check_bool,
        fields=(
            Field(
                "pass_through_on_error",
                "bool",
                N_(
                    "If a move cannot be compensated, send it as written (otherwise the print "
                    "pauses)"
                ),
                "moves",
                "kincomp_pass_through",
            ),
        ),
    ),
    Setting(
        "apply_changes",
        "next_print",
        _choice_check(APPLY_CHANGES),
        fields=(
            Field(
                "apply_changes",
                "choice",
                N_("New parameters"),
                "moves",
                "kincomp_apply",
                choices=(
                    ("next_print", N_("apply from the next print on")),
                    ("immediately", N_("apply immediately, even during a print")),
                ),
            ),
        ),
    ),
    # live: in demo mode the virtual ballbar streams to KinComp as a live sensor
    Setting(
        "demo",
        {"enabled": False, "live": True},
        check_demo,
        merged=True,
        fields=(
            Field(
                "demo.enabled",
                "bool",
                N_(
                    "Demo mode: the virtual printer gets hidden simulated errors and a virtual "
                    "ballbar"
                ),
                "moves",
                "kincomp_demo",
            ),
        ),
    ),
    Setting("sensor", sensor_defaults(), lambda v, f: validate_sensor(v), merged=True),
    Setting(
        "motion_limits",
        motion_limits_defaults(),
        lambda v, f: validate_motion_limits(v),
        scope="profile",
        merged=True,
    ),
    Setting("software_update", software_update.default_settings(), check_software_update),
    Setting("params", Params().to_dict(), check_params, scope="profile", fields=_PARAMS_FIELDS),
    # per printer: the OctoPrint printer profile whose set (PER_PROFILE keys) is in force
    # above ("" : none yet, the set is adopted by the active profile), every profile's set
    # by profile id, and the profile the runs recorded before profiles belong to (see
    # printer_profiles.py)
    Setting("profile", "", check_profile_id, scope="internal"),
    Setting("legacy_profile", "", check_profile_id, scope="internal"),
    Setting("profiles", {}, lambda v, f: _profiles(v, f), scope="internal"),
)

BY_KEY: Dict[str, Setting] = {s.key: s for s in SETTINGS}
SETTING_KEYS = tuple(BY_KEY)
# what belongs to one printer: kept per printer profile, swapped when the profile changes
PER_PROFILE = tuple(s.key for s in SETTINGS if s.scope == "profile")
# set only by KinComp itself (a profile switch), dropped from what a request sends
INTERNAL_KEYS = tuple(s.key for s in SETTINGS if s.scope == "internal")
# objects updated key by key (a form may send only some keys)
MERGED = tuple(s.key for s in SETTINGS if s.merged)
# key -> check(value, field), in the order of checking
CHECKS: Dict[str, Callable[[Any, str], Any]] = {s.key: s.check for s in SETTINGS}


def defaults() -> Dict[str, Any]:
    """Every setting's default (a fresh copy)."""
    return {s.key: copy.deepcopy(s.default) for s in SETTINGS}


def form_fields(translate: Callable[[str], str] = str) -> List[Dict[str, Any]]:
    """The settings page's plain fields, in the declaration's order, their texts through
    ``translate`` (the page's language)."""
    return [f.as_dict(translate) for s in SETTINGS for f in s.fields]


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


def _profiles(value: Any, field: str) -> Dict[str, Dict[str, Any]]:
    """Each printer profile's set: an object of PER_PROFILE keys (a missing key: its
    default; no ``params``: the profile has no calibration), each checked as on top."""
    if not isinstance(value, dict):
        raise SettingsError(field, Msg("must be an object"))
    out: Dict[str, Dict[str, Any]] = {}
    for pid, entry in value.items():
        check_profile_id(pid, field)
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


def engine_config(
    settings: Dict[str, Any], limits: Optional[Tuple[float, ...]]
) -> Tuple[Params, Options]:
    """The Params and compensator Options the settings describe; ``limits``: the printer
    profile's volume (x0, x1, y0, y1, z0, z1 mm, or None), narrowed by the travel the
    firmware states in the stored ``motion_limits`` text (Klipper's position_min/max, RRF's
    M208, Marlin's M211 answer: ``firmware.motion_limits.narrowed_travel``)."""
    params = Params.from_dict(settings["params"])
    text = (settings.get("motion_limits") or {}).get("text") or ""
    options = Options(
        chord_tol_mm=float(settings["chord_tol_mm"]),
        linearise_arcs=bool(settings.get("linearise_arcs", False)),
        limits=narrowed_travel(limits, text) if text else limits,
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
