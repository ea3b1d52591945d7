"""KinComp's OctoPrint plugin: mixins and hooks wired to the core modules.

Everything that computes lives in plain modules (compensator, queue, settings, runs,
ballbar/...); this class translates OctoPrint's callbacks, requests and events into calls
to them, and their results into responses, notifications and events.
"""

from __future__ import annotations

import datetime as _dt
import io
import json
import os
import re
import threading
import time
from typing import Any, Dict, Optional

import flask
import octoprint.plugin
from flask_babel import gettext
from octoprint.access import ADMIN_GROUP
from octoprint.access.permissions import Permissions
from octoprint.events import Events
from octoprint.filemanager import FileDestinations, valid_file_type
from octoprint.filemanager.util import DiskFileWrapper, StreamWrapper

from .. import __version__
from ..ballbar.analysis import analyse
from ..ballbar.artifacts import ArtifactError, diagnostics_from_artifact
from ..ballbar.demo import DemoBallbar
from ..ballbar.formats import TraceError, load_any
from ..ballbar.program import ProgramError, TestSpec, cap_feed, generate, spec_dict
from ..core.compensator import Options
from ..core.firmware import equivalents
from ..core.kinematics import changes_nothing
from ..core.marker import file_marker
from ..core.messages import Msg, as_dict, error_message, translate
from ..core.params import Params
from ..engines.files import AlreadyCompensated, compensate_file
from ..engines.select import engine
from .firmware_watch import FirmwareWatcher
from .queue import FILE_TAG, QueueCompensator
from .runs import RunNotFound, RunStore
from .settings import (
    SETTINGS_VERSION,
    SettingsError,
    defaults,
    engine_config,
    limits_from_profile,
    max_feeds_from_profile,
    migrate,
    validate_settings,
)
from .upload import BackgroundCompensator, CompensatingStream, Job

MAX_TRACE_UPLOAD = 16 * 1024 * 1024
PROGRAM_FOLDER = "kincomp"
_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


def N_(message: str) -> str:
    """Marks a message for translation; the browser translates it (see _notify)."""
    return message


# what the firmware may compensate too, as words in a notification (translated by the UI)
CONFLICT_NAMES = {"skew": N_("skew"), "backlash": N_("backlash"), "scale": N_("axis scale")}


def _error(message: str, status: int = 400):
    return flask.make_response(flask.jsonify(error=message), status)


def _tr(text) -> str:
    """A core message (messages.Msg) or exception in the requesting user's language."""
    if isinstance(text, BaseException):
        text = error_message(text)
    return translate(text, gettext)


def _with_i18n(eq: Dict[str, Any]) -> Dict[str, Any]:
    """Firmware equivalents with their notes also as translatable templates."""
    return dict(eq, notes_i18n=[as_dict(n) for n in eq.get("notes", [])])


def _json_object() -> Optional[Dict[str, Any]]:
    """The request's JSON body if it is an object, else None."""
    data = flask.request.get_json(silent=True)
    return data if isinstance(data, dict) else None


class _BadRequest(ValueError):
    """A request field of the wrong type (answered 400 with this message)."""


def _flag(data: Dict[str, Any], key: str) -> bool:
    """A JSON boolean field, False when absent. A string such as "false" is refused, not
    taken as true: these flags print, or apply parameters mid-print."""
    value = data.get(key, False)
    if not isinstance(value, bool):
        raise _BadRequest(gettext("'%(key)s' must be true or false", key=key))
    return value


def _require(permission) -> None:
    if not permission.can():
        flask.abort(403)


