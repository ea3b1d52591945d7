"""Finding the runs of a ballbar test in one continuous stream of readings.

The stream is what the sensor sent from arming to the end: times ``t`` (s, increasing, may be host
arrival times with jitter) and readings ``r`` (mm, positive = bar longer). The program
(``calibration/ballbar/program.py``) gives each direction the same shape, which the data shows
whatever the speed profile of the printer (acceleration, junctions, stalls of the host's queue):

1. a dwell at radius R + feed_in: the reading stands still at a level H (>= ``dwell_s``);
2. the radial feed-in: the reading drops by ``feed_in_mm`` within a short time;
3. the arc (overshoot, capture, overshoot): the reading moves only by the machine's errors;
4. the radial feed-out: the reading rises by ``feed_in_mm``;
5. a dwell (the next run's dwell follows at once: the bar stays mounted).

Host send times are not used (the printer's planner buffers moves). Steps are found as
places where the reading differs from itself ``L`` seconds earlier by more than half the
feed-in (``L``: the longest a radial move of feed_in may take, with acceleration); a step
counts when its size is 0.6-1.4 x feed_in, and a run when its feed-in follows a still dwell,
its feed-out is followed by one, and the arc between them lasted at least 0.3 x the time at
the programmed feed (a feed override may speed it up; nothing limits how slow it may be).
Runs are taken in the program's order of directions; consecutive runs must be separated by a
still gap only. Nothing assumes constant speed: only the still dwells and the steps are used.

The runs are then cut out of the stream with their dwells (:class:`RunSegment`), for the
native trace that the analysis maps from time to angle (``calibration/ballbar/analysis.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..calibration.ballbar.program import TestSpec, run_angles
from ..core.messages import Msg

STEP_MIN, STEP_MAX = 0.6, 1.4  # accepted step, times feed_in_mm
ARC_MIN = 0.3  # shortest arc, times its duration at the programmed feed
STILL_FRACTION = 0.98  # share of a dwell's samples within the tolerance


@dataclass
class Event:
    rising: bool  # True: the bar got longer (feed-out), False: shorter (feed-in)
    i: int  # first sample of the step region
    t: float  # s, about the middle of the step
    before: float  # mm, level before the step
    after: float  # mm, level after

    @property
    def step(self) -> float:
        return self.after - self.before


@dataclass
class RunSegment:
    direction: str
    i0: int  # samples [i0, i1) of the stream: dwell, feed-in, arc, feed-out, dwell
    i1: int
    t_in: float  # s, middle of the feed-in
    t_out: float  # s, middle of the feed-out
    dwell_mm: float  # level of the dwell before the feed-in
    step_in_mm: float  # negative: the bar got shorter
    step_out_mm: float


@dataclass
class Detection:
    runs: List[RunSegment] = field(default_factory=list)
    started: bool = False  # a feed-in after a still dwell has been seen
    complete: bool = False  # every direction's run and the final dwell have been seen
    reason: Optional[str] = None  # why not complete (a Msg)
    end_t: Optional[float] = None  # s, when the final dwell was long enough
    t_ref: float = 0.0  # s, stream time of the first run's first sample (trace time 0)


class _Shape:
    """The features the program implies, in the stream's units."""

    def __init__(self, spec: TestSpec, t: np.ndarray, r: np.ndarray):
        self.spec = spec
        self.d = spec.feed_in_mm
        v = spec.feed_mm_min / 60.0
        n = len(t)
        span = float(t[-1] - t[0]) if n > 1 else 0.0
        self.dt = span / (n - 1) if n > 1 and span > 0 else 1e-3
        self.L = max(0.25, 4.0 * self.d / v, 3.0 * self.dt)  # longest radial move, s
        self.W = max(0.1, 3.0 * self.dt)  # level window, s
        dif = np.diff(r)
        sigma = 1.4826 * float(np.median(np.abs(dif))) / math.sqrt(2.0) if n > 2 else 0.0
        self.tol = max(0.05 * self.d, 6.0 * sigma)  # a dwell stays within this, mm
        self.pre = max(0.5 * spec.dwell_s, 3.0 * self.dt)  # still time needed before
        self.post = max(0.75 * spec.dwell_s, 3.0 * self.dt)  # and after a run
        self.arc_s = {
            dd: math.radians(abs(run_angles(spec, dd)[1])) * spec.radius_mm / v
            for dd in ("ccw", "cw")
        }


