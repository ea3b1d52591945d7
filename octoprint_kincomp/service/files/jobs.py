"""Background jobs: the bounded queue in front of the worker process (OctoPrint-free; the
plugin supplies each job's work and hears of every change).

* One job at a time, by one dispatcher thread; the heavy part of a job runs in the
  low-priority worker process (:mod:`.worker`), so neither a request thread nor OctoPrint's
  interpreter does it while a print runs.
* At most ``limit`` jobs queued or running (:class:`QueueFull` beyond: the endpoints answer
  429); at most one job of a kind per file at a time (submitting it again returns the job
  under way, and the endpoints answer 202 with its id; the endpoints canonicalise the path
  first, so ``x/../a.gcode`` and ``/a.gcode`` are ``a.gcode``).
* Fair shares: a user without KinComp's admin permission has at most ``per_user`` jobs
  queued or running, and such users together at most ``limit - reserved``: the last
  ``reserved`` places are kept for admins (and KinComp's own background jobs), whose jobs
  also run before theirs. So read-only users never starve an admin's compensation.
* A job can be cancelled (:meth:`JobQueue.cancel`): a queued one never runs; a running one
  in the worker process ends at once (the process is ended: its partial file is removed),
  other work at its next progress step; it is failed with ``CANCELLED``.
* A job's progress runs 0..1; its state goes queued -> running -> done or failed (with the
  error). Jobs marked ``held_while_printing`` (writing a compensated copy) wait while a
  print runs; dry runs and analyses go on at low priority.
* The job list survives a restart (``history`` file): a job that was queued or running when
  the server stopped is listed as failed ("interrupted").
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import threading
import time
from typing import Any, Callable, Dict, List, Optional

from ...core.atomic import write_atomic

MAX_HISTORY = 50  # finished jobs kept in the list
IDLE_STOP_S = 300.0  # the worker process ends after this long without a job
INTERRUPTED = "interrupted: the server stopped before the job finished"
CANCELLED = "cancelled"
PER_USER = 2  # jobs queued or running per user without the admin permission
RESERVED = 3  # places of the limit kept for admins' jobs

_log = logging.getLogger(__name__)


class QueueFull(RuntimeError):
    """Too many jobs are queued or running (``mine``: too many of this user's own)."""

    def __init__(self, kind: str, mine: bool = False):
        super().__init__(kind)
        self.mine = mine


class JobCancelled(RuntimeError):
    """The job was cancelled while it ran."""


class Job:
    """One background job (progress 0..1, result or error)."""

    def __init__(
        self,
        kind: str,
        path: Optional[str],
        run=None,
        held_while_printing: bool = False,
        owner: Optional[str] = None,
        admin: bool = True,
    ):
        self.id = secrets.token_hex(6)
        self.owner = owner  # the user who submitted it (None: KinComp itself)
        self.admin = admin  # submitted with the admin permission (or by KinComp itself)
        self.cancelled = False
        self.kind = kind  # compensate, dryrun, analyse
        self.path = path  # the file it works on (None: no file, e.g. an uploaded trace)
        self.progress = 0.0
        self.state = "queued"  # queued, running, done, failed
        self.result: Any = None
        self.error: Optional[str] = None
        self.exception: Optional[BaseException] = None  # (not listed) to translate the error
        self.report: Optional[Dict] = None
        self.started = time.time()
        self.finished: Optional[float] = None
        self.held_while_printing = held_while_printing
        self.run = run  # run(job, progress): the work
        self.done = threading.Event()

    @property
    def active(self) -> bool:
        return self.state in ("queued", "running")

    def to_dict(self) -> Dict:
        return {
            "id": self.id,
            "kind": self.kind,
            "path": self.path,
            "owner": self.owner,
            "progress": round(self.progress, 3),
            "state": self.state,
            "result": self.result,
            "error": self.error,
            "report": self.report,
            "started": self.started,
            "finished": self.finished,
        }

    @staticmethod
    def from_dict(d: Dict) -> Job:
        job = Job(str(d.get("kind") or "compensate"), d.get("path"))
        job.id = str(d.get("id") or job.id)
        for key in (
            "owner",
            "progress",
            "state",
            "result",
            "error",
            "report",
            "started",
            "finished",
        ):
            if key in d:
                setattr(job, key, d[key])
        job.done.set()
        return job


class JobQueue:
    """Jobs run one after the other by a dispatcher thread.

    ``notify(job)`` is called on every state change and progress step; ``history`` (a file
    path, or None) keeps the job list over restarts; ``worker`` (a ``WorkerProcess`` or
    None) is the process the jobs' work runs in, stopped when idle."""

    def __init__(
        self,
        notify: Callable[[Job], None],
        limit: int = 8,
        history: Optional[str] = None,
        worker=None,
        per_user: int = PER_USER,
        reserved: int = RESERVED,
    ):
        self._notify = notify
        self.limit = limit
        self.per_user = per_user
        self.reserved = min(reserved, limit - 1)
        self._history = history
        self.worker = worker
        self._cond = threading.Condition()
        self._queue: List[Job] = []
        self.jobs: Dict[str, Job] = {}
        self.paused = False  # a print runs: jobs held_while_printing wait
        self.stopping = False  # the server stops: a job ended now was interrupted
        self._load()
        self._thread = threading.Thread(target=self._loop, name="kincomp-jobs", daemon=True)
        self._thread.start()

    # ~~ submitting ----------------------------------------------------------------------------
    def under_way(self, kind: str, path: str) -> Optional[Job]:
        """The job of ``kind`` on ``path`` that is queued or running, if any."""
        with self._cond:
            return next(
                (j for j in self.jobs.values() if j.active and j.kind == kind and j.path == path),
                None,
            )

    def submit(
        self,
        kind: str,
        path: Optional[str],
        run: Callable,
        held_while_printing: bool = False,
        owner: Optional[str] = None,
        admin: bool = True,
    ) -> Job:
        """A new job, or the one of this kind on ``path`` already under way. Raises
        :class:`QueueFull` when ``limit`` jobs are queued or running, or (``admin`` false)
        when ``owner`` has ``per_user`` of them or such users hold all places but the
        ``reserved`` ones."""
        with self._cond:
            job = self.under_way(kind, path) if path is not None else None
            if job is not None:
                return job
            active = [j for j in self.jobs.values() if j.active]
            if len(active) >= self.limit:
                raise QueueFull(kind)
            if not admin:
                if sum(1 for j in active if j.owner == owner) >= self.per_user:
                    raise QueueFull(kind, mine=True)
                if sum(1 for j in active if not j.admin) >= self.limit - self.reserved:
                    raise QueueFull(kind)
            job = Job(kind, path, run, held_while_printing, owner=owner, admin=admin)
            self.jobs[job.id] = job
            self._queue.append(job)
            self._trim()
            self._cond.notify_all()
        self._changed(job)
        return job

    def cancel(self, job: Job) -> bool:
        """Cancels ``job``: a queued one is failed at once, a running one stops at its next
        progress step. False if it had already finished or is being cancelled already (a
        second cancel of one job is refused, not answered as if it had done something)."""
        with self._cond:
            if not job.active or job.cancelled:
                return False
            job.cancelled = True
            queued = job in self._queue
            if queued:
                self._queue.remove(job)
                job.state = "failed"
                job.error = CANCELLED
                job.finished = time.time()
                job.run = None
        if queued:
            self._changed(job)
            job.done.set()
        elif self.worker is not None and hasattr(self.worker, "abort"):
            self.worker.abort(job.id)  # its work in the worker process ends now
        return True

    def get(self, job_id: str) -> Optional[Job]:
        return self.jobs.get(job_id) if isinstance(job_id, str) else None

    def set_paused(self, paused: bool) -> None:
        with self._cond:
            self.paused = paused
            self._cond.notify_all()

    def stop(self) -> None:
        """The server stops: the worker process ends (its partial output is removed)."""
        self.stopping = True
        if self.worker is not None:
            self.worker.stop()

    # ~~ inside ----------------------------------------------------------------------------------
    def _next(self) -> Optional[Job]:
        """The next job to run: admins' (and KinComp's own) first, then in order."""
        ready = [j for j in self._queue if not (self.paused and j.held_while_printing)]
        job = next((j for j in ready if j.admin), ready[0] if ready else None)
        if job is not None:
            self._queue.remove(job)
        return job

    def _loop(self) -> None:
        while True:
            with self._cond:
                job = self._next()
                if job is None:
                    self._cond.wait(timeout=30.0)
                    job = self._next()
            if job is not None:
                self._execute(job)
            elif self.worker is not None:
                self.worker.stop_if_idle(IDLE_STOP_S)

    def _execute(self, job: Job) -> None:
        job.state = "running"
        self._changed(job)
        last = [0.0]

        def progress(frac: float) -> None:
            if job.cancelled:
                raise JobCancelled(CANCELLED)
            job.progress = max(0.0, min(1.0, float(frac)))
            if job.progress - last[0] >= 0.05:
                last[0] = job.progress
                self._notify_safely(job)

        try:
            if job.cancelled:
                raise JobCancelled(CANCELLED)
            job.run(job, progress)
            job.state = "done"
            job.progress = 1.0
        except Exception as exc:
            job.state = "failed"
            job.exception = exc
            job.error = (
                CANCELLED
                if job.cancelled
                else INTERRUPTED
                if self.stopping
                else (str(exc) or type(exc).__name__)
            )
        job.finished = time.time()
        job.run = None
        self._changed(job)
        job.done.set()

    def _changed(self, job: Job) -> None:
        self._save()
        self._notify_safely(job)

    def _notify_safely(self, job: Job) -> None:
        try:
            self._notify(job)
        except Exception:
            _log.exception("KinComp: job notification failed")

    def _trim(self) -> None:
        finished = sorted(
            (j for j in self.jobs.values() if not j.active), key=lambda j: j.finished or j.started
        )
        for job in finished[: max(0, len(finished) - MAX_HISTORY)]:
            del self.jobs[job.id]

    # ~~ the job list over restarts ----------------------------------------------------------
    def _load(self) -> None:
        if not self._history or not os.path.exists(self._history):
            return
        try:
            with open(self._history, encoding="utf-8") as f:
                stored = json.load(f)
            jobs = [Job.from_dict(d) for d in stored if isinstance(d, dict)]
        except (OSError, ValueError, TypeError, AttributeError):
            _log.warning("KinComp: the job list %s could not be read", self._history)
            return
        for job in jobs:
            if job.state not in ("done", "failed"):
                job.state = "failed"
                job.error = INTERRUPTED
                job.finished = job.finished or time.time()
            self.jobs[job.id] = job
        self._trim()
        self._save()

    def _save(self) -> None:
        if not self._history:
            return
        with self._cond:  # (held while writing: an older list never overwrites a newer)
            listed = [j.to_dict() for j in self.jobs.values()]
            try:
                write_atomic(self._history, json.dumps(listed, allow_nan=False).encode())
            except (OSError, ValueError, TypeError):
                _log.exception("KinComp: the job list could not be saved")
