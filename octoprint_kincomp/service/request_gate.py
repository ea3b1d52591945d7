"""KinComp's requests rationed while a print runs (no OctoPrint import): every request to
the plugin's routes (reads such as ``/status``, ``/runs``, ``/campaigns``,
``/sensor/status``, ``/jobs/<id>``; uploads, analyses, everything else) passes
:meth:`RequestGate.admit` before it is answered.

Why: OctoPrint serves every request in the process that streams the print, and a request
costs that process several milliseconds of its interpreter however little it asks for;
the serial send loop hands each line on between threads, and a thread that has to wait for
the interpreter lock behind a busy one loses up to the switch interval each time. Four
clients reading KinComp's status in a tight loop left the print 17 % of its quiet line rate
(OctoPrint's own ``/api/version`` read so: 38 %; docs/reliability.md), and a request
refused at once (a 409 asked again and again) costs as much. So while a print runs:

* each client (the caller names it: the plugin takes a user's scripts, by API key, and its
  pages, by login, apart) gets ``per_user_rate`` requests a second after a burst of
  ``per_user_burst``, and all together ``rate`` after ``burst`` (token buckets; a page
  loading asks for a handful at once, which passes at once; KinComp's page reads on
  events, it never polls);
* a request beyond its ration waits for its turn, sleeping (the print's threads have the
  interpreter meanwhile), when its turn comes within ``max_wait_s`` and fewer than
  ``max_waiting`` requests wait already (each holds one of OctoPrint's few request threads);
* else it is refused: :meth:`admit` returns the seconds until its turn, which the route
  answers as 429 with ``Retry-After``. A client that waits as told is served at the ration;
  one that asks again at once costs what any refused request costs OctoPrint.

With no print running nothing is rationed (there is nothing to starve). The heavy work of a
request (an analysis, a dry run) is a job of the low-priority worker process under the job
queue's own quotas (``service/files/jobs.py``); this ration is about the requests themselves.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable, Dict, Optional, Tuple

PER_USER_RATE = 2.0  # requests a second, each user, while a print runs
PER_USER_BURST = 10.0
RATE = 4.0  # requests a second, all users together
BURST = 20.0
MAX_WAIT_S = 2.0  # a request waits for its turn at most this long ...
MAX_WAITING = 2  # ... and at most this many wait at once


class _Bucket:
    __slots__ = ("rate", "burst", "tokens", "at")

    def __init__(self, rate: float, burst: float, now: float):
        self.rate, self.burst, self.tokens, self.at = rate, burst, burst, now

    def fill(self, now: float) -> None:
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now

    def delay(self) -> float:
        """Seconds until one token is there (0: now)."""
        return 0.0 if self.tokens >= 1.0 else (1.0 - self.tokens) / self.rate


class RequestGate:
    """The ration of requests while ``active()`` holds (a print runs)."""

    def __init__(
        self,
        active: Callable[[], bool],
        per_user_rate: float = PER_USER_RATE,
        per_user_burst: float = PER_USER_BURST,
        rate: float = RATE,
        burst: float = BURST,
        max_wait_s: float = MAX_WAIT_S,
        max_waiting: int = MAX_WAITING,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self._active = active
        self._user = (per_user_rate, per_user_burst)
        self._all = (rate, burst)
        self.max_wait_s = max_wait_s
        self.max_waiting = max_waiting
        self._clock = clock
        self._sleep = sleep
        self._lock = threading.Lock()
        self._users: Dict[str, _Bucket] = {}
        self._total: Optional[_Bucket] = None
        self.waiting = 0
        self.refused = 0  # requests refused so far

    def _buckets(self, user: str, now: float) -> Tuple[_Bucket, _Bucket]:
        if self._total is None:
            self._total = _Bucket(*self._all, now)
        mine = self._users.get(user)
        if mine is None:
            if len(self._users) > 1000:  # (names come from logins; bounded anyway)
                self._users.clear()
            mine = self._users[user] = _Bucket(*self._user, now)
        return mine, self._total

    def admit(self, user: Optional[str]) -> Optional[float]:
        """None: the request may be answered (after waiting for its turn, if it had to);
        else the seconds until its turn (answer 429 with that ``Retry-After``)."""
        if not self._active():
            return None
        with self._lock:
            now = self._clock()
            buckets = self._buckets(user or "", now)
            for b in buckets:
                b.fill(now)
            wait = max(b.delay() for b in buckets)
            if wait > 0 and (wait > self.max_wait_s or self.waiting >= self.max_waiting):
                self.refused += 1
                return float(max(1, math.ceil(wait)))
            for b in buckets:
                b.tokens -= 1.0  # (below 0: the turn is reserved, later reads wait longer)
            if wait > 0:
                self.waiting += 1
        if wait > 0:
            try:
                self._sleep(wait)
            finally:
                with self._lock:
                    self.waiting -= 1
        return None
