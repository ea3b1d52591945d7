"""The calibration endpoints: ballbar program, measurement upload and analysis, applying a
proposal, the run history, comparing two runs, and demo mode's simulated trace.

* ``POST /program``  writes a ballbar test program (radius mm, feed mm/min lowered to what the
  printer's motion limits allow, ``plugin/settings/limits_capture.py``; ``feed_lowered`` says why;
  400 when no usable feed is left; centre mm) into OctoPrint's storage, optionally prints it (a live
  sensor, if one is set, is armed first through ``on_print``). The program is for the printer's
  firmware (:meth:`CalibrationApi.firmware`): its pause, and its planner with the stated limits
  recorded in the header for the analysis.
* ``POST /trace``    a trace, .b5r or summary file (multipart field ``file``, at most
  MAX_TRACE_UPLOAD bytes): analysed in the worker process (a background job: the run comes
  in the response if it is ready within TRACE_WAIT_S, else 202 with the job, whose result
  is the run id) and stored as a run; nothing is applied.
* ``POST /analyze``  typed numbers: a ballbar summary or printed-artifact measurements.
* ``POST /apply``    a run's proposed parameters, or given ones, into the settings; an
  untrusted run (an error finding) only with ``"force": true`` (409 naming the error
  without it), and so a run of another printer profile than the one in force (409
  without it; with it the run and the answer carry the warning ``applied.other_profile``);
  a run whose trace is not tied to a program KinComp printed
  (``needs_confirmation``) only with ``"confirm"`` stating its plane, radius and feed
  (and for an angle trace the sensor, for an unrecorded firmware state the firmware's
  compensation: the keys it lists; 409 naming them without it; ``force`` does not replace
  it).
* ``GET /runs``, ``/runs/<id>``, ``/runs/<id>/trace``, ``/compare?before=&after=``,
  ``/demo/trace``.

Every stored run carries ``findings`` (worst first; message and advice translatable) and ``trusted``
(``service/calibration/findings_view.py``). Each method here is one route's body (the plugin class
holds the routes); errors are JSON ``{"error": ...}`` responses in the user's language, 400 naming
the field for bad input. A run whose numbers are not all finite is never stored.
"""

from __future__ import annotations

import datetime as _dt
import io
import json
import os
import re
from typing import Any, Callable, Dict, Optional, Tuple

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions
from octoprint.filemanager import FileDestinations
from octoprint.filemanager.util import StreamWrapper

from ...calibration.ballbar.program import (
    PLANES,
    ProgramError,
    TestSpec,
    check_bounds,
    generate,
    pause_for,
    spec_dict,
    spec_from_program,
)
from ...calibration.ballbar.timing import SentWith
from ...calibration.findings import worst_first
from ...core.kinematics import changes_nothing
from ...core.messages import as_dict
from ...core.params import Params
from ...firmware.compensation import FirmwareCompensation
from ...firmware.motion_limits import LimitsError, circle_feed, describe, firmware_kind
from ...firmware.planner import settings_from_limits
from ...service.calibration.demo_mode import DemoMode
from ...service.calibration.findings_view import findings_of, refusal
from ...service.calibration.known_squareness import known_squareness
from ...service.calibration.measurement import known_as_of
from ...service.calibration.printed_programs import PrintedPrograms, trace_meta
from ...service.calibration.run_store import RunNotFound, RunNotStorable, RunStore
from ...service.notify import Notifier
from ...service.printing.queue import QueueCompensator
from ...service.settings.printer_profiles import applied_elsewhere, other_profile
from ...service.settings.schema import SettingsError
from ...simulator.closed_loop import servo_in_force, table
from .. import http
from ..files.job_api import JobApi
from ..settings.limits_capture import effective_limits
from ..settings.settings_store import ProfileChanged, SettingsStore

MAX_TRACE_UPLOAD = 16 * 1024 * 1024  # bytes, also OctoPrint's body size limit for /trace


