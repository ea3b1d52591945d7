"""Live ballbar capture: one sensor port read in its own thread.

States (``Capture.state``)::

    idle -> preview -> armed -> capturing -> done
                \\-------\\--------\\---------> failed

* ``idle``: not opened yet. ``open()`` starts the thread, which opens the port.
* ``preview``: the port is open and read; the live view (current reading, a moving chart,
  noise in um) is up to date; nothing is recorded.
* ``armed``: ``arm(spec)`` was called: samples are recorded (only the last ``pre_keep_s``
  seconds, at least 2 dwells + 1 s, while no run has begun), the runs are looked for in the
  data every ``tick_s``.
* ``capturing``: the first run's feed-in (after a still dwell) has been seen.
* ``done``: every run and the dwell after the last one were seen: ``result.trace`` is the
  native trace, ``result.stream`` the raw stream. The port stays open (live view goes on).
* ``failed``: ``result.message`` says why; whatever was recorded is kept in
  ``result.stream``. Port-level faults (cannot open, unplugged, read error, a stream of
  mostly bad lines) close the port; capture-level ones (no data for ``no_data_timeout_s``,
  more than ``max_samples``, longer than ``max_duration_s``, ``stop()`` before the end)
  keep it open. More than 20,000 lines/s, sustained beyond a second's backlog, is a flood
  (``FloodWatch``): it closes the port in any state, so a runaway sensor cannot hog the
  host's CPU, while lines held up by a busy host and then read at once are no flood. A
  port-level fault while nothing is armed gives ``failed`` with ``status()["message"]`` and
  no new result.

Readings are mm, positive = bar longer; times s. Thread safety: every public method only
takes a short lock and returns at once (no I/O; only ``close(wait_s>0)`` and ``wait()`` wait,
when asked to), so OctoPrint's comm thread and queuing hook can call them; the reading, parsing,
run detection and trace building happen in the capture's thread. ``listener(kind, status)``
is called from that thread (``kind`` = ``"state"`` on every state change, ``"tick"`` about
every ``tick_s`` while the port is open) and must return quickly. A capture never changes
any parameter: it only produces data.
"""

from __future__ import annotations

import threading
import time
from array import array
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import numpy as np

from ..calibration.ballbar.formats import NativeTrace
from ..calibration.ballbar.program import TestSpec
from ..core.messages import Msg
from .config import SensorConfig
from .live import LiveView
from .ports import open_port, read_some
from .run_detection import detect_runs, program_seconds
from .sensor_error import SensorError
from .stream import RawStream, trace_from_stream

IDLE, PREVIEW, ARMED, CAPTURING, DONE, FAILED = (
    "idle",
    "preview",
    "armed",
    "capturing",
    "done",
    "failed",
)
STATES = (IDLE, PREVIEW, ARMED, CAPTURING, DONE, FAILED)
DEFAULT_MAX_SAMPLES = 1_000_000
PRE_KEEP_S = 30.0
MAX_LINE_RATE = 20_000  # lines/s: more is a flood (a 10 kHz sensor stays well below)
BACKLOG_S = 1.0  # s of lines at MAX_LINE_RATE that a burst may bring before it is a flood


class FloodWatch:
    """Tells a flood (a sensor sending more than ``MAX_LINE_RATE`` lines/s, sustained) from a
    backlog (lines held up by a busy host or a stalled sender, then delivered at once).

    A leaky bucket: every line arriving fills it by one, it drains at ``MAX_LINE_RATE``
    lines/s, and it holds ``MAX_LINE_RATE * BACKLOG_S`` lines. A flood overfills it (50,000
    lines/s in 0.67 s, 25,000 lines/s in 4 s); a sensor at its normal rate that catches up
    on a second it could not send does not. ``update(now_s, lines)`` takes the host time
    (monotonic s) and the count of lines received so far; it returns the flood's rate (lines/s
    since the bucket was last empty) once it overflows, else None."""

    def __init__(self, now_s: float, lines: int) -> None:
        self._t, self._lines = now_s, lines
        self._level = 0.0
        self._filling_since, self._lines_then = now_s, lines

    def update(self, now_s: float, lines: int) -> Optional[float]:
        drained = MAX_LINE_RATE * max(0.0, now_s - self._t)
        self._level += (lines - self._lines) - drained
        self._t, self._lines = now_s, lines
        if self._level <= 0.0:
            self._level = 0.0
            self._filling_since, self._lines_then = now_s, lines
            return None
        if self._level <= MAX_LINE_RATE * BACKLOG_S:
            return None
        return (lines - self._lines_then) / max(now_s - self._filling_since, 1e-3)


