"""The print's line rate under load, on a real server (``DevServer``, virtual printer,
throttle off): what the starvation checks (``tests/e2e/test_reliability.py``,
``tests/e2e/test_reliability_round4.py``) and ``scripts/load_probe.py`` measure.

A print streams a file of short moves as fast as the CPU lets it (:func:`fast_print`); its
rate is the count of numbered ``Send:`` lines in serial.log per second. A load runs in short
phases alternated with quiet ones (:func:`alternate`); each loaded phase is compared with the
quiet phases either side of it (the machine is shared and its speed drifts by the minute;
seconds apart it is the same), and the median of those ratios is the load's figure. In the
quiet phases KinComp's worker process is stopped (SIGSTOP): a nice-19 process gets next to
no CPU while the print streams, so jobs queued by a load would otherwise still run there.

A :class:`Load` is ``clients`` threads, each calling ``step(client)`` again and again on its
own keep-alive connection (:class:`Client`); ``step`` returns how long to wait before the
next call (0: a tight loop; the ``Retry-After`` of a 202 or 429, as KinComp's own page
does). Every answer's status is counted.
"""

from __future__ import annotations

import datetime
import http.client
import json
import os
import re
import signal
import statistics
import threading
import time
from typing import Callable, Dict, List, Optional, Tuple

from octoprint_kincomp.tools.devserver import multipart_body

SEND_TS = re.compile(rb"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) - Send: N\d+ ")
WORKER_MODULE = "octoprint_kincomp.service.files.worker"


def write_gcode(path: str, lines: int, move, first: str = "G1 Z0.3 F3000") -> None:
    """A G-code file: homing, modes, ``first``, then ``move(i)`` for i < ``lines``."""
    with open(path, "w") as f:
        f.write(f"G28\nG90\nM83\n{first}\n")
        f.writelines(move(i) for i in range(lines))


def fast_print(path: str, lines: int) -> None:
    """A print the virtual printer streams as fast as the CPU lets it: 0.05 mm moves at
    200 mm/s take it 25 us each (it simulates moves at ten times their speed), so the
    Send: rate measures the serial stream, not simulated motion."""
    write_gcode(
        path,
        lines,
        lambda i: f"G1 X{100 + (i % 2) * 0.05:.2f} Y{20 + (i // 2) % 8000 * 0.01:.2f} E0.001\n",
        first="G1 X100 Y20 Z0.3 F12000",
    )


def big_gcode(path: str, lines: int) -> None:
    """Slicer-like moves all over the bed (what a dry run chews on)."""
    write_gcode(
        path,
        lines,
        lambda i: (
            f"G1 X{20 + (i * 37) % 180}.{i % 10} Y{20 + (i * 53) % 180}.{i % 7} "
            f"E0.0{i % 9 + 1} F{1800 + i % 5 * 600} ; extrude {i}\n"
        ),
    )


class SendLog:
    """The times of the numbered ``Send:`` lines of a server's serial.log, read on from
    where the last call stopped (the log grows by megabytes a minute)."""

    def __init__(self, srv):
        self.path = os.path.join(srv.basedir, "logs", "serial.log")
        self._pos = 0
        self._rest = b""
        self.times: List[float] = []

    def read(self) -> List[float]:
        try:
            with open(self.path, "rb") as f:
                f.seek(self._pos)
                data = f.read()
        except OSError:
            return self.times
        self._pos += len(data)
        lines = (self._rest + data).split(b"\n")
        self._rest = lines.pop()
        cache: Dict[bytes, float] = {}
        for line in lines:
            m = SEND_TS.match(line)
            if m:
                stamp = m.group(1)
                t = cache.get(stamp)
                if t is None:
                    t = datetime.datetime.strptime(
                        stamp.decode(), "%Y-%m-%d %H:%M:%S,%f"
                    ).timestamp()
                    cache = {stamp: t}
                self.times.append(t)
        return self.times


def rate(times: List[float], t0: float, t1: float) -> float:
    import bisect

    return (bisect.bisect_left(times, t1) - bisect.bisect_left(times, t0)) / (t1 - t0)


def worker(srv, sig) -> None:
    """Send ``sig`` to KinComp's worker process, if it runs."""
    import psutil

    for child in psutil.Process(srv.proc.pid).children(recursive=True):
        try:
            if WORKER_MODULE in " ".join(child.cmdline()):
                child.send_signal(sig)
        except psutil.Error:
            pass


def job_state(srv) -> str:
    return srv.request("GET", "/api/job")[1]["state"]


