"""KinComp's settings as OctoPrint stores them, and how they take effect.

The checks themselves live in ``service/settings/schema.py`` (no OctoPrint import); this piece reads
the stored settings through OctoPrint's ``PluginSettings``, migrates old versions, saves a validated
document (the params document replaced whole) and applies it to the queue's compensator, now or from
the next print on.

Invalid stored settings (a hand-edited config.yaml, a downgrade) are never overwritten:
the stored document stays exactly as it is, compensation is off (nothing is compensated,
no file is written or marked) and the problem is reported (log, ``/status``, the UI) until
the user fixes it. A save is merged into the stored document, so it keeps every stored key
it does not name; while the stored document is invalid a save that does not fix the bad
value is refused (400 naming it). The machine limits (mm) and axis feeds (mm/min) come from the
current printer profile.

Every change goes through :meth:`SettingsStore.update` (or ``dialog_save``, OctoPrint's own
settings endpoint): under one lock it reads the stored document, merges the change in,
validates the result whole, replaces KinComp's stored settings by it in one step (never
removing a part first: a config.yaml written meanwhile holds the old document or the new
one, never one without parameters), writes config.yaml and applies it. So two saves at the
same time never lose each other's keys or the calibration. A write that fails (disk full)
puts the document back as it was: what is in effect is what is on disk.

It also guards OctoPrint's own settings endpoint (``POST /api/settings``) for KinComp's
part: 403 without KinComp's admin permission, 400 for invalid values; nothing is stored
then.
"""

from __future__ import annotations

import copy
import json
import threading
from typing import Any, Callable, Dict, List, Optional, Tuple

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions
from octoprint.util import dict_minimal_mergediff

from ...core.compensator import Options
from ...core.messages import error_message
from ...core.params import Params
from ...service.notify import N_, Notifier
from ...service.printing.queue import QueueCompensator
from ...service.settings.printer_profiles import (
    calibrated,
    deleted,
    owners,
    profile_id,
    profile_name,
    recorded,
    switch,
)
from ...service.settings.schema import (
    INTERNAL_KEYS,
    SETTINGS_VERSION,
    SettingsError,
    SettingsInvalid,
    defaults,
    engine_config,
    limits_from_profile,
    max_feeds_from_profile,
    migrate,
    repaired,
    validate_settings,
)
from .. import http


class ProfileChanged(Exception):
    """A change meant for printer profile ``expected`` while ``current``'s set is in force
    (a page loaded before a switch): refused, nothing stored."""

    def __init__(self, expected: str, current: str):
        super().__init__(f"expected printer profile {expected!r}, {current!r} is in force")
        self.expected = expected
        self.current = current


