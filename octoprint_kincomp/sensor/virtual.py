"""A virtual ballbar that streams SIMULATED readings like a USB sensor (demo and tests).

It writes the KinComp line protocol (or plain readings) to a pseudo-terminal (``os.openpty``,
opened by pyserial as a device path) or to a loopback TCP socket (``socket://127.0.0.1:PORT``),
in real time or ``speedup`` times faster, so that KinComp reads it exactly as a USB device.

``play(lines, start_time)`` gives it the G-code lines the virtual printer executes (as the
printer receives them: comments stripped, line numbers, compensated or not) and the host time
(``time.monotonic()``) at which the printer starts on them (a time that passed while the
simulator ran is replaced by the next sample: the program starts late rather than
skipping). The readings come from the ballbar simulator (``simulator/printer.py``, with the
printer's hidden errors of ``truth``): sample ``n`` of the simulated program goes out at
``start_time + n / (rate * speedup)`` with
device clock ``n / rate`` after the program start. Before the program and after it, the bar
holds its reading (with fresh noise); before any program it reads ``idle_mm``. Readings are
mm, positive = bar longer, unless ``units``/``longer_positive`` ask for another convention.
The device clock is a 32-bit microsecond counter starting at ``clock_start_us`` (so tests can
cross its wrap); the header block is repeated every ``header_every_s`` of device time. With
``range_mm`` (low, high in mm, positive = longer) the header declares the bar's measuring
range (in the units and sign it sends).
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time
import tty
from typing import List, Optional, Sequence

import numpy as np

from ..calibration.ballbar.formats import NativeTrace
from ..calibration.ballbar.program import TestSpec
from ..simulator.demo import demo_truth
from ..simulator.printer import Truth, simulate_program
from .convention import UNITS
from .protocol_kincomp import NAME, US32, VERSION

MAX_PENDING = 1 << 18  # bytes held for a slow reader; older whole lines are dropped
TICK_S = 0.005


class VirtualSensor:
    def __init__(
        self,
        truth: Optional[Truth] = None,
        transport: str = "pty",
        protocol: str = "kincomp",
        speedup: float = 1.0,
        idle_mm: float = 1.0,
        clock_start_us: int = 0,
        header_every_s: float = 2.0,
        units: str = "mm",
        longer_positive: bool = True,
        seed: int = 7,
        range_mm: Optional[Sequence[float]] = None,
    ):
        if transport not in ("pty", "tcp") or protocol not in ("kincomp", "plain"):
            raise ValueError("transport is 'pty' or 'tcp', protocol 'kincomp' or 'plain'")
        self.truth = truth or demo_truth()
        self.transport, self.protocol = transport, protocol
        self.speedup = float(speedup)
        self.rate = float(self.truth.sample_rate_hz)
        self.idle_mm = idle_mm
        self.clock_start_us = int(clock_start_us)
        self.header_every_s = header_every_s
        self.units, self.longer_positive = units, longer_positive
        self._factor = (1.0 if longer_positive else -1.0) / UNITS[units]
        self._decimals = {"mm": 6, "um": 3, "inch": 7}[units]
        self.range_mm = tuple(range_mm) if range_mm is not None else None
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._program = None  # (k0, readings by sample from k0)
        self._k = 0  # next sample to send
        self._inject = bytearray()
        self._pending = bytearray()
        self._running = False
        self._thread: Optional[threading.Thread] = None
        self._fd = self._slave = None
        self._server = self._client = None
        self.url = ""
        self.sent_lines = 0
        self.dropped_bytes = 0
        self.program_end: Optional[float] = (
            None  # host time when the program's last sample goes out
        )

    # ---- transport ------------------------------------------------------------------------

    def start(self) -> str:
        """Open the pty or socket and start streaming; returns the pyserial URL/path."""
        if self.transport == "pty":
            self._fd, self._slave = os.openpty()
            tty.setraw(self._slave)
            os.set_blocking(self._fd, False)
            self.url = os.ttyname(self._slave)
        else:
            self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._server.bind(("127.0.0.1", 0))
            self._server.listen(1)
            self._server.setblocking(False)
            self.url = "socket://127.0.0.1:%d" % self._server.getsockname()[1]
        self._epoch = time.monotonic()
        self._running = True
        self._thread = threading.Thread(
            target=self._loop, name="kincomp-virtual-ballbar", daemon=True
        )
        self._thread.start()
        return self.url

    def _write(self, data: bytes) -> None:
        self._pending += data
        if len(self._pending) > MAX_PENDING:  # nobody reads: drop the oldest whole lines
            cut = self._pending.find(b"\n", len(self._pending) - MAX_PENDING) + 1
            self.dropped_bytes += cut
            del self._pending[:cut]
        if self.transport == "tcp":
            self._accept()
            if self._client is None:
                self.dropped_bytes += len(self._pending)
                self._pending.clear()
                return
        try:
            if self.transport == "pty":
                n = os.write(self._fd, bytes(self._pending))
            else:
                n = self._client.send(bytes(self._pending))
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # the reader went away
            if self.transport == "tcp":
                self._client.close()
                self._client = None
            self._pending.clear()
            return
        del self._pending[:n]

    def _accept(self) -> None:
        if self._client is not None:
            return
        try:
            self._client, _ = self._server.accept()
            self._client.setblocking(False)
            self._pending.clear()  # a fresh connection starts with fresh data
        except (BlockingIOError, InterruptedError):
            pass

    def unplug(self) -> None:
        """Pull the plug: the pty (or socket) closes under the reader, mid-stream."""
        self._running = False
        if self._thread is not None:
            self._thread.join(2.0)
        for closer in (self._close_fd, self._close_sockets):
            closer()

    stop = unplug

    def _close_fd(self) -> None:
        for name in ("_fd", "_slave"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    def _close_sockets(self) -> None:
        for name in ("_client", "_server"):
            sock = getattr(self, name)
            if sock is not None:
                sock.close()
                setattr(self, name, None)

    def inject(self, data: bytes) -> None:
        """Raw bytes to send next (garbage, floods, partial lines: for fault tests)."""
        with self._lock:
            self._inject += data

    # ---- the program ----------------------------------------------------------------------

    def play(
        self,
        lines: Sequence[str],
        start_time: Optional[float] = None,
        spec: Optional[TestSpec] = None,
        program_hash: str = "",
    ) -> NativeTrace:
        """Simulate the printer executing ``lines`` from ``start_time`` (host monotonic s;
        default now) and stream the bar's readings at their times. Runs the simulator in the
        caller's thread (about a second); returns the simulated trace (the offline stream).
        Raises the simulator's ProgramError when the lines hold no ballbar runs."""
        trace = simulate_program("\n".join(lines) + "\n", self.truth, spec, program_hash)
        t = np.array([row[1] for row in trace.rows])
        r = np.array([row[2] for row in trace.rows])
        order = np.argsort(t, kind="stable")
        j = np.rint(t[order] * self.rate).astype(np.int64)
        readings = np.interp(np.arange(j[0], j[-1] + 1), j, r[order])
        start = time.monotonic() if start_time is None else start_time
        k0 = int(math.ceil((start - self._epoch) * self.speedup * self.rate))
        with self._lock:
            # a start that has passed while simulating begins now: skipping the program's
            # first samples would make the bar jump
            k0 = max(k0, self._k + 1) + int(j[0])
            self._program = (k0, readings)
        self.program_end = self._epoch + (k0 + len(readings)) / (self.rate * self.speedup)
        return trace

    def _reading(self, k: int) -> float:
        prog = self._program
        noise = self.truth.noise_um * 1e-3
        if prog is None:
            return self.idle_mm + self._rng.normal(0.0, noise) if noise else self.idle_mm
        k0, readings = prog
        i = k - k0
        if 0 <= i < len(readings):
            return float(readings[i])
        held = readings[0] if i < 0 else readings[-1]
        return float(held + (self._rng.normal(0.0, noise) if noise else 0.0))

    def header(self) -> List[str]:
        return [
            f"{NAME} {VERSION}",
            "# sensor: KinComp virtual ballbar (SIMULATED)",
            f"# units: {self.units}",
            f"# positive: {'longer' if self.longer_positive else 'shorter'}",
            f"# sample_rate_hz: {self.rate:g}",
            "# resolution_um: 0.001",
            "# simulated: true",
        ] + self._range_line()

    def _range_line(self) -> List[str]:
        if self.range_mm is None:
            return []
        lo, hi = sorted(v * self._factor for v in self.range_mm)
        return [f"# range: {lo:g},{hi:g}"]

    def _loop(self) -> None:
        k = self._k = 0
        next_header = 0.0
        period_us = 1e6 / self.rate
        while self._running:
            now_dev = (time.monotonic() - self._epoch) * self.speedup
            out: List[str] = []
            with self._lock:
                while k / self.rate <= now_dev and len(out) < 50_000:
                    if self.protocol == "kincomp" and k / self.rate >= next_header:
                        out.extend(self.header())
                        next_header = k / self.rate + self.header_every_s
                    value = f"{self._reading(k) * self._factor:.{self._decimals}f}"
                    if self.protocol == "kincomp":
                        t_us = (self.clock_start_us + int(round(k * period_us))) % US32
                        out.append(f"{t_us},{value}")
                    else:
                        out.append(value)
                    k += 1
                self._k = k
                injected, self._inject = bytes(self._inject), bytearray()
            self.sent_lines += len(out)
            data = ("\n".join(out) + "\n").encode("ascii") if out else b""
            try:
                self._write(data + injected)
            except OSError:
                return
            time.sleep(TICK_S)
