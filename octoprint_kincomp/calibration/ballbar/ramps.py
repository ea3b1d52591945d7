"""What a time-series trace's radial feed-in and feed-out tell besides the time (issue 34).

Every run of a KinComp test program starts with a radial feed-in of ``feed_in_mm`` towards the
centre (the bar gets shorter) at the program's feed and ends with a feed-out of the same size
(longer again). They are commanded steps of known size, direction and speed, so the trace
checks its own sensor and labels:

* **sign** (:func:`reading_sign`): the reading before the feed-in must lie ``feed_in_mm``
  *above* the arc's (positive = bar longer); ``feed_in_mm`` below it is a sensor that reports
  extension as negative;
* **gain** (:func:`still_levels` here, the gain itself after the fit:
  ``checks.sensor_gain``): the reading while the head stands still ``feed_in_mm`` outside the
  circle (the dwells before a feed-in and after a feed-out, where the play of each axis is
  known from the move before) lies ``feed_in_mm`` above what the fitted model says the bar
  reads there without that step; a sensor whose gain is 1.03 puts it 1.03 mm above;
* **speed** (:func:`ramp_speed`): how long the middle of each ramp took against the plan: a
  trace of a program printed at half the feed (R50 F925 labelled R100 F1850 keeps the
  angular speed, so the arc's time cannot see it) takes its 1 mm ramps about 1.8 times as
  long;
* **run order** (:func:`run_order`): the program runs its directions in the order of its
  ``directions``; time-stamped runs in the other order have their labels swapped.

Units: mm, s (the reading in mm, positive = bar longer); ratios are plain numbers.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

SPEED_LEVELS = (0.3, 0.7)  # the ramp's time is taken between these shares of its step


def reading_sign(
    runs: Sequence[Tuple[str, np.ndarray, np.ndarray]], feed_in_mm: float, n0: int
) -> Tuple[int, List[float]]:
    """(+1, -1 or 0, each run's step in feed-ins): the median of a run's first ``n0``
    samples (the dwell before the feed-in) less the median of its middle half, over
    ``feed_in_mm``. About +1 with a right sensor, about -1 with one that reports extension
    as negative (all runs), 0 when the runs disagree or show no step (not a test trace)."""
    steps = []
    for _, _, r in runs:
        n = len(r)
        mid = float(np.median(r[n // 4 : max(n // 4 + 1, 3 * n // 4)]))
        steps.append((float(np.median(r[: max(n0, 1)])) - mid) / feed_in_mm)
    if steps and all(s > 0.5 for s in steps):
        return 1, steps
    if steps and all(s < -0.5 for s in steps):
        return -1, steps
    return 0, steps


def run_order(
    runs: Sequence[Tuple[str, np.ndarray, np.ndarray]], directions: Sequence[str]
) -> Dict[str, object]:
    """The labelled runs against the program's order: ``{"expected": [...], "found": [...],
    "swapped": bool or None}``; ``found`` in the order the runs' samples were taken (by
    their times). ``swapped`` is None when the runs' time spans overlap (a logger whose clock
    restarts each run: the order cannot be told)."""
    spans = {d: (float(t.min()), float(t.max())) for d, t, _ in runs if len(t)}
    found = sorted(spans, key=lambda d: spans[d][0])
    expected = [d for d in directions if d in spans]
    out: Dict[str, object] = {"expected": expected, "found": found, "swapped": None}
    if len(found) < 2:
        return out
    ordered = all(spans[a][1] <= spans[b][0] for a, b in zip(found, found[1:]))
    if ordered:
        out["swapped"] = found != expected
    return out


def ramp_speed(
    test, t: np.ndarray, r: np.ndarray, k0: int, k1: int, falling: bool, tau: float
) -> Optional[float]:
    """How long the ramp's middle took against the plan (measured / planned time between
    :data:`SPEED_LEVELS` of its step): 1 when it ran at the planned speed, about 2 at half
    the feed; None when the trace does not show the crossings."""
    p0, p1 = test.span(k0, k1)
    ts = np.linspace(p0 - 0.05, p1 + 0.05, 800)
    rp, _ = test.radial(ts)
    d = test.spec.feed_in_mm
    planned = _crossings(ts, rp, d, falling)
    span = max(p1 - p0, 0.02)
    sel = (t >= p0 - span + tau) & (t <= p1 + span + tau)
    if planned is None or sel.sum() < 6:
        return None
    tt, rr = t[sel], r[sel]
    lo, hi = float(np.percentile(rr, 5)), float(np.percentile(rr, 95))
    if hi - lo < 0.5 * d:
        return None
    measured = _crossings(tt, (rr - lo) / (hi - lo) * d, d, falling)
    if measured is None or planned <= 0:
        return None
    return measured / planned


def _crossings(t: np.ndarray, r: np.ndarray, d: float, falling: bool) -> Optional[float]:
    """s between the crossings of the two :data:`SPEED_LEVELS` (shares of ``d``) by a ramp
    that falls from ``d`` to 0 (``falling``) or rises from 0 to ``d``."""
    times = []
    for share in SPEED_LEVELS:
        level = (1.0 - share) * d if falling else share * d
        s = (r < level) if falling else (r > level)
        hit = np.nonzero(s[1:] & ~s[:-1])[0]
        if not len(hit):
            return None
        i = int(hit[0])
        a, b = r[i], r[i + 1]
        times.append(float(t[i] + (t[i + 1] - t[i]) * (a - level) / (a - b)) if a != b else t[i])
    return times[1] - times[0]


STATE_MM = 0.05  # an axis that moved this far in a block has its play on that side after it


def _play_state(test, k: int, axes: Sequence[int]) -> Optional[Tuple[int, int]]:
    """Per plane axis the side its play is on after block ``k`` (+1: the carriage lags
    behind a drive that moved +): the sign of its last move of at least :data:`STATE_MM`;
    None when that move comes before the test's first run (the printer came from wherever
    it was)."""
    first = min(rp.feed_in[0] for rp in test.runs.values())
    out = []
    for ax in axes:
        moved = test.blocks.p1[: k + 1, ax] - test.blocks.p0[: k + 1, ax]
        idx = np.nonzero(np.abs(moved) >= STATE_MM)[0]
        if not len(idx) or idx[-1] < first:
            return None
        out.append(1 if moved[idx[-1]] > 0 else -1)
    return out[0], out[1]


def still_levels(test, direction: str, t: np.ndarray, r: np.ndarray, sync) -> List[Dict]:
    """The still readings ``feed_in_mm`` outside the circle of one run: the dwell before its
    feed-in (when an earlier run set the play) and the dwell after its feed-out: per dwell
    ``{"level_mm", "t_s", "theta_rad", "state"}`` (the median reading and time of its
    middle, the nominal angle of the ramp, the play side of axes A and B). With servo
    pre-compensation in force each level is taken back by the lead it left the head standing
    at (:func:`_leads_at_rest`), and a dwell where that lead depends on the play is left
    out."""
    from .program import run_angles

    spec = test.spec
    rp = test.runs[direction]
    a0, sweep = run_angles(spec, direction)
    waits = np.nonzero(test.blocks.feed == 0.0)[0]
    leads = _leads_at_rest(test)
    a_ax, b_ax = spec.axes
    out = []
    before = waits[waits < rp.feed_in[0]]
    after = waits[waits > rp.feed_out[1]]
    for dwell, ref, angle, tau in (
        (before[-1] if len(before) else None, rp.feed_in[0] - 1, a0, sync.tau_in),
        (after[0] if len(after) else None, rp.feed_out[1], a0 + sweep, sync.tau_out),
    ):
        if dwell is None:
            continue
        state = _play_state(test, int(ref), spec.axes)
        w0, w1 = test.plan.block_span(int(dwell))
        sel = (t >= w0 + tau + 0.2 * (w1 - w0)) & (t <= w1 + tau - 0.1 * (w1 - w0))
        if state is None or sel.sum() < 10:
            continue
        lead = 0.0
        nth = int(np.searchsorted(waits, dwell))  # the program's dwells, in order
        if nth < len(leads):
            if leads[nth] is None:
                continue
            th = math.radians(angle)
            lead = float(leads[nth][a_ax] * math.cos(th) + leads[nth][b_ax] * math.sin(th))
        out.append(
            {
                "level_mm": float(np.median(r[sel])) - lead,
                "t_s": float(np.median(t[sel])),
                "theta_rad": math.radians(angle),
                "state": state,
            }
        )
    return out


def _leads_at_rest(test) -> List[Optional[np.ndarray]]:
    """Per dwell of the program (in order), mm along each axis: how far servo
    pre-compensation left the head standing beyond the point the program means. The
    compensator leads each move's end by ``T v`` of the move's programmed feed and direction,
    which a still drive does not lag. None for a dwell after a move of no length (a run's
    first line, which only sets the feed): that line takes the lead back, the drives reverse
    by it into their play and the carriage follows only by what exceeds the play, so where
    it stands depends on the play (the lab's clean re-tests read 0.988-0.999 there, by
    plane). Taken from the nominal program's last move before each dwell; empty without
    servo pre-compensation."""
    params = test.current
    if params is None or not params.has_servo_precomp:
        return []
    from ...firmware.interpreter import Dwell, Move
    from ...firmware.planner import program_events
    from .program import generate

    lag = np.array([params.servo_lag_ms[a] * 1e-3 for a in "xyz"])
    leads: List[Optional[np.ndarray]] = []
    last: Optional[np.ndarray] = np.zeros(3)
    for ev in program_events(generate(test.spec, date="-").splitlines(), test.spec.centre):
        if isinstance(ev, Move):
            d = np.subtract(ev.end, ev.start, dtype=float)
            n = float(np.linalg.norm(d))
            last = lag * d / n * ev.feed / 60.0 if n > 0.0 and ev.feed > 0.0 else None
        elif isinstance(ev, Dwell) and ev.seconds > 0.0:
            leads.append(last)
    return leads
