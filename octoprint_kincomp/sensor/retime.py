"""Re-timing host-stamped samples (plain and pattern protocols).

A device that samples at a steady rate sends line ``n`` at ``t0 + n / rate``; the host sees it
``latency >= 0`` later (USB frames, the adapter's latency timer, scheduling: typically 1-16 ms,
in bursts where several lines share one arrival time). Since the latency is never negative,
the true times lie on the **lower envelope** of the arrival times against the line number:

* ``rate`` given (the device's declared rate, trusted whatever the arrival times say):
  ``t = t0 + n / rate`` with ``t0`` at the lower envelope;
* otherwise the rate is fitted: a least-squares line, refitted twice on the points at or below
  it (the low-latency arrivals), then ``t0`` moved to the envelope.

If the residuals after that show the device's rate was not steady (lines lost in transit, a
paused device: spread over 50 ms), the times follow the arrival times locally instead: the
running minimum of the residual (against the median local rate) over about 0.5 s, smoothed.
All times in s; the returned ``jitter_ms`` is the 95th percentile of the arrival delay over the
envelope."""

from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

UNSTEADY_S = 0.05


def _lower_line(n: np.ndarray, t: np.ndarray) -> Tuple[float, float]:
    keep = np.ones(len(n), dtype=bool)
    slope, icept = 0.0, float(t[0])
    for _ in range(3):
        slope, icept = np.polyfit(n[keep], t[keep], 1)
        res = t - (slope * n + icept)
        below = res <= 0
        if below.sum() < max(2, len(n) // 10):
            break
        keep = below
    return float(slope), float(icept)


def _running_min(x: np.ndarray, w: int) -> np.ndarray:
    """Minimum over a centred window of ``w`` samples, in O(n) whatever ``w`` (van Herk /
    Gil-Werman: per block of ``w``, prefix and suffix minima; a window meets two blocks)."""
    if w <= 1:
        return x.copy()
    pad = np.concatenate([np.full(w // 2, np.inf), x, np.full(w - 1 - w // 2, np.inf)])
    n = len(pad)
    blocks = np.concatenate([pad, np.full(-n % w, np.inf)]).reshape(-1, w)
    prefix = np.minimum.accumulate(blocks, axis=1).ravel()
    suffix = np.minimum.accumulate(blocks[:, ::-1], axis=1)[:, ::-1].ravel()
    j = np.arange(n - w + 1)
    return np.minimum(suffix[j], prefix[j + w - 1])


def _running_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Mean over a centred window of ``w`` samples (edges repeated), in O(n)."""
    pad = np.pad(x, (w // 2, w - 1 - w // 2), mode="edge")
    c = np.concatenate([[0.0], np.cumsum(pad)])
    return (c[w:] - c[:-w]) / w


def retime(seq, t_host, rate_hz: Optional[float] = None) -> Tuple[np.ndarray, Dict[str, object]]:
    """Times (s) for samples with line numbers ``seq`` that arrived at ``t_host`` (s)."""
    n = np.asarray(seq, dtype=float)
    t = np.asarray(t_host, dtype=float)
    if len(n) < 3:
        return t.copy(), {"timing_method": "arrival", "timing_jitter_ms": None}
    n0 = n[0]
    n = n - n0
    if rate_hz:
        slope = 1.0 / rate_hz
        icept = float(np.min(t - slope * n))
        method = "declared rate"
    else:
        slope, icept = _lower_line(n, t)
        method = "fitted rate"
    res = t - (slope * n + icept)
    icept += float(np.percentile(res, 1))
    res = t - (slope * n + icept)
    out = slope * n + icept
    if not rate_hz and np.percentile(res, 99.5) - np.percentile(res, 0.5) > UNSTEADY_S:
        m = max(3, min(len(n) // 4, int(1.0 / slope) if slope > 0 else 3))
        slope = float(np.median((t[m:] - t[:-m]) / (n[m:] - n[:-m])))  # ignores a jump
        res = t - slope * n
        w = max(3, int(round(0.5 / slope))) if slope > 0 else 3
        env = _running_mean(_running_min(res, w), w)
        out = np.maximum.accumulate(slope * n + env)
        res = t - out
        method += ", local envelope (rate not steady)"
    info = {
        "timing_method": method,
        "timing_rate_hz": (1.0 / slope) if slope > 0 else None,
        "timing_jitter_ms": float(np.percentile(np.abs(res), 95)) * 1e3,
    }
    return out, info
