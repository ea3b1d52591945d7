"""The live view of a sensor: the current reading, a short moving chart and the noise level.

A fixed-size ring buffer of the last samples (time in s on the host's clock, reading in mm,
positive = bar longer), so memory stays bounded however long the port is open. The noise
level is the standard deviation of the sample-to-sample differences over the last ``n``
samples divided by sqrt(2), in um: the white noise of a still bar, unaffected by a slow drift
or a steady motion.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Dict, List, Optional

import numpy as np

DEFAULT_KEEP = 5000  # samples in the ring buffer
NOISE_SAMPLES = 200


class LiveView:
    def __init__(self, keep: int = DEFAULT_KEEP):
        self._t: deque = deque(maxlen=keep)
        self._mm: deque = deque(maxlen=keep)
        self.last_host_t: Optional[float] = None

    def add(self, t_host: float, mm: float) -> None:
        self._t.append(t_host)
        self._mm.append(mm)
        self.last_host_t = t_host

    def clear(self) -> None:
        self._t.clear()
        self._mm.clear()

    @property
    def reading_mm(self) -> Optional[float]:
        return self._mm[-1] if self._mm else None

    def noise_um(self, n: int = NOISE_SAMPLES) -> Optional[float]:
        if len(self._mm) < 5:
            return None
        k = min(n, len(self._mm))
        tail = np.fromiter((self._mm[i] for i in range(len(self._mm) - k, len(self._mm))),
                           dtype=float, count=k)
        return float(np.std(np.diff(tail)) / math.sqrt(2.0) * 1e3)

    def chart(self, now: float, seconds: float = 10.0, max_points: int = 400
              ) -> Dict[str, List[float]]:
        """The last ``seconds`` as {"t": s before now (<= 0), "mm": readings}, thinned."""
        ts = list(self._t)
        lo = np.searchsorted(np.asarray(ts), now - seconds) if ts else 0
        ts, mm = ts[lo:], list(self._mm)[lo:]
        step = max(1, int(math.ceil(len(ts) / max_points)))
        return {"t": [round(t - now, 4) for t in ts[::step]],
                "mm": [round(v, 6) for v in mm[::step]]}
