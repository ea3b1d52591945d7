"""KinComp's work on the G-code files in OctoPrint's local storage.

* Endpoints: ``GET /dryrun?path=`` (what compensating a file would change, nothing
  written), ``POST /compensate`` ({"path": ...}: a background job writes
  ``<name>.kincomp.gcode``), ``GET /files`` (the files with the parameter hash they were
  compensated with, and whether that is outdated), ``GET /jobs/<id>`` (one job).
* Dry runs and compensations are jobs (``service/files/jobs.py``) whose work runs in the
  low-priority worker process (``service/files/worker.py``), never in a request thread: a dry run
  answers 200 with its report if that is ready within a few seconds, else 202 with the job (poll
  ``/jobs/<id>``, cancel ``POST /jobs/<id>/cancel``, see :mod:`.job_api`); 429 when too many jobs
  wait, or too many of the user's own (``service/files/jobs.py``). A job's path is the file's
  canonical one (below the uploads folder), whatever spelling the request used. A compensation
  answers 202 with its job.
* Background mode (setting ``mode = background``): every G-code file added is queued for a
  job, unless it already carries KinComp's marker. Job changes go to the UI as plugin
  messages ``{"type": "job", "job": ...}`` (compensations only).
* On-upload mode (``mode = on_upload``): the preprocessor hook saves uploads through a
  :class:`CompensatingStream`.
* Nothing is compensated while the stored settings are invalid (409), and a symbolic link
  in the uploads folder that leads out of it is not followed (403).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import tempfile
from typing import Any, Callable, Dict

import flask
from flask_babel import gettext
from octoprint.filemanager import FileDestinations, valid_file_type
from octoprint.filemanager.util import DiskFileWrapper, StreamWrapper
from octoprint.util import RepeatedTimer

from ...core.atomic import clean_abandoned_octoprint_uploads, clean_stale, clean_stale_uploads
from ...core.kinematics import changes_nothing
from ...core.marker import file_marker
from ...engines.file_loop import AlreadyCompensated
from ...service.files.jobs import Job, JobQueue, QueueFull
from ...service.files.worker import WorkerProcess
from ...service.notify import N_, Notifier
from ...service.printing.queue import QueueCompensator, edge_of, notify_edge
from ...service.settings.schema import SettingsInvalid
from .. import http
from ..settings.settings_store import SettingsStore
from .job_api import JobApi
from .upload import CompensatingStream

_logger = logging.getLogger("octoprint.plugins.kincomp")
SWEEP_S = 3600.0  # s between sweeps of OctoPrint's abandoned upload files


class LinkOutside(PermissionError):
    """A symbolic link in the uploads folder leads out of it (not followed)."""


def options_dict(options) -> Dict[str, Any]:
    """Options as keyword arguments (what the worker process rebuilds them from)."""
    return dataclasses.asdict(options)


def start_up_clean(folder: str) -> None:
    """The plugin's data folder at start-up: temporary files of processes that no longer
    run (``.kincomp-*``), and job outputs that were never moved into the uploads; and in
    the temporary folder the files of uploads to KinComp's routes whose server was killed
    (``kincomp-upload-<pid>-*.tmp``, ``upload_handler.py``) and OctoPrint's own upload files
    abandoned the same way (:func:`sweep_octoprint_uploads`)."""
    for sub in ("", "runs", "jobs"):
        clean_stale(os.path.join(folder, sub))
    clean_stale_uploads(tempfile.gettempdir())
    sweep_octoprint_uploads()
    jobs = os.path.join(folder, "jobs")
    if os.path.isdir(jobs):
        for name in os.listdir(jobs):
            path = os.path.join(jobs, name)
            if name.endswith(".gcode") and os.path.isfile(path):
                try:
                    os.unlink(path)
                except OSError:
                    pass


_SWEEPER = []  # the one timer of this process


def _start_sweeping() -> None:
    if not _SWEEPER:
        _SWEEPER.append(RepeatedTimer(SWEEP_S, sweep_octoprint_uploads, daemon=True))
        _SWEEPER[0].start()


def sweep_octoprint_uploads() -> None:
    """OctoPrint's own upload routes leave their temporary file behind when the server is
    killed during an upload, and nothing removes it: at start-up and every
    :data:`SWEEP_S` those last written over an hour ago that no process has open are removed
    (``core.atomic.clean_abandoned_octoprint_uploads``) and logged."""
    for path in clean_abandoned_octoprint_uploads(tempfile.gettempdir()):
        _logger.info("removed an abandoned upload file of OctoPrint's: %s", path)


class FilesApi:
    """File work; ``data_folder()`` (the plugin's data folder, made if missing) holds the
    job list and a job's output until it is moved into the uploads. Owns the job queue
    (``jobs``) and so the worker process (``worker``: None for a new process)."""

    def __init__(
        self,
        store: SettingsStore,
        queue: QueueCompensator,
        file_manager,
        notifier: Notifier,
        data_folder: Callable[[], str],
        worker=None,
    ):
        self._store = store
        self._queue = queue
        self._file_manager = file_manager
        self._notifier = notifier
        self._data_folder = data_folder
        folder = data_folder()
        start_up_clean(folder)
        _start_sweeping()
        self.jobs = JobQueue(
            self._job_changed,
            history=os.path.join(folder, "jobs.json"),
            worker=worker if worker is not None else WorkerProcess(),
        )
        self.job_api = JobApi(self.jobs)

    # ~~ endpoints ---------------------------------------------------------------------------
    @http.route(
        "/dryrun",
        "GET",
        needs=(
            http.STATUS,
            http.FILES_LIST,
        ),
    )
    def dryrun(self):
        disk = self.local_file(flask.request.args.get("path", ""))
        path = self._canonical(disk)
        running = self.jobs.under_way("dryrun", path)
        if running is not None:  # asked again: the answer costs nothing more
            return self.job_api.answer(running, lambda j: j.report)
        try:
            s = self._store.require_usable()
        except SettingsInvalid as exc:
            return http.error(http.tr(exc), 409)
        params, options = self._store.engine_config(s)
        args = {
            "src": disk,
            "dst": None,
            "params": params.to_dict(),
            "options": options_dict(options),
            "dry_run": True,
        }

        def run(job: Job, progress) -> None:
            job.report = self.jobs.worker.call(job.id, "compensate", args, progress)

        job = self.job_api.submit("dryrun", path, run)
        return self.job_api.answer(job, lambda j: j.report)

    @http.route(
        "/compensate",
        "POST",
        needs=(
            http.PLUGIN_KINCOMP_ADMIN,
            http.FILES_UPLOAD,
        ),
    )
    def compensate(self):
        data = http.json_object() or {}
        disk = self.local_file(data.get("path", ""))
        path = self._canonical(disk)
        try:
            self._store.require_usable()
        except SettingsInvalid as exc:
            return http.error(http.tr(exc), 409)
        if file_marker(disk) is not None:
            return http.error(gettext("This file is already compensated"), 409)
        job = self.job_api.submit(
            "compensate", path, self._compensation(path), held_while_printing=True
        )
        return flask.make_response(flask.jsonify(job=job.to_dict()), 202)

    @http.route("/files", "GET", needs=(http.FILES_LIST,))
    def files(self):
        """Local G-code files with the parameter hash they were compensated with (if any)."""
        out = []
        current = self._queue.params.hash()

        def walk(node, prefix=""):
            for name, entry in (node or {}).items():
                if entry.get("type") == "folder":
                    walk(entry.get("children"), entry.get("path", name) + "/")
                elif entry.get("type") == "machinecode":
                    path = entry.get("path") or prefix + name
                    try:
                        h = file_marker(self._disk(path))
                    except Exception:
                        h = None
                    out.append(
                        {"path": path, "params_hash": h, "outdated": h is not None and h != current}
                    )

        walk(
            self._file_manager.list_files(FileDestinations.LOCAL, recursive=True).get(
                FileDestinations.LOCAL
            )
        )
        return flask.jsonify(files=out, params_hash=current)

    # ~~ jobs ------------------------------------------------------------------------------------
    def _compensation(self, path: str):
        """A job's work: ``path`` compensated into ``<root>.kincomp<ext>`` beside it."""

        def run(job: Job, progress) -> None:
            s = self._store.require_usable()  # the settings may have changed meanwhile
            params, options = self._store.engine_config(s)
            src = self._disk(path)
            folder = os.path.join(self._data_folder(), "jobs")
            os.makedirs(folder, exist_ok=True)
            out = os.path.join(folder, job.id + ".gcode")
            try:
                result = self.jobs.worker.call(
                    job.id,
                    "compensate",
                    {
                        "src": src,
                        "dst": out,
                        "params": params.to_dict(),
                        "options": options_dict(options),
                    },
                    progress,
                )
                if result["precompensated"] is not None:
                    raise AlreadyCompensated(result["precompensated"])
                root, ext = os.path.splitext(path)
                dest = f"{root}.kincomp{ext or '.gcode'}"
                self._file_manager.add_file(
                    FileDestinations.LOCAL,
                    dest,
                    DiskFileWrapper(os.path.basename(dest), out, move=True),
                    allow_overwrite=True,
                )
                self._file_manager.set_additional_metadata(
                    FileDestinations.LOCAL,
                    dest,
                    "kincomp",
                    {"params_hash": params.hash(), "source": path},
                    overwrite=True,
                )
                job.result = dest
                job.report = result["report"]
                notify_edge(self._notifier, edge_of(job.report, options.policy), path)
            finally:
                if os.path.exists(out):
                    os.unlink(out)

        return run

    def _job_changed(self, job: Job) -> None:
        if job.kind == "compensate":
            self._notifier.message({"type": "job", "job": job.to_dict()})

    # ~~ hooks and events ----------------------------------------------------------------------
    def preprocess(self, path: str, file_object, printer_profile=None):
        """The preprocessor hook: in on-upload mode a G-code upload is saved compensated
        (None: saved as it is; also while the stored settings are invalid)."""
        s = self._store.current()
        if not s["enabled"] or s["mode"] != "on_upload":
            return None
        if not valid_file_type(path, type="gcode"):
            return None
        params, options = self._store.engine_config(s, printer_profile)
        if changes_nothing(params):
            return None
        return StreamWrapper(
            file_object.filename, CompensatingStream(file_object.stream(), params, options)
        )

    def file_added(self, payload: Dict[str, Any]) -> None:
        """FILE_ADDED: in background mode an unmarked local G-code file gets a job."""
        s = self._store.current()
        path = payload.get("path")
        if (
            not s["enabled"]
            or s["mode"] != "background"
            or not path
            or payload.get("storage") != FileDestinations.LOCAL
            or not valid_file_type(path, type="gcode")
        ):
            return
        try:
            if file_marker(self._disk(path)) is not None:
                return
            self.jobs.submit("compensate", path, self._compensation(path), held_while_printing=True)
        except (OSError, ValueError, QueueFull) as exc:
            self._notifier.notify(
                "error",
                N_("KinComp could not queue %(path)s for compensation: %(reason)s"),
                path=path,
                reason=str(exc),
            )

    # ~~ inside ----------------------------------------------------------------------------------
    def _disk(self, path: str) -> str:
        """Where the stored file ``path`` is on disk; :class:`LinkOutside` if it is a link
        that leads out of the uploads folder (never followed)."""
        disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        root = self._uploads_root()
        real, base = os.path.realpath(disk), os.path.realpath(root)
        if os.path.commonpath([real, base]) != base:
            raise LinkOutside(
                gettext(
                    "%(path)s is a link out of the uploads folder; KinComp does not follow it",
                    path=path,
                )
            )
        return disk

    def inside_uploads(self, path: str) -> str:
        """The disk path of the stored file ``path`` (its existence checked by the caller);
        aborts with 403 for a link out of the uploads folder."""
        try:
            return self._disk(path)
        except LinkOutside as exc:
            http.abort(403, str(exc))

    def _uploads_root(self) -> str:
        return os.path.dirname(
            self._file_manager.path_on_disk(FileDestinations.LOCAL, "kincomp-root-probe.gcode")
        )

    def _canonical(self, disk: str) -> str:
        """The one spelling of the stored file at ``disk``: its path below the uploads
        folder, "/"-separated (``x/../a.gcode`` and ``/a.gcode`` are ``a.gcode``), so one
        file has one job of a kind whatever the request wrote."""
        rel = os.path.relpath(os.path.normpath(disk), os.path.normpath(self._uploads_root()))
        return rel.replace(os.sep, "/")

    def local_file(self, path: Any) -> str:
        """The disk path of the stored G-code file ``path`` (a request field): aborts with
        400 for a malformed path, 404 if there is no such file, 403 for a link out of the
        uploads folder."""
        if not isinstance(path, str) or not path or "\0" in path:
            http.abort(400, gettext("'%(key)s' must be the path of a G-code file", key="path"))
        if not valid_file_type(path, type="gcode"):
            http.abort(404, gettext("No such G-code file"))
        try:
            exists = self._file_manager.file_exists(FileDestinations.LOCAL, path)
            disk = self._disk(path) if exists else None
        except LinkOutside as exc:
            http.abort(403, str(exc))
        except ValueError:  # the storage refuses paths outside its folder
            exists = False
        except Exception:
            http.abort(400, gettext("'%(key)s' is not a valid file path", key="path"))
        if not exists:
            http.abort(404, gettext("No such G-code file"))
        return disk