class SettingsStore:
    """The stored settings of the plugin ``identifier``.

    ``on_applied(settings)`` runs after every application to the queue (the plugin turns
    demo mode on or off and checks for firmware conflicts there). ``lock`` (reentrant)
    serialises every read-merge-validate-write of the stored document.
    """

    def __init__(
        self,
        settings,
        identifier: str,
        profiles,
        queue: QueueCompensator,
        notifier: Notifier,
        logger,
        on_applied: Callable[[Dict[str, Any]], None],
    ):
        self._settings = settings
        self._identifier = identifier
        self._profiles = profiles
        self._queue = queue
        self._notifier = notifier
        self._logger = logger
        self._on_applied = on_applied
        self.lock = threading.RLock()
        # OctoPrint's own settings lock, held from reading the stored document to writing
        # config.yaml: OctoPrint's own saves (``/api/settings``) and its reloads of a
        # changed config.yaml then never fall in between (they take it too). Always taken
        # after ``lock``, never before; nothing of OctoPrint's holding it calls KinComp.
        self._config_lock = (
            getattr(getattr(settings, "settings", None), "_lock", None) or threading.RLock()
        )
        # what is wrong with the stored settings (a SettingsError), None when they are valid
        self.problem: Optional[SettingsError] = None
        # (stored document as JSON, its validation or None, its SettingsError or None)
        self._validated: Optional[Tuple[str, Any, Any]] = None

    # ~~ reading ------------------------------------------------------------------------------
    def stored(self) -> Dict[str, Any]:
        """The stored settings over the defaults, as they are (not validated): what a
        partial save is merged into. Read from what config.yaml holds itself, so a stored
        value of the wrong type (``params: garbage``) is seen as it is, not hidden behind
        its default."""
        with self.lock:
            raw = self._settings.get_all_data(merged=False)
            raw = copy.deepcopy(raw) if isinstance(raw, dict) else {}
        return {k: _overlay(v, raw[k]) if k in raw else v for k, v in defaults().items()}

    def current(self) -> Dict[str, Any]:
        """The settings in effect: the stored ones, validated; while they are invalid the
        defaults with compensation off (the stored ones stay untouched, ``problem`` says
        what is wrong). The validation of a stored document is kept until the document
        changes (every request asks for the settings: validating them is most of what a
        read of /status or /runs cost the server). A copy, for the caller to change."""
        with self.lock:
            stored = self.stored()
            # (the document's exact text: ``True == 1.0`` in Python, not in a setting)
            key = json.dumps(stored, sort_keys=True, default=repr)
            cached = self._validated
            if cached is None or cached[0] != key:
                try:
                    cached = (key, validate_settings(stored, defaults()), None)
                except SettingsError as exc:
                    cached = (key, None, exc)
                self._validated = cached
            _, s, exc = cached
            if exc is not None:
                self._set_problem(exc)
                s = defaults()
                s["enabled"] = False
                return s
            if self.problem is not None:
                self._logger.info("KinComp: the stored settings are valid again")
                self.problem = None
            return copy.deepcopy(s)

    def editable(self) -> Dict[str, Any]:
        """The settings to show and edit: the stored ones, with any invalid value shown as
        its default (see ``problem``)."""
        s = self.current()
        if self.problem is None:
            return s
        view, _ = repaired(self.stored())
        return view

    def require_usable(self) -> Dict[str, Any]:
        """The current settings, or :class:`SettingsInvalid` while the stored ones are
        invalid (compensation and file jobs refuse to run then)."""
        s = self.current()
        if self.problem is not None:
            raise SettingsInvalid(self.problem)
        return s

    def _set_problem(self, exc: SettingsError) -> None:
        if self.problem is None or str(self.problem) != str(exc):
            self._logger.error(
                "Stored KinComp settings are invalid (%s): compensation is off until they "
                "are fixed; nothing stored was changed",
                exc,
            )
            self._notifier.notify(
                "error",
                N_(
                    "The stored KinComp settings are invalid (%(reason)s): "
                    "compensation is off until you fix them in KinComp's settings. "
                    "Nothing stored was changed."
                ),
                reason=error_message(exc),
            )
        self.problem = exc

    def limits(self) -> Optional[Tuple[float, ...]]:
        """The current printer profile's bed volume (x0, x1, y0, y1, z0, z1 mm), if any."""
        try:
            profile = self._profiles.get_current_or_default()
        except Exception:
            profile = None
        return limits_from_profile(profile)

    def max_feeds(self) -> Optional[Dict[str, float]]:
        """The current printer profile's axis max feeds (mm/min), if any."""
        try:
            return max_feeds_from_profile(self._profiles.get_current_or_default())
        except Exception:
            return None

    def engine_config(self, s: Dict[str, Any], profile=None) -> Tuple[Params, Options]:
        """The Params and Options that the settings ``s`` describe, with the limits of
        ``profile`` (a printer profile) or else of the current profile."""
        return engine_config(s, limits_from_profile(profile) or self.limits())

    def upload_fields(self) -> Tuple[str, str]:
        """The suffixes of the form fields in which OctoPrint hands an uploaded file's
        temporary path and its name to a blueprint view (``file.<suffix>``)."""
        suffix = self._settings.global_get(["server", "uploads", "pathSuffix"]) or "path"
        name_suffix = self._settings.global_get(["server", "uploads", "nameSuffix"]) or "name"
        return suffix, name_suffix

    # ~~ migrating -----------------------------------------------------------------------------
    def migrate(self, target: int, current: Optional[int]) -> None:
        """Stored settings of version ``current`` (None: before versioning) brought to
        ``target``: moved keys moved, unknown keys removed; every value kept as it is (an
        invalid one is reported by ``current``, never replaced; nothing but the moved keys
        is touched then)."""
        with self.lock:
            self._migrate(target, current)

    def _migrate(self, target: int, current: Optional[int]) -> None:
        if current is None or current < target:
            raw = self._settings.get_all_data(merged=False) or {}
            if not raw:
                return  # nothing stored yet: the defaults are current
            migrated = migrate(raw, current)
            for key, value in migrated.items():
                if key in defaults():
                    self._settings.set([key], value)
            try:
                validate_settings(
                    {k: v for k, v in migrated.items() if k in defaults()}, defaults()
                )
                unused = set(raw) - set(defaults())  # moved, or no longer known
            except SettingsError:
                unused = set(raw) - set(migrated)  # only what moved: nothing else is touched
            for key in unused:
                self._settings.remove([key])

    # ~~ saving and applying -----------------------------------------------------------------
    def dialog_save(self, data: Dict[str, Any]):
        """The standard settings dialog path. Invalid values never get here through the UI
        (the before_request hook answers 400 first); anything else invalid is refused whole,
        logged and reported, and the stored settings stay as they were. Without the KinComp
        admin permission nothing is changed (the request hook answers 403 first).
        config.yaml is written here, before the change is applied (OctoPrint writes it again
        after): on a full disk OctoPrint's own write failed after KinComp had applied the new
        parameters, which were then in force without being stored; now a failed write
        changes nothing (the stored document is put back) and says so."""
        if flask.has_request_context() and not Permissions.PLUGIN_KINCOMP_ADMIN.can():
            self._logger.warning(
                "KinComp settings refused: the user lacks the KinComp admin permission"
            )
            return {}
        try:
            _, diff = self.update(data, write=True)
        except SettingsError as exc:
            self._logger.warning("KinComp settings refused: %s", exc)
            self._notifier.notify(
                "error", N_("KinComp settings not saved: %(reason)s"), reason=error_message(exc)
            )
            return {}
        except OSError as exc:  # disk full: nothing changed, nothing in force
            self._logger.error("KinComp settings not saved: %s", exc)
            self._notifier.notify(
                "error", N_("KinComp settings not saved: %(reason)s"), reason=str(exc)
            )
            raise
        return diff

    def update(
        self,
        data: Dict[str, Any],
        replace_params: bool = False,
        immediately: Optional[bool] = None,
        vet: Optional[Callable] = None,
        write: bool = True,
        internal: bool = False,
        expected_profile: Optional[str] = None,
    ) -> Tuple[Dict[str, Any], Dict[str, Any]]:
        """The one way a change is saved: under ``lock``, the stored document with ``data``
        merged in (``replace_params``: its ``params`` replace the stored ones whole),
        validated whole, ``vet(stored, new)`` (may raise, e.g. a permission refused),
        what it changes of the printer's own set recorded for the profile in force
        (:func:`.printer_profiles.recorded`), stored in one step, written to config.yaml
        (``write``) and applied. The profile keys (``INTERNAL_KEYS``) are KinComp's own:
        dropped from ``data`` unless ``internal`` (a profile switch). ``expected_profile``
        (a page sends the profile it was loaded for): :class:`ProfileChanged` (nothing
        changed) when another profile's set is in force. Raises :class:`SettingsError`
        (nothing changed) or what ``vet`` or the write raise (an OSError: the stored
        document is put back, nothing changed). Returns (the new settings, the diff
        stored)."""
        if not internal:
            data = {k: v for k, v in data.items() if k not in INTERNAL_KEYS}
        with self.lock:
            old = self.current()
            with self._config_lock:
                stored = self.stored()
                if expected_profile is not None and expected_profile != stored["profile"]:
                    raise ProfileChanged(expected_profile, stored["profile"])
                new = validate_settings(data, stored, replace_params=replace_params)
                if vet is not None:
                    vet(stored, new)
                if not internal:
                    new = recorded(stored, new)
                diff = self._store(new, write)
            self._applied(old, new, immediately)
            if not internal and self._follow(self.current()):  # (settings just fixed)
                new = self.current()
            return new, diff

    def save(self, new: Dict[str, Any], immediately: Optional[bool] = None, write: bool = False):
        """Stores the validated settings ``new`` (complete: made by ``validate_settings``
        over ``stored()``) as :meth:`update` does, without merging or checking. Returns the
        diff stored (what differs from the defaults)."""
        with self.lock:
            old = self.current()
            with self._config_lock:
                new = recorded(self.stored(), new)
                diff = self._store(new, write)
            self._applied(old, new, immediately)
            return diff

    def _store(self, new: Dict[str, Any], write: bool) -> Dict[str, Any]:
        """KinComp's stored document replaced by what ``new`` differs in from the defaults
        (and the settings version), in one ``set`` of the whole subtree: no moment without
        the parameters; then config.yaml written if ``write`` (on failure the previous
        document is stored again and the error raised)."""
        previous = self._settings.get_all_data(merged=False)
        previous = copy.deepcopy(previous) if isinstance(previous, dict) else {}
        diff = dict_minimal_mergediff(defaults(), new)
        self._settings.set([], dict(diff, _config_version=SETTINGS_VERSION), force=True)
        if write:
            try:
                self.write()
            except Exception:  # disk full, or a value the writer cannot write
                self._settings.set([], previous, force=True)
                raise
        return diff

    def _applied(
        self, old: Dict[str, Any], new: Dict[str, Any], immediately: Optional[bool]
    ) -> None:
        """``new`` (just stored) to the queue; ``params_applied`` if the parameters changed."""
        self.apply(new, immediately=immediately)
        if new["params"] != old["params"]:
            params = Params.from_dict(new["params"])
            self._notifier.event(
                "params_applied",
                {
                    "params_hash": params.hash(),
                    "previous_hash": Params.from_dict(old["params"]).hash(),
                    "pending_until_next_print": self._queue.pending is not None,
                },
            )

    def write(self) -> None:
        """Writes the stored settings to OctoPrint's config file (atomically: a temporary
        file renamed over it)."""
        self._settings.save()

    def apply(self, s: Dict[str, Any], immediately: Optional[bool] = None) -> None:
        """The settings ``s`` to the queue's compensator: at once if ``immediately`` (None:
        as the settings' ``apply_changes`` says), else from the next print on if one runs.
        Compensation stays off while the printer profile in force has no calibration, and
        while the set is another profile's than the connected printer's."""
        params, options = self.engine_config(s)
        now = s["apply_changes"] == "immediately" if immediately is None else immediately
        q = self._queue
        q.pass_through_on_error = s["pass_through_on_error"]
        connected = self._connected_id()
        # another printer connected than the one whose set this is: off until it switches
        theirs = not s["profile"] or connected is None or connected == s["profile"]
        if not q.configure(params, options, s["enabled"] and calibrated(s) and theirs, now):
            self._notifier.notify(
                "info",
                N_(
                    "A print is running: the new KinComp settings (parameters, "
                    "compensation on or off) take effect from the next print on."
                ),
            )
        self._on_applied(s)

    # ~~ printer profiles ---------------------------------------------------------------------
    def active_profile(self, connected: bool = False) -> Optional[Dict[str, Any]]:
        """OctoPrint's current printer profile (or its default one; ``connected``: None
        while none is selected, i.e. no printer connected); {} if OctoPrint gives none."""
        try:
            if connected:
                return self._profiles.get_current()
            return self._profiles.get_current_or_default() or {}
        except Exception:
            return {}

    def profile_names(self) -> Optional[Dict[str, str]]:
        """OctoPrint's printer profiles as {id: name}; None when OctoPrint does not say."""
        try:
            profiles = self._profiles.get_all()
        except Exception:
            return None
        if not isinstance(profiles, dict):
            return None
        return {pid: profile_name(dict(p or {}, id=pid)) for pid, p in profiles.items()}

    def profile_status(self, s: Dict[str, Any]) -> Dict[str, Any]:
        """Which printer profile's calibration is in force (for /status and the UI), and
        the profiles KinComp keeps a set of that OctoPrint no longer has (``deleted``)."""
        profile = self.active_profile(connected=True) or self.active_profile()
        names = self.profile_names()
        return {
            "id": s["profile"],
            "name": profile_name(profile) if profile_id(profile) == s["profile"] else s["profile"],
            "calibrated": calibrated(s),
            "known": sorted(s["profiles"]),
            "deleted": deleted(s["profiles"], names),
        }

    def compensated_for(self, params_hash: str) -> List[str]:
        """The names of the other printer profiles whose parameters have the hash
        ``params_hash`` (a marked file: which printer it was compensated for)."""
        names = self.profile_names() or {}
        return [names.get(pid, pid) for pid in owners(self.current(), params_hash)]

    def follow_profile(self) -> None:
        """Puts the current printer profile's set in force if another one is (a profile
        chosen on connecting, at start-up; while no printer is connected the last one's set
        stays), at once: printer A's parameters must never reach printer B. Says which one,
        and applies the settings. A profile without a calibration: compensation off, and the
        user is told."""
        with self.lock:
            s = self.current()
            try:
                if self._follow(s):
                    return
            except Exception as exc:
                # the switch was not stored: the set in force is still the other
                # profile's, and apply() below keeps compensation off for this printer
                self._logger.exception(
                    "KinComp: the printer profile's calibration could not be put in force"
                )
                self._notifier.notify(
                    "error",
                    N_(
                        "KinComp could not switch to this printer's calibration "
                        "(%(error)s): compensation is off until it can."
                    ),
                    error=str(exc)[:120],
                )
            self.apply(s)

    def _connected_id(self) -> Optional[str]:
        """The id of the connected printer's profile; None while none is connected."""
        profile = self.active_profile(connected=True)
        return None if profile is None else profile_id(profile)

    def _follow(self, s: Dict[str, Any]) -> bool:
        """Switches to the current profile's set if ``s`` (valid settings in force) is
        another's; True if it did (and applied it)."""
        if self.problem is not None:
            return False  # compensation is off; the switch follows once they are fixed
        profile = self.active_profile(connected=True)
        if profile is None:
            # no printer connected: the last one's set stays in force, and settings from
            # before profiles wait for the first printer that connects (OctoPrint's default
            # profile need not be the printer they were measured on)
            return False
        pid = profile_id(profile)
        data = switch(s, pid)
        if data is None:
            return False
        adopted = not s["profile"]
        new, _ = self.update(data, replace_params=True, immediately=True, internal=True)
        # the views reload what they show (the badge, the tab, the history, the limits)
        self._notifier.message({"type": "profile", "profile": self.profile_status(new)})
        self._notifier.message({"type": "motion_limits"})
        if adopted:
            self._logger.info("KinComp: the calibration now belongs to printer profile %s", pid)
        elif calibrated(new):
            self._notifier.notify(
                "status",  # for the record: a line in the tab, no pop-up
                N_("Printer profile %(profile)s: its KinComp calibration is in force."),
                profile=profile_name(profile),
            )
        else:
            self._notifier.notify(
                "warning",
                N_(
                    "Printer profile %(profile)s has no KinComp calibration: "
                    "prints go out uncompensated until you calibrate it or "
                    "enter its parameters."
                ),
                profile=profile_name(profile),
            )
        return True

    # ~~ OctoPrint's settings endpoint --------------------------------------------------------
    def check_settings_request(self):
        """OctoPrint's settings endpoint, for KinComp's part: 403 unless the user has
        KinComp's admin permission (OctoPrint's SETTINGS permission alone must not change
        the machine model), and 400 (instead of OctoPrint's silent 200) for invalid values;
        nothing is stored then. None lets the request through."""
        req = flask.request
        if req.method != "POST" or not req.path.rstrip("/").endswith("/api/settings"):
            return None
        if not Permissions.SETTINGS.can():
            return None
        try:
            data = req.get_json(silent=True)
        except RecursionError:
            return http.error(gettext("The request body is nested too deeply"), 400)
        if not isinstance(data, dict) or not isinstance(data.get("plugins"), dict):
            return None
        mine = data["plugins"].get(self._identifier)
        if mine is None:
            return None
        if not Permissions.PLUGIN_KINCOMP_ADMIN.can():
            return http.error(
                gettext("Changing KinComp's settings needs the KinComp admin permission"), 403
            )
        try:
            http.check_json(mine)
        except http.BadRequest as exc:
            return http.error(gettext("KinComp: %(reason)s", reason=str(exc)), 400)
        stored = self.stored()
        try:
            new = validate_settings(mine, stored)
        except SettingsError as exc:
            return http.error(gettext("KinComp: %(reason)s", reason=http.tr(exc)), 400)
        return http.update_source_refused(stored, new)


def _overlay(default: Any, stored: Any) -> Any:
    """``stored`` over ``default``: objects merged key by key (config.yaml holds only what
    differs from the defaults), anything else as stored, whatever its type."""
    if isinstance(default, dict) and isinstance(stored, dict):
        out = dict(default)
        for key, value in stored.items():
            out[key] = _overlay(default[key], value) if key in default else value
        return out
    return stored