def _level(t, r, t0, t1) -> float:
    a, b = np.searchsorted(t, [t0, t1])
    return float(np.median(r[a:b])) if b > a else float("nan")


def _still(t, r, t0, t1, level, tol) -> bool:
    a, b = np.searchsorted(t, [t0, t1], side="right")
    if b - a < 3:
        return False
    return float(np.mean(np.abs(r[a:b] - level) <= tol)) >= STILL_FRACTION


def find_steps(t: np.ndarray, r: np.ndarray, shape: _Shape) -> List[Event]:
    """Steps of more than half the feed-in within L seconds, in time order."""
    L, W = shape.L, shape.W
    diff = r - np.interp(t - L, t, r)
    events = []
    for rising in (False, True):
        mask = (diff > 0.5 * shape.d) if rising else (diff < -0.5 * shape.d)
        mask &= t - L >= t[0]
        edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        last_end = -math.inf
        for a, b in zip(starts.tolist(), ends.tolist()):
            if b - a < 2 or t[b - 1] - t[a] < 0.3 * L:
                continue  # a single outlier, not a step
            tm = float(t[a])
            if tm - last_end < L and events and events[-1].rising == rising:
                last_end = float(t[b - 1])  # the same step, split by noise
                continue
            last_end = float(t[b - 1])
            events.append(
                Event(
                    rising,
                    a,
                    tm,
                    _level(t, r, tm - L - W, tm - L),
                    _level(t, r, tm + L, tm + L + W),
                )
            )
    events.sort(key=lambda e: e.t)
    return events


def _step_ok(e: Event, shape: _Shape) -> bool:
    size = -e.step if not e.rising else e.step
    return STEP_MIN * shape.d <= size <= STEP_MAX * shape.d