def _analysis_wait_s() -> float:
    """Seconds an analysis may take and still come in the response (20; the environment's
    KINCOMP_ANALYSIS_WAIT_S, a number of 1 to 3600, overrides it: the test suite's servers
    wait longer, since a loaded CI machine starves the nice-19 worker and the tests check the
    result, not the user's wait)."""
    try:
        v = float(os.environ.get("KINCOMP_ANALYSIS_WAIT_S", "20"))
    except ValueError:
        return 20.0
    return v if 1.0 <= v <= 3600.0 else 20.0


TRACE_WAIT_S = _analysis_wait_s()  # an analysis done within this many seconds comes in the answer
PROGRAM_FOLDER = "kincomp"  # where generated programs go in OctoPrint's local storage
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


class UploadRefused(Exception):
    """No uploaded file, or one too large: the message and the HTTP status."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.message = message
        self.status = status


def _same(given: Any, stated: Any) -> bool:
    """Whether a confirmed value matches the stated one (numbers within 1e-6, text by case)."""
    if isinstance(stated, (int, float)) and not isinstance(stated, bool):
        try:
            return abs(float(given) - float(stated)) <= 1e-6
        except (TypeError, ValueError):
            return False
    return str(given or "").strip().upper() == str(stated or "").strip().upper()


def _firmware_of(diag: Dict[str, Any]) -> Optional[Dict[str, Any]]:
    """The firmware's compensation a result was measured with (a campaign's or a test's)."""
    camp = diag.get("campaign") if isinstance(diag.get("campaign"), dict) else {}
    return diag.get("firmware_compensation") or camp.get("firmware_compensation")


def safe_name(name: str) -> str:
    """``name`` with only letters, digits, '.', '_' and '-' (others become '_'), at most 100
    characters, "trace" if nothing is left."""
    return _UNSAFE.sub("_", name)[:100] or "trace"


