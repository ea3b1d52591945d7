"""The low-priority worker process that does KinComp's heavy work for the plugin: whole-file
compensation, dry runs and every analysis of a measurement: traces, summaries, campaign
tests, campaigns' joint analyses, printed artifacts (no OctoPrint import: the child
runs ``python -m octoprint_kincomp.service.files.worker`` and loads only what its work needs).

Why a separate process at the lowest CPU priority (nice 19, and the lowest best-effort I/O
priority where the OS has one) rather than a thread: a thread of OctoPrint's process shares
its interpreter lock with the serial send loop, so CPU-bound work in any thread of that
process slows the print's stream however it is scheduled; a process at nice 19 gets the
CPU only when OctoPrint (nice 0) does not need it, and the kernel schedules it, not Python.

Protocol, pickled tuples over the child's stdin and stdout (the child's own output goes to
stderr): the parent sends ``(job_id, kind, args)``; the child answers any number of
``("progress", job_id, fraction 0..1)`` and then ``("done", job_id, result)`` or
``("failed", job_id, exception)``. The child ends at end of input (the parent closed it or
died), on SIGTERM/SIGINT (a file it was writing is removed: ``core.atomic``), and when its
parent is gone (checked at each progress step, so an orphan never finishes a file).
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Callable, Dict, Optional

PROGRESS_EVERY_S = 0.2  # at most this often a progress message


class WorkerDied(RuntimeError):
    """The worker process ended in the middle of a job (killed, out of memory)."""


# ~~ the child's work ----------------------------------------------------------------------
def _engine_args(params: Dict[str, Any], options: Dict[str, Any]):
    from ...core.compensator import Options
    from ...core.params import Params

    return Params.from_dict(params), Options(**options)


def task_compensate(
    src: str,
    dst: Optional[str],
    params: Dict[str, Any],
    options: Dict[str, Any],
    progress: Callable[[float], None],
    dry_run: bool = False,
) -> Dict[str, Any]:
    """``src`` compensated into ``dst`` (or only counted with ``dry_run``): the report, or
    ``{"precompensated": hash}`` for a file that already carries KinComp's marker."""
    from ...engines.file_loop import AlreadyCompensated, compensate_file

    p, o = _engine_args(params, options)
    total = max(1, os.path.getsize(src))
    try:
        report = compensate_file(
            src, dst, p, o, dry_run=dry_run, progress=lambda done: progress(min(1.0, done / total))
        )
    except AlreadyCompensated as exc:
        return {"precompensated": exc.params_hash, "report": None}
    return {"precompensated": None, "report": report.to_dict(), "params_hash": p.hash()}


def task_analyse(
    data: bytes,
    name: str,
    current: Dict[str, Any],
    progress: Callable[[float], None],
    known: Optional[Dict[str, Any]] = None,
    campaign: Optional[Dict[str, Any]] = None,
    step: Optional[Dict[str, Any]] = None,
    origin: Optional[Dict[str, Any]] = None,
) -> Dict[str, Any]:
    """A trace, .b5r or summary file analysed (``service/calibration/measurement.py``, the
    one analysis of a measurement); ``known``: the printer's squareness from its run
    history; ``campaign`` and ``step``: the campaign test it must be the trace of;
    ``origin``: what the test ran with (``service/calibration/printed_programs.py``)."""
    from ..calibration.measurement import analyse_measurement

    progress(0.1)
    return analyse_measurement(data, name, current, known, campaign, step, origin)


def task_analyse_campaign(
    traces,
    current: Dict[str, Any],
    progress: Callable[[float], None],
    origin: Optional[Dict[str, Any]] = None,
) -> Dict[str, Any]:
    """A campaign's joint analysis of its tests' traces ``[(name, data)]``; ``origin``: what
    its tests ran with (as ``task_analyse``'s)."""
    from ..calibration.measurement import analyse_joint

    progress(0.1)
    return analyse_joint(traces, current, origin)


def task_analyse_artifact(
    text: str,
    readings: Dict[str, Any],
    current: Dict[str, Any],
    progress: Callable[[float], None],
    simulated: bool = False,
) -> Dict[str, Any]:
    """A printed artifact's caliper readings against its program ``text`` (``simulated``:
    the readings are demo mode's, and the result says SIMULATED)."""
    from ..calibration.measurement import analyse_artifact_readings

    progress(0.1)
    return analyse_artifact_readings(text, readings, current, simulated)


TASKS = {
    "compensate": task_compensate,
    "analyse": task_analyse,
    "analyse_campaign": task_analyse_campaign,
    "analyse_artifact": task_analyse_artifact,
}


def lower_priority() -> None:
    """This process at the lowest CPU priority, and the lowest best-effort I/O priority
    where psutil can set it (not the idle class: on a busy machine that could starve the
    job for ever)."""
    try:
        os.nice(19 - os.nice(0))
    except (AttributeError, OSError):
        pass
    try:
        import psutil

        psutil.Process().ionice(psutil.IOPRIO_CLASS_BE, 7)
    except Exception:
        pass