class KinCompPlugin(
    octoprint.plugin.StartupPlugin,
    octoprint.plugin.SettingsPlugin,
    octoprint.plugin.TemplatePlugin,
    octoprint.plugin.AssetPlugin,
    octoprint.plugin.BlueprintPlugin,
    octoprint.plugin.EventHandlerPlugin,
    octoprint.plugin.WizardPlugin,
):
    def __init__(self):
        super().__init__()
        self.queue: Optional[QueueCompensator] = None
        self.watch = FirmwareWatcher()
        self.runs: Optional[RunStore] = None
        self.demo: Optional[DemoBallbar] = None
        self.files: Optional[BackgroundCompensator] = None
        self._program_path: Optional[str] = None
        self._program_spec: Optional[TestSpec] = None
        self._program_hash = ""
        self._lock = threading.RLock()
        self._warned_conflicts: Dict[str, str] = {}
        self._warned_unknown_at = 0.0  # time.monotonic() of the last such notification
        self._pause_seen = False
        # The print's start is seen by the queuing hook (file reader thread) and by
        # PRINT_STARTED (event thread), in either order: decisions and their effects on the
        # print state are made under this lock, or both threads could begin one print and
        # every later end event would look like a late one.
        self._print_lock = threading.RLock()
        self._prints_begun = 0  # prints whose first line (or start event) was handled
        self._start_events = 0  # PRINT_STARTED events received
        self._file_lines_seen = False  # a line of the current print went through the hook
        self._comm = None  # the MachineCom of the current connection
        # stored settings that could not be used (defaults instead), shown in the UI
        self._settings_problem = None

    # ~~ lifecycle ---------------------------------------------------------------------------
    def initialize(self):
        self.runs = RunStore(self.get_plugin_data_folder())
        self.queue = QueueCompensator(Params(), Options(), on_error=self._on_compensation_error,
                                      on_untouched=self._on_untouched)
        self.files = BackgroundCompensator(self._run_file_job, self._job_changed)

    def on_after_startup(self):
        self._apply_settings(self._current_settings(), immediately=True)
        self._logger.info("KinComp %s ready (compensation %s, %s engine)", __version__,
                          "on" if self.queue.enabled else "off",
                          engine())

    # ~~ settings ----------------------------------------------------------------------------
    def get_settings_defaults(self):
        return defaults()

    def get_settings_version(self):
        return SETTINGS_VERSION

    def on_settings_migrate(self, target, current):
        if current is None or current < target:
            raw = self._settings.get_all_data(merged=False) or {}
            if not raw:
                return  # nothing stored yet: the defaults are current
            migrated = migrate(raw, current)
            try:
                clean = validate_settings(
                    {k: v for k, v in migrated.items() if k in defaults()}, defaults())
            except SettingsError as exc:
                self._logger.warning("Stored KinComp settings invalid (%s): defaults used", exc)
                self._settings_problem = error_message(exc)
                clean = defaults()
            for key, value in clean.items():
                self._settings.set([key], value)
            for key in set(migrated) - set(defaults()):
                self._settings.remove([key])

    def _current_settings(self) -> Dict[str, Any]:
        current = {k: self._settings.get([k], merged=True) for k in defaults()}
        try:
            return validate_settings(current, defaults())
        except SettingsError as exc:
            self._logger.error("Stored KinComp settings are invalid (%s); using defaults", exc)
            self._settings_problem = error_message(exc)
            return defaults()

    def on_settings_save(self, data):
        """The standard settings dialog path. Invalid values never get here through the UI
        (the before_request hook answers 400 first); anything else invalid is refused
        whole, logged and reported, and the stored settings stay as they were. Without the
        KinComp admin permission nothing is changed (the request hook answers 403 first)."""
        if flask.has_request_context() and not Permissions.PLUGIN_KINCOMP_ADMIN.can():
            self._logger.warning("KinComp settings refused: the user lacks the KinComp "
                                 "admin permission")
            return {}
        try:
            new = validate_settings(data, self._current_settings())
        except SettingsError as exc:
            self._logger.warning("KinComp settings refused: %s", exc)
            self._notify("error", N_("KinComp settings not saved: %(reason)s"),
                         reason=error_message(exc))
            return {}
        return self._save_settings(new)

    def _save_settings(self, new: Dict[str, Any], immediately: Optional[bool] = None):
        old = self._current_settings()
        # the base class merges into what is stored: optional params terms that the new
        # document leaves out (servo_lag_ms, axis_errors, ...) would survive. Replace them.
        self._settings.remove(["params"])
        diff = octoprint.plugin.SettingsPlugin.on_settings_save(self, new)
        self._apply_settings(new, immediately=immediately)
        if new["params"] != old["params"]:
            params = Params.from_dict(new["params"])
            self._event("params_applied", {
                "params_hash": params.hash(),
                "previous_hash": Params.from_dict(old["params"]).hash(),
                "pending_until_next_print": self.queue.pending is not None})
        return diff

    def _limits(self):
        try:
            profile = self._printer_profile_manager.get_current_or_default()
        except Exception:  # noqa: BLE001 - no profile: no limits
            profile = None
        return limits_from_profile(profile)

    def _apply_settings(self, s: Dict[str, Any], immediately: Optional[bool] = None) -> None:
        params, options = engine_config(s, self._limits())
        now = s["apply_changes"] == "immediately" if immediately is None else immediately
        q = self.queue
        q.pass_through_on_error = s["pass_through_on_error"]
        if not q.configure(params, options, s["enabled"], now):
            self._notify("info", N_("A print is running: the new KinComp settings (parameters, "
                                    "compensation on or off) take effect from the next print "
                                    "on."))
        if s["demo"]["enabled"] and self.demo is None:
            self.demo = DemoBallbar()
        elif not s["demo"]["enabled"]:
            self.demo = None
        self._check_conflicts()

    # ~~ wizard ------------------------------------------------------------------------------
    def is_wizard_required(self):
        return True  # shown once (per wizard version): it introduces the calibration tab

    def get_wizard_version(self):
        return 1

    # ~~ templates and assets ----------------------------------------------------------------
    def is_template_autoescaped(self):
        return True

    def get_template_configs(self):
        return [
            {"type": "settings", "name": "KinComp", "custom_bindings": True},
            {"type": "tab", "name": gettext("Calibration"), "custom_bindings": True},
            {"type": "wizard", "name": "KinComp", "custom_bindings": True},
        ]

    def get_assets(self):
        return {"js": ["js/kincomp.js"], "css": ["css/kincomp.css"]}

    # ~~ hooks -------------------------------------------------------------------------------
    def queuing_hook(self, comm_instance, phase, cmd, cmd_type, gcode, subcode=None,
                     tags=None, *args, **kwargs):
        if comm_instance is not self._comm:
            self._connection_changed(comm_instance)
        if tags and FILE_TAG in tags and not (
                self.queue.printing and self._file_lines_seen and "fileline:1" not in tags):
            # (the test above skips the lock for the lines of a print that is under way:
            # under the lock, such a line changes nothing either)
            with self._print_lock:
                if not self.queue.printing or ("fileline:1" in tags and
                                               self._file_lines_seen):
                    # the first line of a print: PRINT_STARTED may be delivered later, on
                    # the event thread, so the print's state is set up here, before its
                    # first line is handled (also when the previous print's end event is
                    # still pending)
                    self._print_begins(self._current_job())
                self._file_lines_seen = True
        q = self.queue
        if q.halted:
            self._follow_pause(comm_instance)
        if cmd[:1] in "MmSs" and FirmwareWatcher.relevant(cmd[:8]):
            self.watch.sent(cmd)
            self._check_conflicts()
        result = q.handle(cmd, tags)
        demo = self.demo
        if demo is not None and demo.recording:
            # what goes out, recorded once here: in the sent phase resends would repeat lines
            if result is None:
                demo.record(cmd)
            else:
                for line in result:
                    demo.record(line)
        return result

    def _connection_changed(self, comm_instance) -> None:
        """A new connection (OctoPrint makes a new comm object per connect): nothing about
        the printer's position or firmware is known any more. Done here, synchronously, as
        CONNECTED reaches ``on_event`` only after the first commands may have gone out."""
        self._comm = comm_instance
        self.queue.reset()
        self.watch.reset()

    def _current_job(self) -> Dict[str, Any]:
        try:
            f = (self._printer.get_current_job() or {}).get("file") or {}
        except Exception:  # noqa: BLE001 - no job information: not precompensated
            f = {}
        return {"origin": f.get("origin"), "path": f.get("path")}

    def _print_begins(self, payload) -> None:
        """A print starts: fresh state, its marker checked. Counted, so that a PrintDone of
        the previous print that arrives after this print's first line is recognised."""
        self._prints_begun += 1
        self._file_lines_seen = False
        marked = self._is_precompensated(payload)
        self.queue.print_started(marked)
        self._warned_unknown_at = 0.0
        self._pause_seen = False
        self.files.set_paused(True)
        self._start_demo_recording(payload)

    def _follow_pause(self, comm_instance) -> None:
        """After a compensation error the queue holds the print's moves back until the user
        resumes. PRINT_RESUMED reaches on_event only after OctoPrint has started sending
        again, so the hook watches the printer state: paused (or pausing) once, then
        printing again means resumed."""
        try:
            if comm_instance.isPausing() or comm_instance.isPaused():
                self._pause_seen = True
            elif self._pause_seen and (comm_instance.isPrinting() or
                                       comm_instance.isResuming()):
                self._resumed_after_error()
        except AttributeError:  # not a MachineCom (tests): the event does it
            pass

    def _resumed_after_error(self) -> None:
        q = self.queue
        if not q.halted:
            return
        self._logger.warning("KinComp: print resumed after a compensation error; %d moves "
                             "were held back", q.held_moves)
        q.resume()
        self._pause_seen = False
        self._warned_unknown_at = 0.0  # the position is unknown now: say so again

    def _on_untouched(self, cmd: str, why: str) -> None:
        """A move went out as written: its start position is not known (no G28 since
        connecting, probing, a compensation error), or it is malformed. Never silent: always
        logged, notified at most once a minute."""
        if why == "malformed":
            self._logger.warning("KinComp: malformed move %r sent as written; position "
                                 "forgotten until the next G28 or absolute move", cmd)
        else:
            self._logger.warning("KinComp: %r sent uncompensated: position unknown", cmd)
        now = time.monotonic()
        if now - self._warned_unknown_at < 60.0:
            return
        self._warned_unknown_at = now
        if why == "malformed":
            self._notify("warning", N_("KinComp could not read the move '%(cmd)s' and sent it "
                                       "as written; moves are compensated again once the "
                                       "position is known (G28 or an absolute move)."),
                         cmd=cmd)
        else:
            self._notify("warning", N_("KinComp sent '%(cmd)s' uncompensated because the "
                                       "printer's position is unknown. Home the printer "
                                       "(G28) so that moves can be compensated."), cmd=cmd)

    def received_hook(self, comm_instance, line, *args, **kwargs):
        if comm_instance is not self._comm:
            self._connection_changed(comm_instance)
        if FirmwareWatcher.relevant(line):
            self.watch.received(line)
            self._check_conflicts()
        return line

    def preprocessor_hook(self, path, file_object, links=None, printer_profile=None,
                          allow_overwrite=False, *args, **kwargs):
        s = self._current_settings()
        if not s["enabled"] or s["mode"] != "on_upload":
            return None
        if not valid_file_type(path, type="gcode"):
            return None
        params, options = engine_config(s, limits_from_profile(printer_profile) or
                                        self._limits())
        if changes_nothing(params):
            return None
        return StreamWrapper(file_object.filename,
                             CompensatingStream(file_object.stream(), params, options))

    def permissions_hook(self, *args, **kwargs):
        return [{
            "key": "ADMIN",
            "name": "KinComp admin",
            "description": N_("Change KinComp's parameters, run and apply calibrations and "
                              "compensate files"),
            "roles": ["admin"],
            "dangerous": True,
            "default_groups": [ADMIN_GROUP],
        }]

    def bodysize_hook(self, current_max_body_sizes, *args, **kwargs):
        return [("POST", r"/trace", MAX_TRACE_UPLOAD)]

    def custom_events_hook(self, *args, **kwargs):
        return ["params_applied", "calibration_analysed"]

    def before_api_request_hook(self, plugin=None, *args, **kwargs):
        return [self._check_settings_request]

    def _check_settings_request(self):
        """OctoPrint's settings endpoint, for KinComp's part: 403 unless the user has
        KinComp's admin permission (OctoPrint's SETTINGS permission alone must not change
        the machine model), and 400 (instead of OctoPrint's silent 200) for invalid values;
        nothing is stored then."""
        req = flask.request
        if req.method != "POST" or not req.path.rstrip("/").endswith("/api/settings"):
            return None
        if not Permissions.SETTINGS.can():
            return None
        data = req.get_json(silent=True)
        if not isinstance(data, dict):
            return None
        mine = (data.get("plugins") or {}).get(self._identifier)
        if mine is None:
            return None
        if not Permissions.PLUGIN_KINCOMP_ADMIN.can():
            return _error(gettext("Changing KinComp's settings needs the KinComp admin "
                                  "permission"), 403)
        try:
            validate_settings(mine, self._current_settings())
        except SettingsError as exc:
            return _error(gettext("KinComp: %(reason)s", reason=_tr(exc)), 400)
        return None

    # ~~ events ------------------------------------------------------------------------------
    _PRINT_EVENTS = frozenset({Events.DISCONNECTED, Events.PRINT_STARTED, Events.PRINT_DONE,
                               Events.PRINT_FAILED, Events.PRINT_CANCELLED})

    def on_event(self, event, payload):
        payload = payload or {}
        if event in self._PRINT_EVENTS:
            with self._print_lock:  # against the queuing hook's view of the print
                self._on_print_event(event, payload)
        elif event == Events.FIRMWARE_DATA:
            self._query_firmware_compensation(payload)
        elif event in (Events.CONNECTED, Events.PRINTER_PROFILE_MODIFIED):
            # the bed volume (limits) and axis feeds come from the printer profile, which
            # a connection may switch and the user may edit
            self._apply_settings(self._current_settings())
        elif event == Events.TRANSFER_STARTED:
            if self.queue.enabled:
                self._notify("warning", N_("Files streamed to the printer's SD card are not "
                                           "compensated; compensate them on upload first."))
        elif event == Events.PRINT_PAUSED:
            if self.queue.halted:
                self._pause_seen = True
        elif event == Events.PRINT_RESUMED:
            self._resumed_after_error()
        elif event == Events.FILE_ADDED:
            self._maybe_background(payload)

    def _on_print_event(self, event, payload):
        if event == Events.DISCONNECTED:
            self._comm = None
            self.queue.reset()
            self.watch.reset()
            if self.queue.printing:
                self.queue.print_ended()
        elif event == Events.PRINT_STARTED:
            self._start_events += 1
            if payload.get("origin") == FileDestinations.SDCARD and self.queue.enabled:
                self._notify("warning", N_("This print runs from the printer's SD card: "
                                           "KinComp cannot compensate it."))
            if self._prints_begun < self._start_events:  # not seen by the queuing hook
                self._print_begins(payload)
        else:  # the print is done, failed or cancelled
            if self._prints_begun > self._start_events and self._printing_now():
                return  # late: the next print's first line was already handled
            # (if the counts ever drifted apart, an end with nothing printing resyncs them)
            self._start_events = self._prints_begun
            self.queue.print_ended()
            self.files.set_paused(False)
            self._finish_demo(event == Events.PRINT_DONE)

    def _query_firmware_compensation(self, payload) -> None:
        """After the M115 reply: a Marlin firmware is asked for its settings (M503), whose
        M852/M425 lines tell whether it compensates skew or backlash itself."""
        name = str(payload.get("name") or "")
        if "marlin" not in name.lower():
            return
        try:
            self._printer.commands(["M503"], tags={"plugin:kincomp", "kincomp:firmware-check"})
        except Exception:  # noqa: BLE001 - a check, not a necessity
            self._logger.exception("KinComp: could not ask the firmware for its settings")

    def _printing_now(self) -> bool:
        """A print is under way (printing, pausing or paused)."""
        try:
            p = self._printer
            return bool(p.is_printing() or p.is_pausing() or p.is_paused())
        except Exception:  # noqa: BLE001 - no printer state: trust the counts
            return True

    def _is_precompensated(self, payload) -> bool:
        if payload.get("origin") != FileDestinations.LOCAL or not payload.get("path"):
            return False
        try:
            disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, payload["path"])
            h = file_marker(disk)
        except Exception:  # noqa: BLE001 - unreadable: treat as not compensated
            return False
        if h is not None and h != self.queue.params.hash():
            self._notify("warning", N_(
                "This file was compensated with other KinComp parameters (%(old)s, now "
                "%(new)s); it prints as compensated then."), old=h,
                new=self.queue.params.hash())
        return h is not None

    # ~~ compensation errors and firmware conflicts -------------------------------------------
    def _on_compensation_error(self, cmd: str, exc: Exception) -> None:
        passed = self.queue.pass_through_on_error
        self._logger.error("KinComp could not compensate %r: %s (%s)", cmd, exc,
                           "sent as written" if passed else "not sent")
        if passed:
            self._notify("warning", N_("KinComp could not compensate '%(cmd)s' (%(err)s); it "
                                       "was sent as written."), cmd=cmd, err=str(exc))
            return
        if self._printer.is_printing():
            self._printer.pause_print(tags={"plugin:kincomp"})
            self._notify("error", N_("KinComp could not compensate '%(cmd)s': %(err)s. The "
                                     "command was not sent and the print is paused; moves "
                                     "queued until the pause are held back too. Cancel the "
                                     "print, or resume to continue without them."),
                         cmd=cmd, err=str(exc))
        else:
            self._notify("error", N_("KinComp could not compensate '%(cmd)s': %(err)s. The "
                                     "command was not sent."), cmd=cmd, err=str(exc))

    def _check_conflicts(self) -> None:
        if self.queue is None or not self.queue.enabled:
            return
        conflicts = self.watch.conflicts(self.queue.params)
        for kind, where in conflicts.items():
            if self._warned_conflicts.get(kind) != where:
                self._warned_conflicts[kind] = where
                self._logger.warning("Double compensation: firmware %s active (%s)", kind, where)
                self._notify("warning", N_(
                    "The firmware compensates %(kind)s too (%(where)s): with KinComp on, it is "
                    "corrected twice. Turn one of them off."), tr_params=("kind",),
                    kind=CONFLICT_NAMES[kind], where=where)

    # ~~ notifications -----------------------------------------------------------------------
    def _notify(self, severity: str, msgid: str, tr_params=(), **params) -> None:
        """Tell the UI. Sent as the English message id plus its parameters: this can run
        on any thread (no request, so no server-side locale); the browser translates it,
        and the parameters named in ``tr_params`` (message ids themselves) and the core
        messages among the parameters (as template + parameters) too."""
        self._plugin_manager.send_plugin_message(self._identifier, {
            "type": "notify", "severity": severity, "msgid": msgid,
            "params": {k: as_dict(v) if isinstance(v, Msg) else v for k, v in params.items()},
            "translate": list(tr_params), "text": msgid % params if params else msgid})

    def _event(self, name: str, payload: Dict[str, Any]) -> None:
        self._event_bus.fire(f"plugin_{self._identifier}_{name}", payload)

    def _job_changed(self, job: Job) -> None:
        self._plugin_manager.send_plugin_message(self._identifier,
                                                 {"type": "job", "job": job.to_dict()})

    # ~~ background file compensation ---------------------------------------------------------
    def _maybe_background(self, payload) -> None:
        s = self._current_settings()
        path = payload.get("path")
        if (not s["enabled"] or s["mode"] != "background" or not path
                or payload.get("storage") != FileDestinations.LOCAL
                or not valid_file_type(path, type="gcode")):
            return
        disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        if file_marker(disk) is not None:
            return
        self.files.submit(path)

    def _run_file_job(self, job: Job, progress) -> None:
        s = self._current_settings()
        params, options = engine_config(s, self._limits())
        src = self._file_manager.path_on_disk(FileDestinations.LOCAL, job.path)
        total = max(1, os.path.getsize(src))
        root, ext = os.path.splitext(job.path)
        dest = f"{root}.kincomp{ext or '.gcode'}"
        tmp = os.path.join(self.get_plugin_data_folder(), "job.tmp")
        report = compensate_file(src, tmp, params, options,
                                 progress=lambda done: progress(min(1.0, done / total)))
        self._file_manager.add_file(
            FileDestinations.LOCAL, dest,
            DiskFileWrapper(os.path.basename(dest), tmp, move=True), allow_overwrite=True)
        self._file_manager.set_additional_metadata(
            FileDestinations.LOCAL, dest, "kincomp",
            {"params_hash": params.hash(), "source": job.path}, overwrite=True)
        job.result = dest
        job.report = report.to_dict()

    # ~~ API ---------------------------------------------------------------------------------
    def is_blueprint_protected(self):
        return True

    def is_blueprint_csrf_protected(self):
        return True

    @octoprint.plugin.BlueprintPlugin.route("/status", methods=["GET"])
    def api_status(self):
        _require(Permissions.STATUS)
        s = self._current_settings()
        params = Params.from_dict(s["params"])
        return flask.jsonify(
            version=__version__,
            settings=s,
            params_hash=params.hash(),
            engine=engine(),
            compensation=self.queue.status(),
            firmware={"skew": self.watch.skew, "backlash": self.watch.backlash,
                      "conflicts": self.watch.conflicts(params)},
            equivalents=_with_i18n(equivalents(params)),
            demo=self.demo is not None,
            limits=self._limits(),
            max_feeds=self._max_feeds(),
            jobs=[j.to_dict() for j in self.files.jobs.values()],
            settings_problem=(_tr(self._settings_problem)
                              if self._settings_problem is not None else None),
        )

    @octoprint.plugin.BlueprintPlugin.route("/settings", methods=["POST"])
    def api_settings(self):
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = _json_object()
        if data is None:
            return _error(gettext("Expected a JSON object"), 400)
        try:
            immediately = _flag(data, "apply_now")
        except _BadRequest as exc:
            return _error(str(exc), 400)
        data.pop("apply_now", None)
        try:
            new = validate_settings(data, self._current_settings())
        except SettingsError as exc:
            return _error(_tr(exc), 400)
        self._save_settings(new, immediately=immediately or None)
        self._settings.save()
        self._settings_problem = None  # valid settings are stored now
        return flask.jsonify(settings=new, params_hash=Params.from_dict(new["params"]).hash(),
                             compensation=self.queue.status())

    def _max_feeds(self):
        try:
            return max_feeds_from_profile(self._printer_profile_manager.get_current_or_default())
        except Exception:  # noqa: BLE001
            return None

    @octoprint.plugin.BlueprintPlugin.route("/program", methods=["POST"])
    def api_program(self):
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = _json_object() or {}
        try:
            do_print, mount_pause = _flag(data, "print"), _flag(data, "mount_pause")
        except _BadRequest as exc:
            return _error(str(exc), 400)
        if do_print:
            _require(Permissions.PRINT)
        try:
            plane = str(data.get("plane", "XY")).upper()
            feed = float(data.get("feed", 1850.0))
            spec = TestSpec(
                plane=plane,
                centre=tuple(float(v) for v in data.get("centre", (110, 110, 10))),
                radius_mm=float(data.get("radius", 100.0)),
                feed_mm_min=cap_feed(feed, plane, self._max_feeds()),
                requested_feed_mm_min=feed,
                mount_pause=mount_pause,
            )
            params = self.queue.params
            text = generate(spec, volume=self._limits(), params_hash=params.hash())
        except (ProgramError, TypeError, ValueError) as exc:
            return _error(_tr(exc), 400)
        name = f"ballbar_{spec.plane}_R{spec.radius_mm:g}_" \
               f"{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}.gcode"
        path = f"{PROGRAM_FOLDER}/{name}"
        self._file_manager.add_folder(FileDestinations.LOCAL, PROGRAM_FOLDER,
                                      ignore_existing=True)
        self._file_manager.add_file(
            FileDestinations.LOCAL, path,
            StreamWrapper(name, io.BytesIO(text.encode())), allow_overwrite=True)
        from ..ballbar.program import spec_from_program

        _, prog_hash = spec_from_program(text)
        with self._lock:
            self._program_path = path
            self._program_spec = spec
            self._program_hash = prog_hash
        printing = False
        if do_print:
            if not self._printer.is_operational() or self._printer.is_printing():
                return _error(gettext("The printer is not ready to print"), 409)
            self._printer.select_file(path, False, printAfterSelect=True,
                                      tags={"plugin:kincomp", "kincomp:calibration"})
            printing = True
        return flask.jsonify(path=path, spec=spec_dict(spec), lines=text.count("\n"),
                             printing=printing, program_hash=prog_hash)

    def _start_demo_recording(self, payload) -> None:
        demo = self.demo
        if demo is None:
            return
        with self._lock:
            if payload.get("path") != self._program_path or self._program_spec is None:
                return
            demo.start(self._program_spec, self._program_hash)

    def _finish_demo(self, done: bool) -> None:
        demo = self.demo
        if demo is None or not demo.recording:
            return
        if not done:
            demo.cancel()
            return
        threading.Thread(target=self._simulate_demo, args=(demo,), name="kincomp-demo",
                         daemon=True).start()

    def _simulate_demo(self, demo: DemoBallbar) -> None:
        """Runs the simulator (seconds) on its own thread, not on OctoPrint's event thread."""
        try:
            trace = demo.finish()
        except Exception:  # noqa: BLE001 - a demo failure must not disturb anything else
            self._logger.exception("KinComp demo: simulation failed")
            return
        if trace is not None:
            self._notify("success", N_(
                "SIMULATED ballbar trace ready (demo mode): load it in the calibration tab."))
            self._plugin_manager.send_plugin_message(self._identifier, {"type": "demo_trace"})

    @octoprint.plugin.BlueprintPlugin.route("/demo/trace", methods=["GET"])
    def api_demo_trace(self):
        _require(Permissions.STATUS)
        if self.demo is None or self.demo.last_trace is None:
            return _error(gettext("No simulated trace yet: print a ballbar program in demo "
                                  "mode first"), 404)
        text = self.demo.last_trace.to_text()
        resp = flask.make_response(text)
        resp.headers["Content-Type"] = "text/csv; charset=utf-8"
        resp.headers["Content-Disposition"] = 'attachment; filename="simulated_trace.csv"'
        return resp

    @octoprint.plugin.BlueprintPlugin.route("/trace", methods=["POST"])
    def api_trace(self):
        """Upload a trace, .b5r or summary file (multipart field 'file'), analyse it and
        store the run; nothing is applied."""
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        suffix = self._settings.global_get(["server", "uploads", "pathSuffix"]) or "path"
        name_suffix = self._settings.global_get(["server", "uploads", "nameSuffix"]) or "name"
        tmp_path = flask.request.values.get("file." + suffix)
        filename = flask.request.values.get("file." + name_suffix, "trace")
        if tmp_path:
            size = os.path.getsize(tmp_path)
            if size > MAX_TRACE_UPLOAD:
                return _error(gettext("The file is too large"), 413)
            with open(tmp_path, "rb") as f:
                data = f.read()
        else:
            data = flask.request.get_data(cache=False)
            if not data:
                return _error(gettext("No file uploaded (multipart field 'file')"), 400)
            if len(data) > MAX_TRACE_UPLOAD:
                return _error(gettext("The file is too large"), 413)
        return self._analyse_and_store(data, filename, "upload")

    @octoprint.plugin.BlueprintPlugin.route("/analyze", methods=["POST"])
    def api_analyze(self):
        """Analyse typed numbers: {"summary": {...}} or {"artifact": {...}}."""
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = _json_object()
        if data is None:
            return _error(gettext("Expected a JSON object"), 400)
        if "summary" in data:
            return self._analyse_and_store(json.dumps(data["summary"]).encode(),
                                           "typed summary", "summary")
        if "artifact" in data:
            a = data["artifact"]
            if not isinstance(a, dict):
                return _error(gettext("Expected a JSON object"), 400)
            try:
                diag = diagnostics_from_artifact(
                    str(a.get("plane", "XY")), float(a["ac"]), float(a["bd"]), float(a["ad"]),
                    {k: [(float(n), float(m)) for n, m in v]
                     for k, v in (a.get("lengths") or {}).items()})
            except (ArtifactError, KeyError, TypeError, ValueError) as exc:
                return _error(gettext("Invalid artifact measurements: %(e)s", e=_tr(exc)),
                              400)
            from ..ballbar.analysis import Geometry, propose_params

            notes = []
            current = self.queue.params
            params = propose_params(diag, Geometry(diag["plane"], 0.0, None, None), current,
                                    notes)
            return self._store_run({"diagnostics": diag, "parameters": params.to_dict(),
                                    "firmware": equivalents(params), "notes": notes},
                                   "printed artifact", "artifact", None)
        return _error(gettext("Give 'summary' or 'artifact'"), 400)

    def _analyse_and_store(self, data: bytes, filename: str, source: str):
        safe = _SAFE_NAME.sub("_", os.path.basename(str(filename)))[:100] or "trace"
        try:
            trace = load_any(data, safe)
            result = analyse(trace, current=self.queue.params)
        except TraceError as exc:
            return _error(gettext("%(name)s: %(reason)s", name=safe, reason=_tr(exc)), 400)
        kind = getattr(trace, "kind", source)
        return self._store_run(result, safe, kind, data if kind != "summary" else None,
                               result.get("plot"))

    def _store_run(self, result, filename, source, raw: Optional[bytes], plot=None):
        run_id = self.runs.new_id()
        current = self.queue.params
        run = {
            "id": run_id,
            "date": _dt.datetime.now().isoformat(timespec="seconds"),
            "filename": filename,
            "source": source,
            "simulated": bool(result["diagnostics"].get("simulated")),
            "params_before": current.to_dict(),
            "params_before_hash": current.hash(),
            "diagnostics": result["diagnostics"],
            "proposed": result["parameters"],
            "firmware": _with_i18n(result["firmware"]),
            "notes": [str(n) for n in result["notes"]],
            "notes_i18n": [as_dict(n) for n in result["notes"]],
            "plot": plot,
            "applied": None,
        }
        if raw is not None:
            self.runs.save_trace(run_id, raw)
        self.runs.save(run)
        self._event("calibration_analysed", {"run": run_id, "source": source,
                                             "simulated": run["simulated"]})
        return flask.jsonify(run)

    @octoprint.plugin.BlueprintPlugin.route("/apply", methods=["POST"])
    def api_apply(self):
        """Apply a run's proposed parameters ({"run": id}) or given ones ({"params": {...}})."""
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = _json_object() or {}
        try:
            apply_now = _flag(data, "apply_now")
        except _BadRequest as exc:
            return _error(str(exc), 400)
        run = None
        if "run" in data:
            try:
                run = self.runs.get(str(data["run"]))
            except RunNotFound:
                return _error(gettext("No such calibration run"), 404)
            params_doc = run["proposed"]
        elif "params" in data:
            params_doc = data["params"]
        else:
            return _error(gettext("Give 'run' or 'params'"), 400)
        new = dict(self._current_settings())
        new["params"] = params_doc
        if "enabled" in data:
            new["enabled"] = data["enabled"]
        try:
            new = validate_settings(new, self._current_settings(), replace_params=True)
        except SettingsError as exc:
            return _error(_tr(exc), 400)
        self._save_settings(new, immediately=apply_now or None)
        self._settings.save()
        if run is not None:
            run["applied"] = _dt.datetime.now().isoformat(timespec="seconds")
            self.runs.save(run)
        return flask.jsonify(params=new["params"],
                             params_hash=Params.from_dict(new["params"]).hash(),
                             compensation=self.queue.status())

    @octoprint.plugin.BlueprintPlugin.route("/runs", methods=["GET"])
    def api_runs(self):
        _require(Permissions.STATUS)
        return flask.jsonify(runs=self.runs.list())

    @octoprint.plugin.BlueprintPlugin.route("/runs/<run_id>", methods=["GET"])
    def api_run(self, run_id):
        _require(Permissions.STATUS)
        try:
            return flask.jsonify(self.runs.get(run_id))
        except RunNotFound:
            return _error(gettext("No such calibration run"), 404)

    @octoprint.plugin.BlueprintPlugin.route("/runs/<run_id>/trace", methods=["GET"])
    def api_run_trace(self, run_id):
        """The measurement file of a run as it was uploaded (trace, .b5r)."""
        _require(Permissions.STATUS)
        try:
            run = self.runs.get(run_id)
        except RunNotFound:
            return _error(gettext("No such calibration run"), 404)
        path = self.runs.trace_path(run_id)
        if path is None:
            return _error(gettext("This run has no stored measurement file"), 404)
        name = _SAFE_NAME.sub("_", str(run.get("filename") or "trace"))[:100] or "trace"
        return flask.send_file(path, mimetype="application/octet-stream", as_attachment=True,
                               download_name=name)

    @octoprint.plugin.BlueprintPlugin.route("/compare", methods=["GET"])
    def api_compare(self):
        _require(Permissions.STATUS)
        from ..ballbar.closedloop import table

        try:
            a = self.runs.get(flask.request.args.get("before", ""))
            b = self.runs.get(flask.request.args.get("after", ""))
        except RunNotFound:
            return _error(gettext("No such calibration run"), 404)
        return flask.jsonify(table=table(a["diagnostics"], b["diagnostics"]),
                             before=a["id"], after=b["id"])

    def _local_file(self, path: str) -> Optional[str]:
        if not isinstance(path, str) or not path or not valid_file_type(path, type="gcode"):
            return None
        try:
            if not self._file_manager.file_exists(FileDestinations.LOCAL, path):
                return None
            return self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        except ValueError:  # the storage refuses paths outside its folder
            return None

    @octoprint.plugin.BlueprintPlugin.route("/dryrun", methods=["GET"])
    def api_dryrun(self):
        _require(Permissions.STATUS)
        _require(Permissions.FILES_LIST)
        disk = self._local_file(flask.request.args.get("path", ""))
        if disk is None:
            return _error(gettext("No such G-code file"), 404)
        s = self._current_settings()
        params, options = engine_config(s, self._limits())
        try:
            report = compensate_file(disk, None, params, options, dry_run=True)
        except AlreadyCompensated as exc:
            return flask.jsonify(precompensated=exc.params_hash, report=None)
        return flask.jsonify(precompensated=None, params_hash=params.hash(),
                             report=report.to_dict())

    @octoprint.plugin.BlueprintPlugin.route("/compensate", methods=["POST"])
    def api_compensate(self):
        _require(Permissions.PLUGIN_KINCOMP_ADMIN)
        _require(Permissions.FILES_UPLOAD)
        data = _json_object() or {}
        path = data.get("path", "")
        disk = self._local_file(path)
        if disk is None:
            return _error(gettext("No such G-code file"), 404)
        if file_marker(disk) is not None:
            return _error(gettext("This file is already compensated"), 409)
        job = self.files.submit(path)
        return flask.jsonify(job=job.to_dict())

    @octoprint.plugin.BlueprintPlugin.route("/files", methods=["GET"])
    def api_files(self):
        """Local G-code files with the parameter hash they were compensated with (if any)."""
        _require(Permissions.FILES_LIST)
        out = []
        current = self.queue.params.hash()

        def walk(node, prefix=""):
            for name, entry in (node or {}).items():
                if entry.get("type") == "folder":
                    walk(entry.get("children"), entry.get("path", name) + "/")
                elif entry.get("type") == "machinecode":
                    path = entry.get("path") or prefix + name
                    try:
                        h = file_marker(self._file_manager.path_on_disk(
                            FileDestinations.LOCAL, path))
                    except Exception:  # noqa: BLE001
                        h = None
                    out.append({"path": path, "params_hash": h,
                                "outdated": h is not None and h != current})

        walk(self._file_manager.list_files(FileDestinations.LOCAL, recursive=True)
             .get(FileDestinations.LOCAL))
        return flask.jsonify(files=out, params_hash=current)


def plugin_hooks(plugin: KinCompPlugin) -> Dict[str, Any]:
    return {
        # run last in queuing so other plugins' rewrites get compensated too
        "octoprint.comm.protocol.gcode.queuing": (plugin.queuing_hook, 10000),
        "octoprint.comm.protocol.gcode.received": plugin.received_hook,
        "octoprint.filemanager.preprocessor": (plugin.preprocessor_hook, 10000),
        "octoprint.access.permissions": plugin.permissions_hook,
        "octoprint.server.http.bodysize": plugin.bodysize_hook,
        "octoprint.events.register_custom_events": plugin.custom_events_hook,
        "octoprint.server.api.before_request": plugin.before_api_request_hook,
    }