@dataclass
class CaptureResult:
    ok: bool
    message: Optional[str]  # Msg: why it failed; None when done
    trace: Optional[NativeTrace]  # the native trace (done only)
    stream: Optional[RawStream]  # all recorded samples (also when failed)
    spec: TestSpec
    program_hash: str
    diagnostics: Dict[str, object] = field(default_factory=dict)
    runs: List[Dict[str, object]] = field(default_factory=list)
    armed_at: float = 0.0  # wall clock (time.time())
    ended_at: float = 0.0


class _Recording:
    """The samples of one armed capture (only the capture thread touches it)."""

    def __init__(
        self, spec: TestSpec, program_hash: str, max_duration_s: float, max_samples: int, now: float
    ):
        self.spec, self.program_hash = spec, program_hash
        self.max_duration_s, self.max_samples = max_duration_s, max_samples
        self.t, self.mm, self.line = array("d"), array("d"), array("q")
        self.armed_host = now
        self.armed_wall = time.time()
        self.last_sample_host = now
        self.next_check = now
        self.started = False
        self.runs_found = 0

    def add(self, samples) -> None:
        for s in samples:
            self.t.append(s.t)
            self.mm.append(s.mm)
            self.line.append(s.seq)

    def detect(self, rate_hz: float):
        """The runs in what was recorded (times from a declared rate if given)."""
        if rate_hz:  # the declared rate beats host arrival times
            t = np.array(self.line, dtype=float) / rate_hz
        else:
            t = np.frombuffer(self.t, dtype=float)
        return detect_runs(t, np.frombuffer(self.mm, dtype=float), self.spec)

    def drop_older(self, keep_s: float) -> None:
        if len(self.t) and self.t[-1] - self.t[0] > 1.5 * keep_s:
            k = int(np.searchsorted(np.frombuffer(self.t, dtype=float), self.t[-1] - keep_s))
            del self.t[:k], self.mm[:k], self.line[:k]

    def stream(self, info: Dict[str, str]) -> Optional[RawStream]:
        if not len(self.t):
            return None
        t = np.array(self.t, dtype=float)
        t = np.round(t - t[0], 6)  # 1 us, as saved: a saved stream gives the same trace
        return RawStream(
            dict(info), t, np.array(self.mm, dtype=float), np.array(self.line, dtype=np.int64)
        )