class CalibrationApi:
    def __init__(
        self,
        store: SettingsStore,
        queue: QueueCompensator,
        runs: RunStore,
        demo: DemoMode,
        notifier: Notifier,
        printer,
        file_manager,
        job_api: JobApi,
    ):
        self._store = store
        self._queue = queue
        self._runs = runs
        self._demo = demo
        self._notifier = notifier
        self._printer = printer
        self._file_manager = file_manager
        # on_print(path, spec, program_hash) -> JSON-ready capture state: arms the live
        # sensor just before the program is printed (None: no live capture)
        self.on_print = None
        self._job_api = job_api
        # () -> the firmware's compensation now (FirmwareWatcher.state); the programs printed
        # (PrintedPrograms: what each test ran with; None: not recorded)
        self.firmware_state = FirmwareCompensation
        self.printed: Optional[PrintedPrograms] = None
        # () -> the firmware's name from its M115 answer ("" before it answered)
        self.firmware_name: Callable[[], str] = lambda: ""

    # ~~ the test program ------------------------------------------------------------------------
    @http.route("/program", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def program(self):
        data = http.json_object() or {}
        try:
            do_print, mount_pause = http.flag(data, "print"), http.flag(data, "mount_pause")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        if do_print:
            http.require(Permissions.PRINT)
        try:
            plane = http.choice(data, "plane", tuple(PLANES), "XY")
            feed = http.number(data, "feed", 1850.0)
            limits, firmware = self.motion_limits(), self.firmware()
            planner = settings_from_limits(limits, firmware)
            spec = TestSpec(
                plane=plane,
                centre=tuple(http.numbers(data, "centre", 3, (110.0, 110.0, 10.0))),
                radius_mm=http.number(data, "radius", 100.0),
                feed_mm_min=feed,
                requested_feed_mm_min=feed,
                mount_pause=mount_pause,
                pause_command=pause_for(firmware),
                motion=planner.metadata() if planner is not None else None,
            )
            volume = self._store.limits()
            check_bounds(spec, volume)
            choice = circle_feed(
                spec.plane, spec.radius_mm, feed, limits, overshoot_deg=spec.overshoot_deg
            )
            spec.feed_mm_min = choice.feed_mm_min
            params = self._queue.in_force
            text = generate(
                spec, volume=volume, params_hash=params.hash(), feed_notes=describe(choice)
            )
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except (ProgramError, LimitsError, TypeError, ValueError) as exc:
            return http.error(http.tr(exc), 400)
        if do_print and not self.printer_ready():  # refused before a file is written
            return http.error(gettext("The printer is not ready to print"), 409)
        name = (
            f"ballbar_{spec.plane}_R{spec.radius_mm:g}_"
            f"{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}.gcode"
        )
        path, prog_hash, _ = self.write_program(text, name)
        printing, capture = self.print_program(path, spec, prog_hash) if do_print else (False, None)
        if do_print and not printing:
            return http.error(gettext("The printer is not ready to print"), 409)
        return flask.jsonify(
            path=path,
            spec=spec_dict(spec),
            lines=text.count("\n"),
            printing=printing,
            program_hash=prog_hash,
            capture=capture,
            feed_lowered=[as_dict(r) for r in choice.reasons],
        )

    def test_printing(self) -> bool:
        """Whether one of KinComp's test programs (its program folder) is printing."""
        try:
            if not self._printer.is_printing():
                return False
            job = self._printer.get_current_job() or {}
            path = str((job.get("file") or {}).get("path") or "")
        except Exception:
            return False
        return path.startswith(PROGRAM_FOLDER + "/")

    def motion_limits(self):
        """The limits a test must respect now (stated limits and the printer profile)."""
        return effective_limits(self._store.current(), self._store.max_feeds())

    def firmware(self) -> Optional[str]:
        """The printer's firmware (``marlin``, ``klipper``, ``reprapfirmware``; None: not
        known): what its M115 answer names, else what its stated motion limits show (a
        pasted printer.cfg is Klipper's)."""
        return firmware_kind(self.firmware_name()) or self.motion_limits().firmware

    def store_program(self, text: str, name: str) -> str:
        """Writes the G-code ``text`` as ``kincomp/<name>`` into OctoPrint's storage (the
        folder made if missing, a file of that name replaced); returns its path."""
        path = f"{PROGRAM_FOLDER}/{name}"
        self._file_manager.add_folder(FileDestinations.LOCAL, PROGRAM_FOLDER, ignore_existing=True)
        self._file_manager.add_file(
            FileDestinations.LOCAL,
            path,
            StreamWrapper(name, io.BytesIO(text.encode())),
            allow_overwrite=True,
        )
        return path

    def write_program(self, text: str, name: str) -> Tuple[str, str, TestSpec]:
        """Writes the ballbar program ``text`` as ``kincomp/<name>`` (:meth:`store_program`)
        and tells demo mode, with the test as the program states it (its params hash and
        campaign keys go into the simulated trace); returns the path, the program hash and
        that test."""
        path = self.store_program(text, name)
        stated, prog_hash = spec_from_program(text)
        self._demo.program_written(path, stated, prog_hash)
        return path, prog_hash, stated

    def printer_ready(self) -> bool:
        """Whether a program can be started now (connected, not printing)."""
        return self._printer.is_operational() and not self._printer.is_printing()

    def job_path(self) -> Optional[str]:
        """The path of the file printing now (also paused or pausing); None when none is."""
        p = self._printer
        if not (p.is_printing() or p.is_paused() or p.is_pausing()):
            return None
        job = p.get_current_job() or {}
        path = (job.get("file") or {}).get("path") if isinstance(job, dict) else None
        return path if isinstance(path, str) and path else None

    def start_print(self, path: str) -> None:
        """Selects the stored file ``path`` and prints it, tagged as KinComp's."""
        self._printer.select_file(
            path, False, printAfterSelect=True, tags={"plugin:kincomp", "kincomp:calibration"}
        )

    def print_program(
        self, path: str, spec: TestSpec, prog_hash: str, arm: bool = True
    ) -> Tuple[bool, Optional[Dict[str, Any]]]:
        """Prints the program at ``path`` (the test ``spec``); a live sensor, if one is in
        use (and ``arm``), is armed first through ``on_print``. (printing, the capture's
        state); (False, None) if the printer is not ready (not connected, or printing)."""
        if not self.printer_ready():
            return False, None
        if self.printed is not None:
            sent = self.sent_now()
            self.printed.record(
                prog_hash,
                spec.metadata(),
                self.firmware_state().to_dict(),
                sent.metadata() if sent is not None else None,
                self._queue.in_force.hash(),
            )
        capture = (
            self.on_print(path, spec, prog_hash) if arm and self.on_print is not None else None
        )
        self.start_print(path)
        return True, capture

    # ~~ what a test ran with ----------------------------------------------------------------
    def sent_now(self) -> Optional[SentWith]:
        """How the queue compensates a program now (None: it does not)."""
        if changes_nothing(self._queue.in_force):
            return None
        return SentWith.of_options(self._queue.comp.options)

    def origin_for(self, meta: Dict[str, str], captured: bool = False) -> Dict[str, Any]:
        """What KinComp knows of the test a trace with ``meta`` comes from, as JSON (the
        worker's arguments): ``firmware`` (the firmware's compensation during it), ``confirmed``
        (``"capture"``: captured while KinComp printed it; ``"printed"``: its program_hash is
        one KinComp printed; None: neither) and ``sent`` (how its program was compensated:
        that print's, else the queue's now)."""
        rec = self.printed.get(meta.get("program_hash")) if self.printed is not None else None
        sent = self.sent_now()
        out: Dict[str, Any] = {
            "firmware": rec.get("firmware") if rec else None,
            "confirmed": "capture" if captured else ("printed" if rec else None),
            "sent": (rec.get("sent") if rec else None)
            or (sent.metadata() if sent is not None else None),
        }
        if captured and out["firmware"] is None:
            out["firmware"] = self.firmware_state().to_dict()
        return out

    # ~~ measurements in ---------------------------------------------------------------------
    @http.route("/trace", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def trace(self):
        """Upload a trace, .b5r or summary file (multipart field 'file'), analyse it (in the
        worker process) and store the run; nothing is applied."""
        try:
            data, filename = self.read_upload()
        except UploadRefused as exc:
            return http.error(exc.message, exc.status)
        return self.analyse_file(data, filename)

    def analyse_file(self, data: bytes, filename: str, source: Optional[str] = None):
        """A trace, .b5r or summary file (``data``) analysed in the worker and stored as a
        run (``source``: its kind when the file does not say it, else "upload")."""
        safe = safe_name(os.path.basename(str(filename)))
        known = self.known_now()
        args = {"data": data, "name": safe, "current": known["current"], "known": known["known"]}
        args["origin"] = self.origin_for(trace_meta(data))

        def store(result) -> str:
            kind = result.pop("kind", None) or source or "upload"
            raw = data if kind != "summary" else None
            extra = {"profile": known["profile"]}
            return self.record_run(result, safe, kind, raw, result.get("plot"), extra)["id"]

        return self.analysis("analyse", args, store, lambda run_id: self._runs.get(run_id), safe)

    # ~~ THE analysis entry point ------------------------------------------------------------
    def analyse_in_worker(self, task: str, args: Dict[str, Any]) -> Dict[str, Any]:
        """``task`` on ``args`` in the worker process, for a thread that is no request (the
        live capture's): a job of KinComp's own (an admin's place), waited for; its result,
        or its exception raised here."""
        out: Dict[str, Any] = {}

        def run(job, progress) -> None:
            out["result"] = self._job_api.jobs.worker.call(job.id, task, args, progress)

        job = self._job_api.jobs.submit("analyse", None, run, owner=None, admin=True)
        job.done.wait()
        if job.state != "done":
            raise job.exception or RuntimeError(str(job.error))
        return out["result"]

    def known_now(self) -> Dict[str, Any]:
        """What every analysis takes from the plugin, taken as the measurement starts (the
        parameters in force, the known squareness, the printer profile id it belongs to:
        ``service/calibration/measurement.known_as_of``)."""
        s = self._store.current()
        return known_as_of(self._queue.in_force, self.known_squareness(), s["profile"] or None)

    def analysis(
        self,
        task: str,
        args: Dict[str, Any],
        store: Callable[[Dict[str, Any]], Any],
        body: Callable[[Any], Dict[str, Any]],
        name: str,
    ):
        """The one way a request analyses a measurement: ``task`` (a worker task of
        ``service/calibration/measurement.py``) on ``args`` in the low-priority worker
        process, as a job under the job queue's fairness rules (quotas, 429); ``store``
        records its result (its return is the job's result), ``body(job result)`` is the
        answer. 200 when done within TRACE_WAIT_S, else 202 with the job; 400 naming
        ``name`` when it failed (507 on a full disk)."""

        def run(job, progress) -> None:
            result = self._job_api.jobs.worker.call(job.id, task, args, progress)
            job.result = store(result)

        return self.answer_job(self._job_api.submit("analyse", None, run), body, name)

    def answer_job(self, job, body: Callable[[Any], Dict[str, Any]], name: Optional[str]):
        """The answer to a request whose analysis is ``job`` (see :meth:`analysis`); a
        failure names the file ``name`` (None: its message names what failed)."""

        def failed(j) -> str:
            exc = j.exception or j.error
            if name is None:
                return http.tr(exc) if isinstance(exc, BaseException) else str(exc)
            return self._analysis_failed(name, exc)

        return self._job_api.answer(job, lambda j: body(j.result), wait=TRACE_WAIT_S, failed=failed)

    def read_upload(self) -> Tuple[bytes, str]:
        """The uploaded file (multipart field 'file', or the raw body) and its name; raises
        UploadRefused when there is none or it is over MAX_TRACE_UPLOAD bytes, and the OSError
        KinComp's upload handler met writing its temporary file (a full disk: 507)."""
        failed = http.upload_failed(flask.request.headers)  # (the upload handler's)
        if failed is not None:
            raise failed  # a full disk: 507
        suffix, name_suffix = self._store.upload_fields()
        tmp_path = flask.request.values.get("file." + suffix)
        filename = flask.request.values.get("file." + name_suffix, "trace")
        if tmp_path:
            size = os.path.getsize(tmp_path)
            if size > MAX_TRACE_UPLOAD:
                raise UploadRefused(gettext("The file is too large"), 413)
            with open(tmp_path, "rb") as f:
                data = f.read()
        else:
            data = flask.request.get_data(cache=False)
            if not data:
                raise UploadRefused(gettext("No file uploaded (multipart field 'file')"), 400)
            if len(data) > MAX_TRACE_UPLOAD:
                raise UploadRefused(gettext("The file is too large"), 413)
        return data, filename

    @http.route("/analyze", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def analyze(self):
        """Analyse a ballbar report's typed numbers: {"summary": {...}}."""
        data = http.json_object()
        if data is None:
            return http.error(gettext("Expected a JSON object"), 400)
        if "summary" in data:
            if not isinstance(data["summary"], dict):
                return http.error(gettext("'%(key)s' must be an object", key="summary"), 400)
            return self.analyse_file(
                json.dumps(data["summary"]).encode(), "typed summary", "summary"
            )
        if "artifact" in data:  # (printed parts are measured at /artifact/analyze)
            return http.error(
                gettext("A printed square's measurements go to /artifact/analyze as 'square'"),
                400,
            )
        return http.error(gettext("Give 'summary'"), 400)

    def _analysis_failed(self, name: str, exc) -> str:
        return gettext(
            "%(name)s: %(reason)s",
            name=name,
            reason=http.tr(exc) if isinstance(exc, BaseException) else str(exc),
        )

    def store_run(
        self, result: Dict[str, Any], filename: str, source: str, raw: Optional[bytes], plot=None
    ):
        """The response to a request whose analysis ``result`` is stored as a run: the run,
        or 400 when it holds a number that is not finite (nothing stored)."""
        try:
            return flask.jsonify(self.record_run(result, filename, source, raw, plot))
        except RunNotStorable:
            return http.error(
                gettext(
                    "The analysis gave numbers that are not finite; check "
                    "the measurements (nothing was stored)"
                ),
                400,
            )

    def record_run(
        self,
        result: Dict[str, Any],
        filename: str,
        source: str,
        raw: Optional[bytes],
        plot=None,
        extra: Optional[Dict[str, Any]] = None,
    ) -> Dict[str, Any]:
        """Store an analysis as a run (and ``raw``, the measurement file, next to it;
        ``extra``: more fields, e.g. a campaign's keys) and announce it; returns the run.
        Raises :class:`RunNotStorable` (nothing stored) if a number is not finite. Needs
        no request: the worker and the live capture's thread store their runs here too."""
        run_id = self._runs.new_id()
        current = self._queue.in_force
        findings, trusted = findings_of(result)
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
            "firmware": http.with_i18n(result["firmware"]),
            "notes": [str(n) for n in result["notes"]],
            "notes_i18n": [as_dict(n) for n in result["notes"]],
            "findings": findings,
            "trusted": trusted,
            "plot": plot,
            "applied": None,
            # what the test ran with (firmware/compensation.py) and what to confirm first
            "firmware_compensation": _firmware_of(result["diagnostics"]),
            "needs_confirmation": result.get("needs_confirmation"),
        }
        run.update(extra or {})
        self._runs.save(run, raw)
        self._notifier.event(
            "calibration_analysed", {"run": run_id, "source": source, "simulated": run["simulated"]}
        )
        return run

    # ~~ applying a proposal -----------------------------------------------------------------
    @http.route("/apply", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def apply(self):
        """Apply a run's proposed parameters ({"run": id}) or given ones ({"params": {...}})."""
        data = http.json_object() or {}
        try:
            apply_now, force = http.flag(data, "apply_now"), http.flag(data, "force")
            expected = http.expected_profile(data)
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        run = None
        if "run" in data:
            try:
                run = self._runs.get(str(data["run"]))
            except RunNotFound:
                return http.error(gettext("No such calibration run"), 404)
            params_doc = run.get("proposed")
            if params_doc is None:
                return http.error(
                    gettext("This run has no proposed parameters (its capture failed)"), 400
                )
            refused = (
                self.other_printers(run, force=force)
                or self.untrusted(run, force)
                or self.unconfirmed(run, data.get("confirm"))
            )
            if refused is not None:
                return refused
        elif "params" in data:
            if not isinstance(data["params"], dict):
                return http.error(gettext("'%(key)s' must be an object", key="params"), 400)
            params_doc = data["params"]
        else:
            return http.error(gettext("Give 'run' or 'params'"), 400)
        return self.apply_params(
            params_doc,
            apply_now,
            run,
            {"enabled": data["enabled"]} if "enabled" in data else None,
            expected,
        )

    def other_printers(self, run: Dict[str, Any], what: Optional[str] = None, force=False):
        """409 when ``run`` (or a campaign: ``what`` names it) was recorded for another
        printer profile than the one in force (a stale page or another user's switch:
        printer A's result is not applied to printer B unless the request says ``force``,
        e.g. one printer set up under two profiles; :meth:`apply_params` then records the
        warning ``applied.other_profile``); None to go on. A run belongs to the profile in
        force when its measurement started (``known_now``), whatever is switched during
        its analysis."""
        s = self._store.current()
        if force or not other_profile(run.get("profile"), s):
            return None
        return http.error(
            gettext(
                "%(what)s belongs to printer profile %(run)s, but %(current)s "
                "is in force: connect that printer to apply it (or apply it anyway: "
                '"force": true).',
                what=what or gettext("This run"),
                run=run.get("profile") or s["legacy_profile"],
                current=s["profile"],
            ),
            409,
        )

    @staticmethod
    def untrusted(run: Dict[str, Any], force: bool):
        """409 naming the first error finding when ``run`` is not trusted and the request
        does not say ``"force": true`` (apply anyway); None to go on."""
        reason = refusal(run)
        if reason is None or force:
            return None
        return http.error(http.tr(reason), 409)

    @staticmethod
    def unconfirmed(run: Dict[str, Any], confirm: Any):
        """409 naming what to confirm when ``run`` needs a confirmation
        (``needs_confirmation``) and ``confirm`` (the request's) does not state those values:
        ``{"plane": "XY", "radius_mm": 100, "feed_mm_min": 1850}`` (the keys the run asks
        for); None to go on."""
        need = run.get("needs_confirmation")
        if not need:
            return None
        stated = need.get("stated") or {}
        keys = list(need.get("confirm") or [])
        if isinstance(confirm, dict) and all(_same(confirm.get(k), stated.get(k)) for k in keys):
            return None
        what = ", ".join(f"{k} {stated.get(k)}" for k in keys)
        return http.error(
            gettext(
                "This result comes from a trace that KinComp cannot tie to a program it printed; "
                "confirm that the test ran as its metadata says (%(what)s) to apply it.",
                what=what,
            ),
            409,
        )

    def apply_params(
        self,
        params_doc,
        apply_now: bool,
        run: Optional[Dict[str, Any]] = None,
        settings: Optional[Dict[str, Any]] = None,
        expected_profile: Optional[str] = None,
    ):
        """Saves ``params_doc`` (and ``settings``, e.g. enabled) as the parameters, validated
        whole (400 naming the field, nothing saved); marks ``run`` applied. 409, nothing
        saved, when ``expected_profile`` is given and another profile's set is in force."""
        new = {"params": params_doc}
        new.update(settings or {})
        try:
            new, _ = self._store.update(
                new,
                replace_params=True,
                immediately=apply_now or None,
                expected_profile=expected_profile,
            )
        except ProfileChanged as exc:
            return http.profile_changed(exc, self._store.profile_names())
        except SettingsError as exc:
            return http.error(http.tr(exc), 400)
        findings = []
        if run is not None:
            s = self._store.current()
            if other_profile(run.get("profile"), s):  # applied anyway (force)
                findings = [applied_elsewhere(run.get("profile"), s, self._store.profile_names())]
                kept = [
                    f for f in run.get("findings") or [] if f.get("code") != findings[0]["code"]
                ]
                run["findings"] = worst_first(kept + findings)
                run["applied_profile"] = s["profile"]
            run["applied"] = _dt.datetime.now().isoformat(timespec="seconds")
            self._runs.save(run)
        return flask.jsonify(
            params=new["params"],
            params_hash=Params.from_dict(new["params"]).hash(),
            compensation=self._queue.status(),
            findings=findings,
        )

    # ~~ the run history -----------------------------------------------------------------------
    def known_squareness(self) -> Dict[str, Any]:
        """The printer's squareness as the history of the printer profile in force knows it
        (:func:`.known_squareness.known_squareness`): what a vertical test analysed alone
        takes as its out-of-plane motion."""
        s = self._store.current()
        return known_squareness(self._runs.index(s["profile"] or None, s["legacy_profile"]))

    @http.route("/runs", "GET", needs=(http.STATUS,))
    def runs(self):
        s = self._store.current()  # the history of the printer profile in force
        return flask.jsonify(runs=self._runs.list(s["profile"] or None, s["legacy_profile"]))

    @http.route("/runs/<run_id>", "GET", needs=(http.STATUS,))
    def run(self, run_id: str):
        try:
            return flask.jsonify(self._runs.get(run_id))
        except RunNotFound:
            return http.error(gettext("No such calibration run"), 404)

    @http.route("/runs/<run_id>/trace", "GET", needs=(http.STATUS,))
    def run_trace(self, run_id: str):
        """The measurement file of a run as it was uploaded (trace, .b5r)."""
        try:
            run = self._runs.get(run_id)
        except RunNotFound:
            return http.error(gettext("No such calibration run"), 404)
        path = self._runs.trace_path(run_id)
        if path is None:
            return http.error(gettext("This run has no stored measurement file"), 404)
        name = safe_name(str(run.get("filename") or "trace"))
        return flask.send_file(
            path, mimetype="application/octet-stream", as_attachment=True, download_name=name
        )

    @http.route("/compare", "GET", needs=(http.STATUS,))
    def compare(self):
        try:
            a = self._runs.get(flask.request.args.get("before", ""))
            b = self._runs.get(flask.request.args.get("after", ""))
        except RunNotFound:
            return http.error(gettext("No such calibration run"), 404)
        return flask.jsonify(
            table=table(a["diagnostics"], b["diagnostics"], servo_in_force(b)),
            before=a["id"],
            after=b["id"],
        )

    # ~~ demo mode ---------------------------------------------------------------------------
    @http.route("/demo/trace", "GET", needs=(http.STATUS,))
    def demo_trace(self):
        trace = self._demo.last_trace()
        if trace is None:
            return http.error(
                gettext("No simulated trace yet: print a ballbar program in demo mode first"), 404
            )
        resp = flask.make_response(trace.to_text())
        resp.headers["Content-Type"] = "text/csv; charset=utf-8"
        resp.headers["Content-Disposition"] = 'attachment; filename="simulated_trace.csv"'
        return resp
