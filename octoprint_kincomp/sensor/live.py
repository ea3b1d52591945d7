"""The live view of a sensor: the current reading, a short moving chart and the noise level.

A fixed-size ring buffer of the last samples (time in s on the host's clock, reading in mm,
positive = bar longer), so memory stays bounded however long the port is open. The noise
level is the standard deviation of the sample-to-sample differences over the last ``n``
samples divided by sqrt(2), in um: the white noise of a still bar, unaffected by a slow drift
or a steady motion. :func:`bar_check` turns a capture's status into what the user checks before
a test: data arriving, the bar steady (seated in its cups) and the reading inside the
sensor's range.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Dict, List, Optional, Tuple

import numpy as np

from .convention import UNITS

DEFAULT_KEEP = 5000  # samples in the ring buffer
NOISE_SAMPLES = 200
FRESH_S = 2.0  # the last sample is at most this old: data arrives
STEADY_UM = 5.0  # noise (um) of a bar resting in its cups; a loose bar rattles more


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
        tail = np.fromiter(
            (self._mm[i] for i in range(len(self._mm) - k, len(self._mm))), dtype=float, count=k
        )
        return float(np.std(np.diff(tail)) / math.sqrt(2.0) * 1e3)

    def chart(
        self, now: float, seconds: float = 10.0, max_points: int = 400
    ) -> Dict[str, List[float]]:
        """The last ``seconds`` as {"t": s before now (<= 0), "mm": readings}, thinned."""
        ts = list(self._t)
        lo = np.searchsorted(np.asarray(ts), now - seconds) if ts else 0
        ts, mm = ts[lo:], list(self._mm)[lo:]
        step = max(1, int(math.ceil(len(ts) / max_points)))
        return {
            "t": [round(t - now, 4) for t in ts[::step]],
            "mm": [round(v, 6) for v in mm[::step]],
        }


def range_mm(sensor: Dict[str, str]) -> Optional[Tuple[float, float]]:
    """The sensor's measuring range in mm, positive = bar longer, from a status's ``sensor``
    metadata (``sensor_range`` in the sensor's units before the sign); None if unknown."""
    try:
        lo, hi = (float(v) for v in sensor["sensor_range"].split(","))
        factor = UNITS[sensor.get("sensor_units", "mm")]
    except (KeyError, ValueError, AttributeError):
        return None
    sign = -1.0 if sensor.get("sensor_positive") == "shorter" else 1.0
    a, b = lo * factor * sign, hi * factor * sign
    return (min(a, b), max(a, b))


def bar_check(status: Dict[str, object]) -> Dict[str, object]:
    """From a capture's status: ``data`` (samples arrive), ``steady`` (noise at most
    ``steady_max_um`` = STEADY_UM um: the bar rests in its cups), ``in_range`` (the reading
    inside the sensor's range), ``range_mm`` and ``margin_mm`` (to the nearer end of the
    range). A check that cannot be made (no data, no range known) is None."""
    age = status.get("last_data_age_s")
    reading, noise = status.get("reading_mm"), status.get("noise_um")
    data = age is not None and age <= FRESH_S and status.get("port_open", False)
    rng = range_mm(status.get("sensor") or {})
    out: Dict[str, object] = {
        "data": bool(data),
        "steady": None,
        "in_range": None,
        "range_mm": list(rng) if rng else None,
        "margin_mm": None,
        "steady_max_um": STEADY_UM,
    }
    if not data or reading is None:
        return out
    if noise is not None:
        out["steady"] = noise <= STEADY_UM
    if rng is not None:
        out["in_range"] = rng[0] <= reading <= rng[1]
        out["margin_mm"] = round(min(reading - rng[0], rng[1] - reading), 4)
    return out