class Capture:
    def __init__(
        self,
        config: SensorConfig,
        listener: Optional[Callable[[str, Dict[str, object]], None]] = None,
        opener: Callable = open_port,
        tick_s: float = 0.5,
        pre_keep_s: float = PRE_KEEP_S,
    ):
        config.validate()
        self.config = config
        self.listener = listener
        self._opener = opener
        self.tick_s = tick_s
        self.pre_keep_s = pre_keep_s
        self._lock = threading.Lock()
        self._thread: Optional[threading.Thread] = None
        self._closing = False
        self._ending = False  # the thread has left its loop and is shutting down
        self._restart = False  # open()/arm() came while it was shutting down
        self._state = IDLE
        self._message: Optional[str] = None
        self._port_open = False
        self._live = LiveView()
        self._arm_request: Optional[dict] = None
        self._stop_request = False
        self._rec: Optional[_Recording] = None
        self._result: Optional[CaptureResult] = None
        self._snapshot: Dict[str, object] = {
            "sensor": {},
            "diagnostics": {},
            "samples": 0,
            "elapsed_s": None,
            "runs_found": 0,
        }

    # ---- public, thread-safe, never blocking ---------------------------------------------

    @property
    def state(self) -> str:
        return self._state

    @property
    def result(self) -> Optional[CaptureResult]:
        """The last finished capture (done or failed), or None."""
        return self._result

    def open(self) -> None:
        """Open the port in the capture thread (live preview); no-op if already open."""
        with self._lock:
            self._closing = False
            if self._thread is None:
                self._start_locked()
            elif self._ending:
                self._restart = True  # the ending thread starts a new one when it is gone

    def _start_locked(self) -> None:
        self._message = None
        self._ending = self._restart = False
        self._thread = threading.Thread(target=self._run, name="kincomp-sensor", daemon=True)
        self._thread.start()

    def arm(
        self,
        spec: TestSpec,
        program_hash: str = "",
        max_duration_s: Optional[float] = None,
        max_samples: int = DEFAULT_MAX_SAMPLES,
    ) -> None:
        """Record from now on and stop when the program's end is seen in the data.

        Opens the port if needed. ``max_duration_s`` defaults to 3 x the program's time at
        its feed + 300 s (for a mount pause). Raises SensorError if a capture is running."""
        if max_duration_s is None:
            max_duration_s = 3.0 * program_seconds(spec) + 300.0
        with self._lock:
            if self._state in (ARMED, CAPTURING) or self._arm_request is not None:
                raise SensorError(Msg("a capture is already running"))
            self._arm_request = dict(
                spec=spec,
                program_hash=program_hash,
                max_duration_s=float(max_duration_s),
                max_samples=int(max_samples),
            )
            self._stop_request = False
        self.open()

    def stop(self) -> None:
        """End the running capture now: done if the program's end is in the data, else
        failed with the partial data kept. No-op when nothing is armed."""
        with self._lock:
            if self._arm_request is not None:
                self._arm_request = None
            elif self._state in (ARMED, CAPTURING):
                self._stop_request = True

    def close(self, wait_s: float = 0.0) -> None:
        """Stop the thread and close the port (a running capture ends as failed)."""
        with self._lock:
            self._closing = True
            self._restart = False
            thread = self._thread
        if wait_s and thread is not None and thread is not threading.current_thread():
            thread.join(wait_s)

    def status(self) -> Dict[str, object]:
        """JSON-ready state for the UI (messages are core.messages.Msg strings)."""
        with self._lock:
            out = dict(self._snapshot)
            out.update(self._status_locked())
        return out

    def live(self, seconds: float = 10.0, max_points: int = 400) -> Dict[str, object]:
        """The moving chart: {"t": [s before now], "mm": [...]} plus reading and noise."""
        now = time.monotonic()
        with self._lock:
            chart = self._live.chart(now, seconds, max_points)
            chart.update(self._status_locked())
        return chart

    def wait(self, states, timeout_s: float) -> str:
        """Poll until the state is one of ``states`` or the timeout (for tools and tests)."""
        end = time.monotonic() + timeout_s
        while self._state not in states and time.monotonic() < end:
            time.sleep(0.02)
        return self._state

    def _status_locked(self) -> Dict[str, object]:
        live = self._live
        age = None if live.last_host_t is None else time.monotonic() - live.last_host_t
        return {
            "state": self._state,
            "message": self._message,
            "port": self.config.port,
            "port_open": self._port_open,
            "protocol": self.config.protocol,
            "reading_mm": live.reading_mm,
            "noise_um": live.noise_um(),
            "last_data_age_s": age,
        }

    # ---- the capture thread ---------------------------------------------------------------

    def _set(self, state: str, message: Optional[str] = None, **kw) -> None:
        with self._lock:
            self._state = state
            self._message = message
            for k, v in kw.items():
                setattr(self, k, v)
            status = dict(self._snapshot)
            status.update(self._status_locked())
        self._emit("state", status)

    def _emit(self, kind: str, status: Dict[str, object]) -> None:
        if self.listener is None:
            return
        try:
            self.listener(kind, status)
        except Exception:
            pass

    def _run(self) -> None:
        try:
            port = self._opener(self.config.port, self.config.baudrate)
        except Exception as exc:
            message = (
                exc.message
                if isinstance(exc, SensorError)
                else Msg(
                    "cannot open %(port)s: %(error)s", port=self.config.port, error=str(exc)[:200]
                )
            )
            self._port_failed(message, None)
            self._exit()
            return
        parser = self.config.make_parser()
        self._set(PREVIEW, None, _port_open=True)
        next_tick = opened = time.monotonic()
        flood = None  # watched from the end of the first second (it may hold a backlog)
        try:
            while not self._closing:
                try:
                    data = read_some(port)
                except Exception as exc:
                    self._port_failed(
                        Msg(
                            "the sensor was disconnected or the port failed: %(error)s",
                            error=str(exc)[:200],
                        ),
                        parser,
                    )
                    return
                now = time.monotonic()
                if not self._step(parser, data, now):
                    return
                if flood is None:
                    if now - opened >= 1.0:
                        flood = FloodWatch(now, parser.seq)
                else:
                    rate = flood.update(now, parser.seq)
                    if rate is not None:  # would hog the host's CPU
                        self._port_failed(
                            Msg(
                                "the sensor floods the port: %(rate)s lines/s (at most %(max)s)",
                                rate=f"{rate:.0f}",
                                max=MAX_LINE_RATE,
                            ),
                            parser,
                        )
                        return
                if now >= next_tick:
                    next_tick = now + self.tick_s
                    self._publish(parser)
                    self._emit("tick", self.status())
            self._port_failed(None, parser)
        except SensorError as exc:
            self._port_failed(exc.message, parser)
        except Exception as exc:
            self._port_failed(
                Msg("internal error in the sensor capture: %(error)s", error=repr(exc)[:200]),
                parser,
            )
        finally:
            try:
                port.close()
            except Exception:
                pass
            self._exit()

    def _exit(self) -> None:
        """The thread ends: start the next one if open() or arm() asked meanwhile."""
        with self._lock:
            self._thread = None
            if self._restart and not self._closing:
                self._start_locked()

    def _publish(self, parser) -> None:
        rec = self._rec
        snap = {
            "sensor": parser.info(),
            "diagnostics": parser.diagnostics.as_dict(),
            "samples": len(rec.t) if rec else 0,
            "elapsed_s": (time.monotonic() - rec.armed_host) if rec else None,
            "runs_found": rec.runs_found if rec else 0,
        }
        with self._lock:
            self._snapshot = snap

    def _step(self, parser, data: bytes, now: float) -> bool:
        """Handle one read; False when the thread must end."""
        with self._lock:
            arm, self._arm_request = self._arm_request, None
            stop, self._stop_request = self._stop_request, False
        if arm is not None:
            parser.diagnostics.reset()
            self._rec = _Recording(now=now, **arm)
            self._result = None
            self._publish(parser)
            self._set(ARMED)
        samples = parser.feed(data, now) if data else []
        with self._lock:
            for s in samples:
                self._live.add(now, s.mm)
        rec = self._rec
        if rec is None:
            fatal = parser.diagnostics.fatal(total_limit=False)
            if fatal:
                self._port_failed(fatal, parser)
                return False
            return True
        rec.add(samples)
        if samples:
            rec.last_sample_host = now
        fatal = parser.diagnostics.fatal(total_limit=True)
        if fatal:
            self._port_failed(fatal, parser)
            return False
        cfg = self.config
        if stop:
            self._evaluate(parser, Msg("stopped before the end of the program was seen"))
        elif now - rec.last_sample_host > cfg.no_data_timeout_s:
            self._end(parser, _no_data(parser, cfg.no_data_timeout_s))
        elif len(rec.t) > rec.max_samples:
            self._end(
                parser,
                Msg(
                    "more than %(n)s samples: the sensor floods or the program's end was not seen",
                    n=rec.max_samples,
                ),
            )
        elif now - rec.armed_host > rec.max_duration_s:
            self._evaluate(
                parser,
                Msg(
                    "the end of the program was not seen within %(s)s s",
                    s=f"{rec.max_duration_s:g}",
                ),
            )
        elif now >= rec.next_check and samples:
            rec.next_check = now + self.tick_s
            self._check(parser, rec)
        return True

    def _check(self, parser, rec: _Recording) -> None:
        rate = self.config.sample_rate_hz if not parser.device_clock else 0.0
        det = rec.detect(rate)
        rec.runs_found = len(det.runs)
        if det.complete:
            self._evaluate(parser, None)
            return
        if det.started and not rec.started:
            rec.started = True
            self._set(CAPTURING)
        if not rec.started:  # keep what the first run's dwell needs, however long the wait
            rec.drop_older(max(self.pre_keep_s, 2.0 * rec.spec.dwell_s + 1.0))

    def _evaluate(self, parser, failure: Optional[str]) -> None:
        """Build the trace from what was recorded: done, or failed with ``failure``."""
        rec = self._rec
        stream = rec.stream(self._info(parser))
        if stream is None:
            self._end(parser, failure or Msg("no data"))
            return
        try:
            trace, det = trace_from_stream(
                stream, rec.spec, rec.program_hash, self.config.sample_rate_hz or None
            )
        except SensorError as exc:
            reason = (
                exc.message
                if failure is None
                else Msg("%(failure)s (%(reason)s)", failure=failure, reason=exc.message)
            )
            self._end(parser, reason, stream)
            return
        runs = [
            {
                "direction": r.direction,
                "feed_in_s": r.t_in - det.t_ref,
                "feed_out_s": r.t_out - det.t_ref,
                "samples": r.i1 - r.i0,
            }
            for r in det.runs
        ]
        self._finish(
            parser, CaptureResult(True, None, trace, stream, rec.spec, rec.program_hash, runs=runs)
        )

    def _info(self, parser) -> Dict[str, str]:
        """The stream's metadata: the sensor's, and where it came from."""
        info = parser.info() if parser is not None else {}
        name = info.get("sensor_name", self.config.protocol)
        info["source"] = f"live capture: {name} on {self.config.port}"
        if info.get("simulated") == "true":
            info["source"] = "SIMULATED " + info["source"]
        return info

    def _end(
        self, parser, message: str, stream: Optional[RawStream] = None, close: bool = False
    ) -> None:
        rec = self._rec
        if stream is None:
            stream = rec.stream(self._info(parser))
        self._finish(
            parser, CaptureResult(False, message, None, stream, rec.spec, rec.program_hash), close
        )

    def _finish(self, parser, result: CaptureResult, close: bool = False) -> None:
        rec = self._rec
        if parser is not None:
            result.diagnostics = parser.diagnostics.as_dict()
        result.armed_at, result.ended_at = rec.armed_wall, time.time()
        self._rec = None
        if parser is not None:
            self._publish(parser)
        with self._lock:
            self._result = result
        extra = {"_port_open": False} if close else {}
        self._set(DONE if result.ok else FAILED, result.message, **extra)

    def _port_failed(self, message: Optional[str], parser) -> None:
        """The port is gone (or closed): a running capture fails with its data kept."""
        with self._lock:
            self._ending = True
            arm, self._arm_request = self._arm_request, None
        if self._rec is None and arm is not None:  # armed, but the port never opened
            self._rec = _Recording(now=time.monotonic(), **arm)
        if self._rec is not None:
            self._end(
                parser, message or Msg("the sensor port was closed during the capture"), close=True
            )
            return
        if message is None:
            self._set(IDLE, None, _port_open=False)
        else:
            self._set(FAILED, message, _port_open=False)


def _no_data(parser, seconds: float) -> str:
    if getattr(parser, "waiting_for_header", 0):
        return Msg(
            "samples arrive but no %(name)s header line: the sensor must send its "
            "header at least every 5 s",
            name="KINCOMP-BALLBAR",
        )
    return Msg(
        "no data from the sensor for %(s)s s: check the port, the baud rate and the sensor's power",
        s=f"{seconds:g}",
    )
