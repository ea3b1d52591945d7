"""Background file compensation: a worker thread that compensates queued G-code files one
after the other (OctoPrint-free; the plugin supplies the work and hears of every change).

A Job's progress runs 0..1; its state goes queued -> running -> done or failed (with the
error). The worker is held while a print runs, so file work never starves the print.
"""

from __future__ import annotations

import threading
import time
from typing import Callable, Dict, Optional


class Job:
    """One background compensation (progress 0..1, result or error)."""

    def __init__(self, path: str):
        self.path = path
        self.progress = 0.0
        self.state = "queued"  # queued, running, done, failed
        self.result: Optional[str] = None
        self.error: Optional[str] = None
        self.report: Optional[Dict] = None
        self.started = time.time()

    def to_dict(self) -> Dict:
        return {"path": self.path, "progress": round(self.progress, 3), "state": self.state,
                "result": self.result, "error": self.error, "report": self.report}


class BackgroundCompensator:
    """A worker thread that compensates queued files one after the other.

    ``run_job(job, progress)`` does the work (the plugin supplies it: read from the file
    manager, compensate with the fast engine, add the result as a new file); ``notify(job)``
    is called on every state change and progress step.
    """

    def __init__(self, run_job: Callable[[Job, Callable[[float], None]], None],
                 notify: Callable[[Job], None]):
        self._run_job = run_job
        self._notify = notify
        self._queue = []
        self._cond = threading.Condition()
        self.jobs: Dict[str, Job] = {}
        self.paused = False  # held while printing: file work must not starve the print
        self._thread = threading.Thread(target=self._loop, name="kincomp-files", daemon=True)
        self._thread.start()

    def submit(self, path: str) -> Job:
        with self._cond:
            job = self.jobs.get(path)
            if job is not None and job.state in ("queued", "running"):
                return job
            job = Job(path)
            self.jobs[path] = job
            self._queue.append(job)
            self._cond.notify()
        self._notify(job)
        return job

    def set_paused(self, paused: bool) -> None:
        with self._cond:
            self.paused = paused
            self._cond.notify()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._queue or self.paused:
                    self._cond.wait()
                job = self._queue.pop(0)
            job.state = "running"
            self._notify(job)
            last = [0.0]

            def progress(frac: float) -> None:
                job.progress = frac
                if frac - last[0] >= 0.05:
                    last[0] = frac
                    self._notify(job)

            try:
                self._run_job(job, progress)
                job.state = "done"
                job.progress = 1.0
            except Exception as exc:  # noqa: BLE001 - reported to the user, never lost
                job.state = "failed"
                job.error = str(exc)
            self._notify(job)