def detect_runs(t, r, spec: TestSpec) -> Detection:
    """The runs of ``spec`` in the stream (t in s, increasing; r in mm, + = longer)."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    if len(t) < 10:
        return Detection(reason=Msg("no data"))
    shape = _Shape(spec, t, r)
    events = find_steps(t, r, shape)
    directions = list(spec.directions)
    chain: List[RunSegment] = []
    best: List[RunSegment] = []
    det = Detection()
    k = 0
    while k < len(events) and len(chain) < len(directions):
        e = events[k]
        if (
            not e.rising
            and _step_ok(e, shape)
            and _still(t, r, e.t - shape.L - shape.pre, e.t - shape.L, e.before, shape.tol)
        ):
            det.started = True
            # the gap since the last run is still (at a slow feed the steps' windows L may
            # cover most of a short dwell: then the window checked just above stands for it)
            gap_from = min(chain[-1].t_out + shape.L, e.t - shape.L - shape.pre) if chain else 0.0
            if chain and not _still(t, r, gap_from, e.t - shape.L, e.before, shape.tol):
                chain = []  # something happened between the runs: start again here
            if k + 1 == len(events):
                break  # this run is in progress
            f = events[k + 1]
            direction = directions[len(chain)]
            pending = k + 2 == len(events) and math.isnan(f.after)  # its level comes next
            if (
                f.rising
                and (pending or _step_ok(f, shape))
                and f.t - e.t >= ARC_MIN * shape.arc_s[direction]
            ):
                chain.append(RunSegment(direction, 0, 0, e.t, f.t, e.before, e.step, f.step))
                best = chain if len(chain) >= len(best) else best
                k += 2
                continue
        chain = []  # not the start of a run, or a broken run
        k += 1
    det.runs = chain if len(chain) == len(directions) else best
    if len(chain) < len(directions):
        det.reason = _why(events, best, directions, shape)
        return det
    last = chain[-1]
    end_level = _level(t, r, last.t_out + shape.L, last.t_out + shape.L + shape.W)
    t_end = last.t_out + shape.L + shape.post
    if t[-1] < t_end or not _still(t, r, last.t_out + shape.L, t_end, end_level, shape.tol):
        det.reason = Msg("waiting for the dwell after the last run")
        return det
    _cut(t, r, chain, shape, end_level)
    det.complete = True
    det.end_t = t_end
    return det


def _why(events, chain, directions, shape) -> str:
    if not events:
        return Msg(
            "no step of about the feed-in (%(d)s mm) in the data: did the test program "
            "run with the bar mounted?",
            d=f"{shape.d:g}",
        )
    if not chain:
        return Msg(
            "no run found: the data has no still dwell, feed-in of %(d)s mm, arc and "
            "feed-out in that order",
            d=f"{shape.d:g}",
        )
    return Msg(
        "%(found)s of %(n)s runs found (%(directions)s)",
        found=len(chain),
        n=len(directions),
        directions=", ".join(directions),
    )


def _cut(t, r, chain: List[RunSegment], shape: _Shape, end_level: float) -> None:
    """Sample ranges of the runs: the still gaps between runs are split in the middle."""
    spec = shape.spec
    first = chain[0]
    limit = 2.0 * spec.dwell_s + 1.0
    a = int(np.searchsorted(t, first.t_in - shape.L, side="right"))
    lo = int(np.searchsorted(t, first.t_in - shape.L - limit))
    away = np.nonzero(np.abs(r[lo:a] - first.dwell_mm) > shape.tol)[0]
    first.i0 = lo + int(away[-1]) + 1 if len(away) else lo
    for prev, nxt in zip(chain, chain[1:]):
        mid = 0.5 * ((prev.t_out + shape.L) + (nxt.t_in - shape.L))
        prev.i1 = nxt.i0 = int(np.searchsorted(t, mid))
    last = chain[-1]
    b = int(np.searchsorted(t, last.t_out + shape.L))
    hi = int(np.searchsorted(t, last.t_out + shape.L + limit, side="right"))
    away = np.nonzero(np.abs(r[b:hi] - end_level) > shape.tol)[0]
    last.i1 = b + int(away[0]) if len(away) else hi


def explain_failure(t, r, spec: TestSpec, detection: Detection) -> str:
    """A hint when the runs are not found as sent but are with another sign or units."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    if detection.runs or len(t) < 10:
        return detection.reason
    if detect_runs(t, -r, spec).runs:
        return Msg(
            "the readings look inverted (the feed-in made the bar read longer): check "
            "the sign setting ('positive')"
        )
    for factor in (1e-3, 1e3, 25.4, 1 / 25.4):  # um, m, inch read as mm; mm read as inch
        for sign in (1.0, -1.0):
            if detect_runs(t, sign * factor * r, spec).runs:
                return Msg(
                    "the feed-in steps are %(factor)s times the feed-in of %(d)s mm: "
                    "check the units setting",
                    factor=f"{1 / factor:.4g}",
                    d=f"{spec.feed_in_mm:g}",
                )
    return detection.reason


def program_seconds(spec: TestSpec) -> float:
    """How long the runs of ``spec`` take at the programmed feed (s, without travel)."""
    v = spec.feed_mm_min / 60.0
    per_run = {
        d: 2.0 * spec.dwell_s
        + 2.0 * spec.feed_in_mm / v
        + math.radians(abs(run_angles(spec, d)[1])) * spec.radius_mm / v
        for d in ("ccw", "cw")
    }
    return sum(per_run[d] for d in spec.directions)
