"""Upload-time and background file compensation (OctoPrint glue around the core engine)."""

from __future__ import annotations

import os
import threading
import time
from typing import Callable, Dict, Optional

from octoprint.filemanager.util import LineProcessorStream

from ..core.compensator import Options
from ..core.lines import UNIVERSAL, join_output, split_ending
from ..core.marker import ENCODING, ERRORS, MARKER_SCAN_LINES, marker_hash
from ..core.params import Params
from ..engines.files import marker_line
from ..engines.select import make_compensator


class CompensatingStream(LineProcessorStream):
    """Compensates an upload while OctoPrint saves it (one line at a time, O(1) memory).

    The first output line is KinComp's marker; a file that already carries a marker among
    its first ``MARKER_SCAN_LINES`` lines (e.g. after lines another preprocessor put first)
    is passed through unchanged (never compensated twice). Those first lines are read
    before anything is written, so the decision covers all of them.
    """

    def __init__(self, input_stream, params: Params, options: Options):
        super().__init__(input_stream)
        self.params = params
        self.comp = make_compensator(params, options)
        self.started = False
        self.passthrough = False

    def process_line(self, line: bytes) -> bytes:
        if not self.started:
            self.started = True
            head = [line]
            while len(head) < MARKER_SCAN_LINES:
                more = self.input_stream.readline()
                if not more:
                    break
                head.append(more)
            return self._head(b"".join(head))
        if self.passthrough:
            return line
        return self._lines(line.decode(ENCODING, ERRORS)).encode(ENCODING, ERRORS)

    def _head(self, data: bytes) -> bytes:
        text = data.decode(ENCODING, ERRORS)
        raws = UNIVERSAL.findall(text) or [text]
        bodies = [split_ending(raw)[0] for raw in raws[:MARKER_SCAN_LINES]]
        if any(marker_hash(b) is not None for b in bodies):
            self.passthrough = True
            return data
        first_ending = split_ending(raws[0])[1]
        return (marker_line(self.params) + (first_ending or "\n")
                + self._lines(text)).encode(ENCODING, ERRORS)

    def _lines(self, text: str) -> str:
        out = []
        for raw in UNIVERSAL.findall(text) or [text]:
            body, ending = split_ending(raw)
            res = self.comp.process(body)
            out.append(raw if res is body else join_output(res, ending))
        return "".join(out)


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


def file_size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0