def wait(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.time() + timeout
    while not predicate():
        if time.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


def start_print(srv, name: str) -> None:
    """Prints the stored file ``name`` and waits until it streams."""
    code, body = srv.request(
        "POST", f"/api/files/local/{name}", {"command": "select", "print": True}
    )
    assert code == 204, body
    wait(lambda: job_state(srv) == "Printing", 60, "the print")


def cancel_print(srv) -> None:
    if job_state(srv) != "Operational":
        srv.request("POST", "/api/job", {"command": "cancel"})
        wait(lambda: job_state(srv) == "Operational", 120, "the cancel")


class Client:
    """One keep-alive HTTP connection to the server (a browser tab's), as a user."""

    def __init__(self, srv, key: Optional[str] = "admin"):
        self.srv = srv
        self.headers = {}
        if key:
            self.headers["X-Api-Key"] = srv.logins[key]["apikey"] if key in srv.logins else key
        self._conn: Optional[http.client.HTTPConnection] = None

    def request(self, method: str, path: str, body=None, raw=None, content_type=None):
        """(status, parsed JSON or None, response headers)."""
        headers = dict(self.headers)
        data = raw
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        elif content_type:
            headers["Content-Type"] = content_type
        for attempt in (0, 1):
            if self._conn is None:
                self._conn = http.client.HTTPConnection("127.0.0.1", self.srv.port, timeout=120)
            try:
                self._conn.request(method, path, body=data, headers=headers)
                resp = self._conn.getresponse()
                text = resp.read()
                break
            except (OSError, http.client.HTTPException):
                self.close()
                if attempt:
                    return 0, None, {}
        try:
            parsed = json.loads(text) if text else None
        except ValueError:
            parsed = None
        return resp.status, parsed, dict(resp.getheaders())

    def upload(self, path: str, filename: str, data: bytes, fields=None):
        body, content_type = multipart_body(filename, data, fields)
        return self.request("POST", path, raw=body, content_type=content_type)

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def retry_after(code: int, headers: Dict[str, str], default: float = 1.0) -> float:
    """How long a client waits after an answer: nothing after a 2xx that is no 202, the
    ``Retry-After`` of a 202 or 429 (``default`` when it has none)."""
    if code in (202, 429, 503):
        try:
            return float(headers.get("Retry-After", default))
        except ValueError:
            return default
    return 0.0


class Load:
    """``clients`` threads, each calling ``step(client) -> seconds to wait`` in a loop
    while the load runs; ``codes`` counts the answers' statuses (``step`` returns them
    through :meth:`count`)."""

    def __init__(self, name: str, step, clients: int = 4, key: Optional[str] = "admin"):
        self.name = name
        self.step = step
        self.clients = clients
        self.key = key
        self.codes: Dict[int, int] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def pause(self, seconds: float) -> None:
        """Waits ``seconds``, less when the load stops meanwhile."""
        self._stop.wait(seconds)

    def count(self, code: int) -> None:
        with self._lock:
            self.codes[code] = self.codes.get(code, 0) + 1

    def _run(self, srv, k: int) -> None:
        client = Client(srv, self.key)
        try:
            while not self._stop.is_set():
                pause = self.step(self, client, k)
                if pause:
                    self._stop.wait(pause)
        finally:
            client.close()

    def start(self, srv) -> None:
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._run, args=(srv, k), daemon=True)
            for k in range(self.clients)
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=180)

    def requests(self) -> int:
        return sum(self.codes.values())

    def server_errors(self) -> int:
        return sum(n for c, n in self.codes.items() if c >= 500 or c == 0)


def alternate(
    srv,
    load: Load,
    log: SendLog,
    rounds: int = 3,
    phase_s: float = 4.0,
    warm_s: float = 1.0,
    busy: Optional[Callable[[], bool]] = None,
) -> Tuple[List[float], List[float], float]:
    """``rounds`` loaded phases of ``phase_s`` seconds, each between two quiet ones; the
    load starts ``warm_s`` before its phase is counted. ``busy()``, if given, must hold
    at the end of each loaded phase (the load really loaded). Returns the phases' rates
    (lines/s, quiet and loaded alternating), each loaded one's ratio to its quiet
    neighbours, and the median ratio."""
    phases = []

    def quiet() -> None:
        worker(srv, signal.SIGSTOP)
        t0 = time.time()
        time.sleep(phase_s)
        phases.append((t0, time.time()))
        worker(srv, signal.SIGCONT)

    try:
        for _ in range(rounds):
            quiet()
            load.start(srv)
            time.sleep(warm_s)
            t0 = time.time()
            time.sleep(phase_s)
            phases.append((t0, time.time()))
            if busy is not None:
                assert busy(), f"{load.name}: the load was not running during its phase"
            load.stop()
        quiet()
    finally:
        load.stop()
        worker(srv, signal.SIGCONT)
    time.sleep(1.5)  # serial.log is written a little behind
    times = log.read()
    rates = [rate(times, a, b) for a, b in phases]
    ratios = [rates[i] / ((rates[i - 1] + rates[i + 1]) / 2) for i in range(1, len(rates), 2)]
    return rates, ratios, statistics.median(ratios)
