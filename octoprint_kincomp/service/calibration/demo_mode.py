"""Demo mode on the OctoPrint side: the virtual ballbar (``simulator/demo.py``) while the
``demo.enabled`` setting is on (everything it measures is SIMULATED).

The last ballbar program KinComp wrote is remembered; when a print of it begins, the
commands leaving KinComp's queuing hook are recorded; when that print is done the simulator
runs on its own thread (seconds, never on OctoPrint's event thread) and the UI is told that
the simulated trace is ready (a campaign's test: its campaign and test are in the message, and
the campaign mode collects the trace). A print that fails or is cancelled drops the
recording.

The live path (``demo.live``, the default): the virtual ballbar is also a live sensor
(:class:`..sensor.virtual.VirtualSensor` on a pseudo-terminal, started when KinComp's
sensor piece asks for its port, stopped when it lets go). When the program's print begins,
the program as the printer receives it (compensated with the queue's parameters if
compensation is on) is played on it from that moment, DEMO_SPEEDUP times faster than the
simulated printer moves (as OctoPrint's virtual printer runs its moves), so that the capture
reads it through pyserial exactly as a USB bar. A program with a mount pause (a campaign's
test: ``M0``, or the firmware's own pause, to mount the bar and to unmount it) is played from
the moment the printer goes on after the mount pause (its first file line after the first
pause is queued:
OctoPrint queues nothing more of the file while paused), not while the printer waits there
for the bar. The recorded commands are still simulated after the print, for "Analyse the
simulated trace" and a campaign's "Use the simulated trace" (the fallbacks), without a
notice then: the live capture tells (a campaign's test is measured by its capture).
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Dict, Iterable, List, Optional, Tuple

from ...calibration.ballbar.formats import NativeTrace
from ...calibration.ballbar.program import ProgramError, TestSpec, generate, is_pause
from ...engines.select import make_compensator
from ...sensor.virtual import VirtualSensor
from ...simulator.demo import DemoBallbar
from ..notify import N_, Notifier
from ..printing.queue import FILE_TAG, command_of

DEMO_SPEEDUP = 10.0  # OctoPrint's virtual printer runs its moves 10 times faster than feed
DEMO_RANGE_MM = (-1.5, 2.5)  # the virtual bar's measuring range (mm, positive = longer)


def lines_as_sent(queue, text: str) -> List[str]:
    """The lines of ``text`` as the printer receives them from ``queue`` (a
    QueueCompensator): compensated by a fresh compensator with its parameters and options
    when compensation is on."""
    if not queue.enabled:
        return text.splitlines()
    comp = make_compensator(queue.params, queue.comp.options)
    out: List[str] = []
    for line in text.splitlines():
        res = comp.process(line)
        out.extend([res] if isinstance(res, str) else res)
    return out


class DemoMode:
    def __init__(self, notifier: Notifier, logger):
        self._notifier = notifier
        self._logger = logger
        self.ballbar: Optional[DemoBallbar] = None  # None: demo mode is off
        self._lock = threading.RLock()
        self._program_path: Optional[str] = None
        self._program_spec: Optional[TestSpec] = None
        self._program_hash = ""
        self.live = False  # the virtual ballbar streams as a live sensor
        self._sensor: Optional[VirtualSensor] = None
        self._played = False  # the current print is played on the live sensor
        self._simulating = False  # its stream is being simulated: its end is not known yet
        # (sensor, spec, program hash) to play once the printer goes on after the mount pause
        self._deferred: Optional[Tuple[VirtualSensor, TestSpec, str]] = None
        self._mount_seen = False  # the program's mount pause (M0) was queued
        # the program's lines as the printer receives them (the plugin compensates them)
        self.lines_as_sent: Callable[[str], List[str]] = str.splitlines

    def set_enabled(self, enabled: bool, live: bool = True) -> None:
        """Turns demo mode on (a fresh virtual ballbar, unless one is there) or off;
        ``live``: its readings stream as a live sensor."""
        if enabled and self.ballbar is None:
            self.ballbar = DemoBallbar()
        elif not enabled:
            self.ballbar = None
        self.live = bool(enabled and live)
        if not self.live:
            self.release_sensor()

    # ~~ the virtual ballbar as a live sensor ------------------------------------------------
    def sensor_port(self) -> Optional[str]:
        """The virtual ballbar's port (a pseudo-terminal, started now if it is not running);
        None when the live path is off."""
        demo = self.ballbar
        if not self.live or demo is None:
            return None
        with self._lock:
            if self._sensor is None:
                self._sensor = VirtualSensor(
                    demo.truth, speedup=DEMO_SPEEDUP, range_mm=DEMO_RANGE_MM
                )
                self._sensor.start()
            return self._sensor.url

    def release_sensor(self) -> None:
        """Stop the virtual ballbar's stream (nobody reads it any more)."""
        with self._lock:
            sensor, self._sensor = self._sensor, None
        if sensor is not None:
            sensor.stop()

    def stream_end(self) -> Optional[float]:
        """When (time.monotonic()) the program being played has been streamed; None if
        nothing is played; ``inf`` while its stream is still being simulated (a slow
        vertical test takes seconds: its end is not known yet; also while it waits for the
        printer to go on after the mount pause)."""
        sensor = self._sensor
        if sensor is None or not self._played:
            return None
        return float("inf") if self._simulating else sensor.program_end

    def _play(self, sensor: VirtualSensor, spec: TestSpec, prog_hash: str, start: float) -> None:
        """Simulate the program (about a second, on its own thread) and stream it from
        ``start`` on."""
        try:
            lines = self.lines_as_sent(generate(spec))
            sensor.play(lines, start, spec=spec, program_hash=prog_hash)
        except (ProgramError, OSError, ValueError):
            self._logger.exception("KinComp demo: the virtual ballbar could not play the program")
        finally:
            self._simulating = False

    def program_written(self, path: str, spec: TestSpec, program_hash: str) -> None:
        """KinComp wrote the ballbar program ``spec`` to ``path`` (in OctoPrint's storage)."""
        with self._lock:
            self._program_path = path
            self._program_spec = spec
            self._program_hash = program_hash

    def print_begins(self, payload: Dict[str, Any]) -> None:
        """A print begins (``payload``: origin and path): recorded if it is the program."""
        demo = self.ballbar
        if demo is None:
            return
        with self._lock:
            self._deferred = None
            if payload.get("path") != self._program_path or self._program_spec is None:
                self._played = False
                return
            spec = self._program_spec
            demo.start(spec, self._program_hash)
            sensor = self._sensor if self.live else None
            self._played = sensor is not None
            if sensor is None:
                return
            self._simulating = True  # (until _play has the stream: its end unknown)
            if spec.mount_pause:  # played when the printer goes on after the mount pause
                self._deferred, self._mount_seen = (sensor, spec, self._program_hash), False
            else:
                self._start_play(sensor, spec, self._program_hash)

    def _start_play(self, sensor: VirtualSensor, spec: TestSpec, prog_hash: str) -> None:
        threading.Thread(
            target=self._play,
            name="kincomp-demo-ballbar",
            daemon=True,
            args=(sensor, spec, prog_hash, time.monotonic()),
        ).start()

    def _file_line(self, cmd: str) -> None:
        """A line of the printed file is queued: the first one after the mount pause starts
        the deferred play (the printer goes on with the bar mounted)."""
        with self._lock:
            deferred = self._deferred
            if deferred is None:
                return
            if not self._mount_seen:
                self._mount_seen = is_pause(cmd)
                return
            self._deferred = None
        self._start_play(*deferred)

    def record(
        self, cmd: str, result: Optional[List[str]], tags: Optional[Iterable[str]] = None
    ) -> None:
        """What the queuing hook sends for ``cmd`` (``tags``: OctoPrint's, a line of the
        printed file has ``source:file``): ``result`` (None: ``cmd`` as it is). Recorded once
        here: in the sent phase resends would repeat lines."""
        demo = self.ballbar
        if demo is None:
            return
        if self._deferred is not None and tags and FILE_TAG in tags:
            self._file_line(cmd)
        if not demo.recording:
            return
        if result is None:
            demo.record(cmd)
        else:
            for line in result:
                demo.record(command_of(line))

    def print_ends(self, done: bool) -> None:
        """The print ended; ``done``: it completed (then the trace is simulated)."""
        with self._lock:
            if self._deferred is not None:  # ended before the printer went on: not played
                self._deferred, self._simulating = None, False
        demo = self.ballbar
        if demo is None or not demo.recording:
            return
        if not done:
            demo.cancel()
            return
        threading.Thread(
            target=self._simulate, args=(demo, self._played), name="kincomp-demo", daemon=True
        ).start()

    def last_trace(self) -> Optional[NativeTrace]:
        """The last simulated trace, if demo mode is on and one was made."""
        demo = self.ballbar
        return None if demo is None else demo.last_trace

    def _simulate(self, demo: DemoBallbar, played: bool) -> None:
        """Runs the simulator (seconds) on its own thread, not on OctoPrint's event thread;
        ``played``: the print was played on the live sensor (its capture tells the UI)."""
        try:
            trace = demo.finish()
        except Exception:
            self._logger.exception("KinComp demo: simulation failed")
            return
        if trace is None:
            return
        if played:  # the live capture tells (a campaign's test: it is its measurement)
            return
        meta = getattr(trace, "meta", None) or {}
        if meta.get("campaign"):  # a campaign's test: the campaign's wizard collects it
            self._notifier.message(
                {
                    "type": "demo_trace",
                    "campaign": meta["campaign"],
                    "campaign_step": meta.get("campaign_step"),
                }
            )
        else:
            self._notifier.notify(
                "success",
                N_("SIMULATED ballbar trace ready (demo mode): load it in the calibration tab."),
            )
            self._notifier.message({"type": "demo_trace"})