def _stop(signum, frame):
    raise SystemExit(128 + signum)


def child_main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # stray prints must not break the protocol
    inp = sys.stdin.buffer
    parent = os.getppid()
    for sig in (signal.SIGTERM, signal.SIGINT, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            signal.signal(sig, _stop)
    lower_priority()

    def send(msg) -> None:
        try:
            pickle.dump(msg, out)
            out.flush()
        except (BrokenPipeError, OSError):
            raise SystemExit(1) from None

    while True:
        try:
            job_id, kind, args = pickle.load(inp)
        except (EOFError, OSError, pickle.UnpicklingError):
            return 0
        last = [0.0]

        def progress(frac: float, job_id=job_id, last=last) -> None:
            if os.getppid() != parent:
                raise SystemExit(1)  # orphaned: nobody wants the result
            now = time.monotonic()
            if now - last[0] >= PROGRESS_EVERY_S:
                last[0] = now
                send(("progress", job_id, float(frac)))

        try:
            result = TASKS[kind](progress=progress, **args)
        except Exception as exc:
            try:
                pickle.dumps(exc)
            except Exception:
                exc = RuntimeError(str(exc))
            send(("failed", job_id, exc))
        else:
            send(("done", job_id, result))


# ~~ the parent's handle ---------------------------------------------------------------------
class WorkerProcess:
    """The parent's end: starts the child when a job needs it, hands it one job at a time
    (``call``; from one thread only) and stops it (``stop``)."""

    def __init__(self, python: Optional[str] = None):
        self._python = python or sys.executable
        self._proc: Optional[subprocess.Popen] = None
        self._lock = threading.Lock()
        self.last_used = time.monotonic()
        self._job: Optional[str] = None  # the id of the job the child works on

    @property
    def pid(self) -> Optional[int]:
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    def _start(self) -> subprocess.Popen:
        if self._proc is not None and self._proc.poll() is None:
            return self._proc
        package_root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            [package_root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
        )
        self._proc = subprocess.Popen(
            [self._python, "-m", "octoprint_kincomp.service.files.worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
            close_fds=True,
        )
        return self._proc

    def call(
        self, job_id: str, kind: str, args: Dict[str, Any], progress: Callable[[float], None]
    ) -> Any:
        """Run one job in the child: its result, or its exception raised here
        (:class:`WorkerDied` if the child ended)."""
        with self._lock:
            proc = self._start()
            self.last_used = time.monotonic()
            self._job = job_id
            try:
                pickle.dump((job_id, kind, args), proc.stdin)
                proc.stdin.flush()
                while True:
                    what, _, value = pickle.load(proc.stdout)
                    if what == "progress":
                        progress(value)
                    else:
                        break
            except (EOFError, OSError, pickle.UnpicklingError):
                self._reap()
                raise WorkerDied("the worker process stopped in the middle of the job") from None
            except BaseException:
                # the job abandoned (the progress callback raised: cancelled): the child
                # ends (its partial file is removed), so the next job starts clean
                self.stop()
                raise
            finally:
                self._job = None
                self.last_used = time.monotonic()
        if what == "done":
            return value
        raise value  # the job's own error, raised in the child

    def _reap(self) -> None:
        proc, self._proc = self._proc, None
        if proc is None:
            return
        for f in (proc.stdin, proc.stdout):
            try:
                f.close()
            except OSError:
                pass
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)

    def stop(self) -> None:
        """End the child (its current file is removed by its SIGTERM handling)."""
        proc = self._proc
        if proc is not None and proc.poll() is None:
            try:
                proc.terminate()
            except OSError:
                pass
        self._reap()

    def abort(self, job_id: str) -> None:
        """Ends the child if it works on the job ``job_id`` (cancelled): SIGTERM, so its
        partial file is removed; ``call`` then raises :class:`WorkerDied`. At once, not at
        the job's next progress step: at nice 19 on a busy machine that can be long."""
        proc = self._proc
        if self._job == job_id and proc is not None and proc.poll() is None:
            try:
                proc.terminate()
            except OSError:
                pass

    def stop_if_idle(self, idle_s: float) -> None:
        """End the child if it has had no job for ``idle_s`` seconds (it holds memory)."""
        if (
            self._proc is not None
            and not self._lock.locked()
            and time.monotonic() - self.last_used > idle_s
        ):
            with self._lock:
                self._reap()  # end of its input: the child returns


class InProcessWorker:
    """The same calls, run in the calling thread (tests; where no child process can be
    started)."""

    pid = None

    def call(
        self, job_id: str, kind: str, args: Dict[str, Any], progress: Callable[[float], None]
    ) -> Any:
        return TASKS[kind](progress=progress, **args)

    def stop(self) -> None:
        pass

    def stop_if_idle(self, idle_s: float) -> None:
        pass


if __name__ == "__main__":
    sys.exit(child_main())
