"""KinComp's work on the G-code files in OctoPrint's local storage.

* Endpoints: ``GET /dryrun?path=`` (what compensating a file would change, nothing
  written), ``POST /compensate`` ({"path": ...}: a background job writes
  ``<name>.kincomp.gcode``), ``GET /files`` (the files with the parameter hash they were
  compensated with, and whether that is outdated).
* Background mode (setting ``mode = background``): every G-code file added is queued for a
  job, unless it already carries KinComp's marker. Job changes go to the UI as plugin
  messages ``{"type": "job", "job": ...}``.
* On-upload mode (``mode = on_upload``): the preprocessor hook saves uploads through a
  :class:`CompensatingStream`.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Dict, Optional

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions
from octoprint.filemanager import FileDestinations, valid_file_type
from octoprint.filemanager.util import DiskFileWrapper, StreamWrapper

from ..core.kinematics import changes_nothing
from ..core.marker import file_marker
from ..engines.files import AlreadyCompensated, compensate_file
from . import http
from .jobs import BackgroundCompensator, Job
from .notify import Notifier
from .queue import QueueCompensator
from .settings_store import SettingsStore
from .upload import CompensatingStream


class FilesApi:
    """File work; ``data_folder()`` (the plugin's data folder, made if missing) holds a
    job's temporary output. Owns the background worker (``jobs``)."""

    def __init__(self, store: SettingsStore, queue: QueueCompensator, file_manager,
                 notifier: Notifier, data_folder: Callable[[], str]):
        self._store = store
        self._queue = queue
        self._file_manager = file_manager
        self._notifier = notifier
        self._data_folder = data_folder
        self.jobs = BackgroundCompensator(self._run_job, self._job_changed)

    # ~~ endpoints ---------------------------------------------------------------------------
    def dryrun(self):
        http.require(Permissions.STATUS)
        http.require(Permissions.FILES_LIST)
        disk = self._local_file(flask.request.args.get("path", ""))
        if disk is None:
            return http.error(gettext("No such G-code file"), 404)
        params, options = self._store.engine_config(self._store.current())
        try:
            report = compensate_file(disk, None, params, options, dry_run=True)
        except AlreadyCompensated as exc:
            return flask.jsonify(precompensated=exc.params_hash, report=None)
        return flask.jsonify(precompensated=None, params_hash=params.hash(),
                             report=report.to_dict())

    def compensate(self):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        http.require(Permissions.FILES_UPLOAD)
        data = http.json_object() or {}
        path = data.get("path", "")
        disk = self._local_file(path)
        if disk is None:
            return http.error(gettext("No such G-code file"), 404)
        if file_marker(disk) is not None:
            return http.error(gettext("This file is already compensated"), 409)
        job = self.jobs.submit(path)
        return flask.jsonify(job=job.to_dict())

    def files(self):
        """Local G-code files with the parameter hash they were compensated with (if any)."""
        http.require(Permissions.FILES_LIST)
        out = []
        current = self._queue.params.hash()

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

    # ~~ hooks and events ----------------------------------------------------------------------
    def preprocess(self, path: str, file_object, printer_profile=None):
        """The preprocessor hook: in on-upload mode a G-code upload is saved compensated
        (None: saved as it is)."""
        s = self._store.current()
        if not s["enabled"] or s["mode"] != "on_upload":
            return None
        if not valid_file_type(path, type="gcode"):
            return None
        params, options = self._store.engine_config(s, printer_profile)
        if changes_nothing(params):
            return None
        return StreamWrapper(file_object.filename,
                             CompensatingStream(file_object.stream(), params, options))

    def file_added(self, payload: Dict[str, Any]) -> None:
        """FILE_ADDED: in background mode an unmarked local G-code file gets a job."""
        s = self._store.current()
        path = payload.get("path")
        if (not s["enabled"] or s["mode"] != "background" or not path
                or payload.get("storage") != FileDestinations.LOCAL
                or not valid_file_type(path, type="gcode")):
            return
        disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        if file_marker(disk) is not None:
            return
        self.jobs.submit(path)

    # ~~ inside ----------------------------------------------------------------------------------
    def _local_file(self, path: str) -> Optional[str]:
        if not isinstance(path, str) or not path or not valid_file_type(path, type="gcode"):
            return None
        try:
            if not self._file_manager.file_exists(FileDestinations.LOCAL, path):
                return None
            return self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        except ValueError:  # the storage refuses paths outside its folder
            return None

    def _run_job(self, job: Job, progress: Callable[[float], None]) -> None:
        """Compensates ``job.path`` into ``<root>.kincomp<ext>`` next to it (worker thread)."""
        params, options = self._store.engine_config(self._store.current())
        src = self._file_manager.path_on_disk(FileDestinations.LOCAL, job.path)
        total = max(1, os.path.getsize(src))
        root, ext = os.path.splitext(job.path)
        dest = f"{root}.kincomp{ext or '.gcode'}"
        tmp = os.path.join(self._data_folder(), "job.tmp")
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

    def _job_changed(self, job: Job) -> None:
        self._notifier.message({"type": "job", "job": job.to_dict()})
