"""From trace samples to nominal angles with the motion the program really produces.

A native trace holds (time, reading) only. The test program is known from the trace metadata
(a KinComp program is regenerated from it byte for byte, then compensated with the parameters
that were active during the test, if any), and ``firmware/planner.py`` plans it with the printer's
planner settings: those recorded in the metadata (``accel_mm_s2``, ``junction_deviation_mm`` or
``square_corner_velocity_mm_s``, ``max_feed_mm_min``) or, when a trace records none, the ones
that best explain the trace's own start-up and stop transients (the radial feed-in from rest
and the feed-out to a stop of each run, see :func:`estimate_motion`).

Each run is synchronised on its two radial ramps: the reading follows the planned radius
``r_p(t - tau)`` there, and ``tau`` is found by least squares (with the levels before and after
the ramp free, so the bar length, set-up offsets and the play taken up on the way do not
matter). Between the feed-in and the feed-out ``tau`` is interpolated linearly (a logger's clock
running at another rate is absorbed). A sample at time ``t`` then sits at the planned time
``t - tau(t)``: its nominal angle, the commanded velocities ``vA, vB`` (mm/s) and whether it lies
on the circle come from the plan. A compensated program is mapped back to the nominal circle
by undoing the compensation model (:func:`nominal_positions`).

Angle-domain traces already carry the angle; the same plan gives each sample its velocity and
time. Units: mm, s, mm/s; angles in the trace in degrees, here in radians.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from ...core.backlash import DEFAULT_DEADBAND_MM
from ...core.kinematics import KinematicModel, changes_nothing
from ...core.marker import BALLBAR_RECORD_KEYS
from ...core.messages import Msg
from ...core.params import AXES, Params
from ...firmware.planner import Blocks, MotionSettings, Plan, program_blocks_of
from . import ramps
from .formats import AngleTrace, NativeTrace, TraceError, meta_centre, meta_float, meta_plane
from .model import Geometry, Run
from .program import ProgramError, TestSpec, arc_angles, generate, run_angles

A_GRID = np.geomspace(100.0, 30000.0, 11)  # mm/s^2, estimation grid
JD_GRID = np.geomspace(0.002, 0.3, 7)  # mm
VALLEY_TOL = 0.002  # log acceleration: where the timing valley is sought to
VALLEY_SKIP_S = 0.005  # s: an estimate whose plan times the runs this well is kept as it is
RAMP_BEFORE_S = 0.03  # s of flat reading used after the feed-out (its play state is constant)
# mm of a ramp's start left out of the synchronisation: an axis that reverses there takes up
# its play first (the carriage stands while its drive crosses the play), which at a low
# acceleration delays the reading by up to a millisecond (simulated: X play 25 um, XZ R50 at
# 300 mm/s^2: the feed-in read 0.9 ms late, the feed-out 0.3 ms; with the pivot 0.2 mm off
# centre that bent the angles enough to move the squareness by 8 um/m when 10 deg more was
# masked). The flat level before the feed-in (another play state) and the arc side after its
# corner (the arc's own take-up) are left out for the same reason; at most this share of
# the feed-in is left out.
TAKEUP_SKIP_MM = 0.2
TAKEUP_SKIP_SHARE = 0.4
CORNER_S = 0.003  # s of the arc side used by the fallback window (a slow logger)


# ---------------------------------------------------------------------------------------
# metadata -> test


def geometry_from_meta(meta: Dict[str, str]) -> Geometry:
    plane = meta_plane(meta)
    radius = meta_float(meta, "radius_mm")
    if not (1.0 <= radius <= 2000.0):
        raise TraceError(
            Msg("metadata 'radius_mm' %(value)s is out of range (1..2000)", value=f"{radius:g}")
        )
    feed = meta_float(meta, "feed_mm_min", 0.0) or None
    start = meta_float(meta, "start_deg", 0.0 if plane == "XY" else -20.0)
    cap = meta_float(meta, "capture_deg", 360.0 if plane == "XY" else 220.0)
    return Geometry(plane, radius, meta_centre(meta), feed, start, cap)


def spec_from_meta(meta: Dict[str, str]) -> TestSpec:
    """The test program a trace's metadata describes (defaults for keys it does not give).
    Raises ProgramError for values no KinComp program can have."""
    geom = geometry_from_meta(meta)
    directions = tuple(d.strip() for d in meta.get("directions", "ccw,cw").split(",") if d)
    kw = dict(
        plane=geom.plane,
        centre=geom.centre or (0.0, 0.0, 0.0),
        radius_mm=geom.radius,
        feed_mm_min=geom.feed or 1850.0,
        capture_deg=geom.capture_deg,
        start_deg=geom.capture_start_deg,
        directions=directions,
    )
    for key in (
        "feed_in_mm",
        "overshoot_deg",
        "dwell_s",
        "chord_error_um",
        "lift_mm",
        "travel_feed_mm_min",
    ):
        if key in meta:
            kw[key] = meta_float(meta, key)
    if "mount_pause" in meta:
        kw["mount_pause"] = meta["mount_pause"].strip().lower() == "true"
    if "mount_pause_command" in meta:
        kw["pause_command"] = meta["mount_pause_command"].strip()
    return TestSpec(**kw)


# The dead band (mm) of the take-ups in the compensated test programs of the simulated
# printer (the closed loop): the simulated printer moves continuously (it has no steps), so a
# dead band derived from a step size (0.625 um at 80 steps/mm) would show there as an error of
# up to its size at each reversal that a stepping printer does not resolve. Its traces say so
# (:class:`SentWith` in their metadata), as the plugin's do for its own settings.
CONTINUOUS_DEADBAND_MM = 1e-6


@dataclass(frozen=True)
class SentWith:
    """How a compensated test program was written on its way to the printer: the
    compensator's ``decimals`` and reversal ``deadband_mm`` (mm). The analysis regenerates
    the program exactly so: a dead band decides where a slowly reversing axis gets its
    take-up move (in a vertical test the out-of-plane axis, moved by the squareness
    compensation, reverses a few degrees after the top with 0.625 um, at the top with
    1e-6 mm; each take-up is a move of its own that the head brakes for, and modelled at the
    wrong place it shifted the time mapping by 14-19 ms: misfit 1.7x, model.unstable and
    campaign.inconsistent on a clean re-test). The defaults are the compensator's own
    (``core.compensator.Options``: what the command line's ``compensate`` and a plugin at
    its default settings send); traces record theirs as ``compensation_decimals`` and
    ``compensation_deadband_mm``."""

    decimals: int = 3  # core.compensator.Options.decimals
    deadband_mm: float = DEFAULT_DEADBAND_MM

    KEYS = BALLBAR_RECORD_KEYS  # (a compensated program's header says them: core/marker.py)

    @staticmethod
    def of_options(options) -> SentWith:
        """The part of a ``core.compensator.Options`` that shapes the program."""
        return SentWith(int(options.decimals), float(options.deadband_mm))

    @staticmethod
    def from_meta(meta: Dict[str, str], default: Optional[SentWith] = None) -> SentWith:
        """The trace's record, else ``default``, else the compensator's defaults."""
        base = default or SentWith()
        if not any(k in meta for k in SentWith.KEYS):
            return base
        dec = meta_float(meta, "compensation_decimals", float(base.decimals))
        band = meta_float(meta, "compensation_deadband_mm", base.deadband_mm)
        if dec != int(dec) or not 3 <= dec <= 8 or not 0.0 <= band <= 0.1:
            raise TraceError(Msg("metadata 'compensation_decimals/_deadband_mm' is not valid"))
        return SentWith(int(dec), band)

    def metadata(self) -> Dict[str, str]:
        return {
            "compensation_decimals": str(self.decimals),
            "compensation_deadband_mm": f"{self.deadband_mm:.10g}",
        }


CONTINUOUS = SentWith(4, CONTINUOUS_DEADBAND_MM)  # the closed loop's (a stepless printer)


def program_text(spec: TestSpec, current: Optional[Params], sent: Optional[SentWith] = None) -> str:
    """The program as the printer received it: generated, then compensated with ``current``
    the way ``sent`` says (default: the compensator's defaults)."""
    text = generate(spec, date="-")
    if current is None or changes_nothing(current):
        return text
    from ...core.compensator import Options
    from ...engines.file_loop import compensate_stream

    sent = sent or SentWith()
    dst = io.StringIO()
    compensate_stream(
        io.StringIO(text),
        dst,
        current,
        Options(decimals=sent.decimals, deadband_mm=sent.deadband_mm),
    )
    return dst.getvalue()


def nominal_positions(
    plan: Plan, ts: np.ndarray, cmd: np.ndarray, params: Optional[Params]
) -> np.ndarray:
    """Nominal (desired) positions of commanded positions ``cmd`` (n, 3) at times ``ts`` of a
    program compensated with ``params``: servo lead and backlash offsets removed, then the
    compensation model inverted (``desired = forward(command)``)."""
    if params is None or changes_nothing(params):
        return cmd
    return _undo_compensation(plan, ts, cmd, params)


def _undo_compensation(
    plan: Plan, ts: np.ndarray, cmd: np.ndarray, params: Params, vel: Optional[np.ndarray] = None
) -> np.ndarray:
    """``nominal_positions``; with ``vel`` (mm/s, (n, 3): the planned velocities at ``ts``)
    the servo lead is taken off as the lag at the planned speed instead of the lead the
    compensator wrote for each block's programmed speed: where the head is when the printer
    lags as the parameters say (:meth:`PlannedTest.head`)."""
    i = plan.block_at(ts)
    u = plan.u[i]
    q = np.array(cmd, dtype=float)
    if params.has_servo_precomp:
        lag = np.array([params.servo_lag_ms[a] * 1e-3 for a in AXES])
        lead = u * plan.f[i][:, None] if vel is None else vel
        q = q - lead * lag[None, :]
    if params.has_backlash:
        for k, a in enumerate(AXES):
            table = params.backlash[a]
            if table.is_zero:
                continue
            sgn = np.sign(u[:, k])
            idx = np.where(sgn != 0, np.arange(len(sgn)), 0)
            sgn = sgn[np.maximum.accumulate(idx)] if len(sgn) else sgn
            at = np.array([p for p, _ in table.points])
            um = np.array([v for _, v in table.points])
            q[:, k] -= sgn * params.backlash_fraction * np.interp(q[:, k], at, um) * 5e-4
    return KinematicModel(params).forward_many(q)


@dataclass
class RunPlan:
    direction: str
    feed_in: Tuple[int, int]  # first and last block index of the radial feed-in
    feed_out: Tuple[int, int]


@dataclass
class PlannedTest:
    """A test program, its blocks and (for the current settings) its plan."""

    spec: TestSpec
    current: Optional[Params]
    blocks: Blocks
    runs: Dict[str, RunPlan]
    plan: Optional[Plan] = None
    settings: Optional[MotionSettings] = None
    sent: Optional[SentWith] = None  # how the compensated program was written

    @staticmethod
    def build(
        spec: TestSpec, current: Optional[Params], sent: Optional[SentWith] = None
    ) -> PlannedTest:
        if current is not None and changes_nothing(current):
            current = None
        text = program_text(spec, current, sent)
        lines = text.splitlines()
        blocks = program_blocks_of(lines, spec.centre)
        fin = [i + 1 for i, ln in enumerate(lines) if "; radial feed-in" in ln]
        fout = [i + 1 for i, ln in enumerate(lines) if "; radial feed-out" in ln]
        runs = {}
        for d, li, lo in zip(spec.directions, fin, fout):
            bi = np.nonzero(blocks.line == li)[0]
            bo = np.nonzero(blocks.line == lo)[0]
            if len(bi) == 0 or len(bo) == 0:
                raise TraceError(Msg("the test program has no radial feed-in/feed-out"))
            runs[d] = RunPlan(d, (int(bi[0]), int(bi[-1])), (int(bo[0]), int(bo[-1])))
        return PlannedTest(
            spec, current, blocks, runs, sent=(sent or SentWith()) if current else None
        )

    def use(self, settings: MotionSettings) -> Plan:
        if self.plan is None or self.settings is not settings:
            self.plan = self.blocks.plan(settings)
            self.settings = settings
        return self.plan

    def span(self, k0: int, k1: int) -> Tuple[float, float]:
        return self.plan.block_span(k0)[0], self.plan.block_span(k1)[1]

    def nominal(self, ts: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        cmd, vel = self.plan.sample(ts)
        if self.current is None:
            return cmd, vel
        return _undo_compensation(self.plan, ts, cmd, self.current), vel

    def head(self, ts: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Where the head is at plan times ``ts`` (mm, (n, 3)) when the printer lags as the
        parameters in force say, and the planned velocities (mm/s): the nominal positions,
        except that a servo lead written for each block's programmed speed is ahead of the
        head wherever it runs slower (``lag * (u * f - v)``). On the radial ramps that is
        most of the ramp: taken for the nominal position, a re-test with classic jerk at
        300 mm/s^2 and F3700 was synchronised 1.8-2.9 ms off (0.6-0.9 ms with junction
        deviation) and its fit left 1.6 times the noise; with it, within 0.5 ms and at the
        noise."""
        if self.current is None or not self.current.has_servo_precomp:
            return self.nominal(ts)
        cmd, vel = self.plan.sample(ts)
        return _undo_compensation(self.plan, ts, cmd, self.current, vel), vel

    def radial(self, ts: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Planned distance of the head from the circle (mm, in the plane: feed_in_mm .. 0)
        and its rate of change (mm/s): the ramps' timing and levels (:meth:`head`)."""
        a, b = self.spec.axes
        p, v = self.head(ts)
        c = self.spec.centre
        da, db = p[:, a] - c[a], p[:, b] - c[b]
        rho = np.hypot(da, db)
        rate = (da * v[:, a] + db * v[:, b]) / np.where(rho > 0, rho, 1.0)
        return rho - self.spec.radius_mm, rate


# ---------------------------------------------------------------------------------------
# synchronisation on the radial ramps


@dataclass
class Ramp:
    t: np.ndarray  # measured times in the window
    r: np.ndarray  # measured readings
    k0: int  # planned blocks of the ramp
    k1: int
    falling: bool  # feed-in (reading falls) or feed-out


def _crossing_time(
    t: np.ndarray, r: np.ndarray, level: float, falling: bool, last: bool = False
) -> Optional[float]:
    s = (r < level) if falling else (r > level)
    d = np.nonzero(s[1:] & ~s[:-1])[0]
    if len(d) == 0:
        return None
    i = int(d[-1] if last else d[0])
    a, b = r[i], r[i + 1]
    return float(t[i] + (t[i + 1] - t[i]) * (a - level) / (a - b)) if a != b else float(t[i])


def _planned_crossing(test: PlannedTest, k0: int, k1: int, level: float) -> float:
    t0, t1 = test.span(k0, k1)
    ts = np.linspace(t0, t1, 400)
    rp, _ = test.radial(ts)
    falling = rp[0] > rp[-1]
    tc = _crossing_time(ts, rp, level, falling)
    return t0 if tc is None else tc


def _ramp_terms(test: PlannedTest, ramp: Ramp, tau: float):
    """Residuals of ``reading = c0 + c1 * r_p(t - tau)`` (c0, c1 by least squares) and the
    derivative of the residuals with respect to ``tau``, projected off the levels."""
    rp, rate = test.radial(ramp.t - tau)
    M = np.stack([np.ones_like(rp), rp], axis=1)
    coef, *_ = np.linalg.lstsq(M, ramp.r, rcond=None)
    e = ramp.r - M @ coef
    g = coef[1] * rate  # d e / d tau
    g = g - M @ np.linalg.lstsq(M, g, rcond=None)[0]
    return e, g


def _fit_tau(
    test: PlannedTest, ramps: List[Ramp], tau: float, iters: int = 8
) -> Tuple[float, float]:
    """Gauss-Newton on one time offset shared by ``ramps``; returns (tau, SSE)."""
    for _ in range(iters):
        num = den = 0.0
        for ramp in ramps:
            e, g = _ramp_terms(test, ramp, tau)
            num += float(g @ e)
            den += float(g @ g)
        if den <= 0:
            break
        step = -num / den
        step = max(-0.005, min(0.005, step))
        tau += step
        if abs(step) < 1e-8:
            break
    sse = 0.0
    for ramp in ramps:
        e, _ = _ramp_terms(test, ramp, tau)
        sse += float(e @ e)
    return tau, sse


def _minimise(f, x0: float, half: float, step: float, tol: float = 2e-7) -> Tuple[float, float]:
    """1-D minimum of ``f`` near ``x0``: grid over +-half, then golden section."""
    xs = np.arange(x0 - half, x0 + half + step / 2, step)
    vals = [f(x) for x in xs]
    j = int(np.argmin(vals))
    lo, hi = xs[max(j - 1, 0)], xs[min(j + 1, len(xs) - 1)]
    g = (math.sqrt(5) - 1) / 2
    a, b = lo + (1 - g) * (hi - lo), lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    while hi - lo > tol:
        if fa < fb:
            hi, b, fb = b, a, fa
            a = lo + (1 - g) * (hi - lo)
            fa = f(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = f(b)
    x = (lo + hi) / 2
    return x, f(x)


@dataclass
class Sync:
    tau_in: float
    tau_out: float
    t_in: float  # measured time of the feed-in end (planned end + tau_in)
    t_out: float
    sse: float

    def tau(self, t: np.ndarray) -> np.ndarray:
        if self.t_out <= self.t_in:
            return np.full_like(t, self.tau_in)
        f = np.clip((t - self.t_in) / (self.t_out - self.t_in), 0.0, 1.0)
        return self.tau_in + (self.tau_out - self.tau_in) * f


@dataclass
class MeasuredRun:
    direction: str
    t: np.ndarray
    r: np.ndarray
    ramps: List[Ramp] = field(default_factory=list)
    tau0: Tuple[float, float] = (0.0, 0.0)


def _measured_run(test: PlannedTest, direction: str, t: np.ndarray, r: np.ndarray) -> MeasuredRun:
    """Coarse sync (mid-level crossings) and the measured ramp windows of one run."""
    spec = test.spec
    d = spec.feed_in_mm
    rp_plan = test.runs[direction]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    n0 = max(3, int(0.3 * spec.dwell_s / dt)) if dt > 0 else 3
    hi0, hi1 = float(np.median(r[:n0])), float(np.median(r[-n0:]))
    t_in = _crossing_time(t, r, hi0 - d / 2, falling=True)
    t_out = _crossing_time(t, r, hi1 - d / 2, falling=False, last=True)
    if t_in is None or t_out is None or t_out <= t_in:
        raise TraceError(Msg("feed-in/feed-out marker not found (is this the right program?)"))
    fi, fo = rp_plan.feed_in, rp_plan.feed_out
    tau_in = t_in - _planned_crossing(test, fi[0], fi[1], d / 2)
    tau_out = t_out - _planned_crossing(test, fo[0], fo[1], d / 2)
    mr = MeasuredRun(direction, t, r, tau0=(tau_in, tau_out))
    for (k0, k1), tau, falling in ((fi, tau_in, True), (fo, tau_out, False)):
        sel = _ramp_samples(test, k0, k1, falling, t - tau)
        if sel.sum() < 4:
            raise TraceError(
                Msg(
                    "%(direction)s run: too few samples on the radial feed-in/"
                    "feed-out to synchronise (sample rate too low?)",
                    direction=direction,
                )
            )
        mr.ramps.append(Ramp(t[sel], r[sel], k0, k1, falling))
    return mr


def _ramp_samples(test: PlannedTest, k0: int, k1: int, falling: bool, tp: np.ndarray) -> np.ndarray:
    """The samples (planned times ``tp``) the synchronisation uses on one ramp: those past its
    take-up (:func:`_ramp_window`) when that part tells the time well enough (at least
    :data:`MIN_TIMING_SHARE` of the information of the whole ramp with its flat level and
    corner, judged on the plan at the trace's sample rate: a fast ramp is nearly a straight
    line, whose time only its ends tell; its take-up is short then), else the whole ramp."""
    p0, p1 = test.span(k0, k1)
    w0, w1 = _ramp_window(test, k0, k1, falling)
    whole = (p0 - RAMP_BEFORE_S, p1 + CORNER_S) if falling else (p0 - CORNER_S, w1)
    part = (tp >= w0) & (tp <= w1)
    dt = float(np.median(np.diff(tp))) if len(tp) > 1 else 0.0
    if part.sum() >= MIN_RAMP_SAMPLES and dt > 0:
        grid = np.arange(whole[0], whole[1], dt)
        inside = (grid >= w0) & (grid <= w1)
        if _timing_information(test, grid[inside]) >= MIN_TIMING_SHARE * _timing_information(
            test, grid
        ):
            return part
    return (tp >= whole[0]) & (tp <= whole[1])


def _timing_information(test: PlannedTest, tp: np.ndarray) -> float:
    """(s^-2, per unit noise variance) how well samples at planned times ``tp`` fix the time
    offset of ``reading = c0 + c1 r_p(t - tau)``: the rate's part that the levels do not
    absorb, squared and summed."""
    if len(tp) < 3:
        return 0.0
    rp, rate = test.radial(tp)
    M = np.stack([np.ones_like(rp), rp], axis=1)
    g = rate - M @ np.linalg.lstsq(M, rate, rcond=None)[0]
    return float(g @ g)


MIN_RAMP_SAMPLES = 6  # fewer past the take-up: the whole ramp with its levels
MIN_TIMING_SHARE = 0.1  # the take-up-free part must tell the time at least this well


def _ramp_window(test: PlannedTest, k0: int, k1: int, falling: bool) -> Tuple[float, float]:
    """Planned times (s) of the part of a ramp the synchronisation uses: from where its axes
    have taken up their play (:data:`TAKEUP_SKIP_MM` into the ramp) to the feed-in's corner,
    or to :data:`RAMP_BEFORE_S` after the feed-out has stopped."""
    p0, p1 = test.span(k0, k1)
    d = test.spec.feed_in_mm
    skip = min(TAKEUP_SKIP_MM, TAKEUP_SKIP_SHARE * d)
    ts = np.linspace(p0, p1, 400)
    rp, _ = test.radial(ts)
    past = (rp < d - skip) if falling else (rp > skip)
    start = float(ts[int(np.argmax(past))]) if past.any() else p0
    return (start, p1) if falling else (start, p1 + RAMP_BEFORE_S)


def sync_run(test: PlannedTest, mr: MeasuredRun, common: bool) -> Sync:
    """Least-squares time offsets of one run's ramps; ``common``: one offset for both (the
    plan's timing between them is trusted: used to estimate the planner settings)."""
    fin, fout = mr.ramps
    tin0, tout0 = mr.tau0
    if common:
        tau, sse = _fit_tau(test, [fin, fout], 0.5 * (tin0 + tout0))
        tau_in = tau_out = tau
    else:
        tau_in, s1 = _fit_tau(test, [fin], tin0)
        tau_out, s2 = _fit_tau(test, [fout], tout0)
        sse = s1 + s2
    t_in = test.span(*test.runs[mr.direction].feed_in)[1] + tau_in
    t_out = test.span(*test.runs[mr.direction].feed_out)[0] + tau_out
    return Sync(tau_in, tau_out, t_in, t_out, sse)


def _syncs(
    test: PlannedTest, measured: List[MeasuredRun], settings: MotionSettings, common: bool
) -> List[Sync]:
    """Each measured run synchronised with the plan of ``settings`` (``common``: one time
    offset for both ramps of a run, else each ramp its own)."""
    test.use(settings)
    return [
        sync_run(test, _measured_run(test, mr.direction, mr.t, mr.r), common=common)
        for mr in measured
    ]


def _timing_gap(test: PlannedTest, measured: List[MeasuredRun], settings: MotionSettings) -> float:
    """s, the measured time between each run's ramps minus the planned time with
    ``settings`` (mean over the runs; each ramp synchronised on its own). It grows with the
    acceleration (a quicker plan) and with the junction deviation (quicker corners)."""
    syncs = _syncs(test, measured, settings, common=False)
    return float(np.mean([s.tau_out - s.tau_in for s in syncs]))


def _valley_accel(gap, la0: float) -> Optional[float]:
    """log acceleration at which ``gap(log accel)`` (increasing) crosses zero, searched
    from ``la0`` within the estimation grid (to VALLEY_TOL, by regula falsi: the gap is
    nearly linear in log acceleration there); None when it does not cross there."""
    lo_end, hi_end = math.log(A_GRID[0]), math.log(A_GRID[-1])
    x0 = min(max(la0, lo_end), hi_end)
    g0 = gap(x0)
    step = 0.25 if g0 < 0 else -0.25  # towards the crossing
    while True:
        x1 = min(max(x0 + step, lo_end), hi_end)
        if x1 == x0:
            return None
        g1 = gap(x1)
        if (g1 >= 0) != (g0 >= 0):
            break
        x0, g0 = x1, g1
    (lo, g_lo), (hi, g_hi) = sorted(((x0, g0), (x1, g1)))
    side = 0
    while hi - lo > VALLEY_TOL:
        mid = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        mid = min(max(mid, lo + 0.25 * VALLEY_TOL), hi - 0.25 * VALLEY_TOL)
        g_mid = gap(mid)
        if (g_mid >= 0) == (g_lo >= 0):
            lo, g_lo = mid, g_mid
            g_hi = g_hi / 2 if side == -1 else g_hi  # (Illinois: no end stays put for long)
            side = -1
        else:
            hi, g_hi = mid, g_mid
            g_lo = g_lo / 2 if side == 1 else g_lo
            side = 1
        if abs(g_mid) < 1e-5:  # s: 10 us, far below any timing tolerance
            return mid
    return 0.5 * (lo + hi)


def _timing_valley(cost, planner, measured, test, la: float, lj: float, c_best: float):
    """(log accel, log junction deviation, cost): the estimate so far when its plan already
    times the runs (within VALLEY_SKIP_S), else the best of it and the points of the timing
    valley, one per junction deviation of the grid (the acceleration at which the planned
    time between the ramps equals the measured one), by the common cost. The local searches
    start from the ramps' acceleration; when the ramps are bent (the take-ups of a
    compensated program: a re-test read 2,624 mm/s^2 and 0.06 mm on a 1,500 mm/s^2,
    0.013 mm printer, 155 ms off in timing) the valley, 1 % of acceleration wide at
    3,700 mm/min, lies outside their reach."""
    if abs(_timing_gap(test, measured, planner(la, lj))) <= VALLEY_SKIP_S:
        return la, lj, c_best
    start = la
    for lj_v in np.log(JD_GRID):
        la_v = _valley_accel(
            lambda x, lj_v=lj_v: _timing_gap(test, measured, planner(x, lj_v)), start
        )
        if la_v is None:
            continue
        start = la_v  # (the valley moves little from one grid step to the next)
        c_v = cost(planner(la_v, lj_v), True)
        if c_v < c_best:
            la, lj, c_best = la_v, float(lj_v), c_v
    return la, lj, c_best


def estimate_motion(test: PlannedTest, measured: List[MeasuredRun]) -> MotionSettings:
    """Planner settings (acceleration, junction deviation; or constant speed) that best
    explain the runs' ramps and the time between them.

    In two stages: the acceleration from the shapes of the radial ramps (each synchronised
    on its own: a smooth cost with one clear minimum, hardly touched by the junction
    deviation); then the junction deviation and the acceleration from the time between the
    ramps (one offset for both: a valley so narrow at higher feeds, 1 % of acceleration at
    3700 mm/min, that a grid over both steps over it and once took constant speed for the
    best fit). A planner must explain ramps and timing clearly better than constant
    speed."""
    base = MotionSettings()
    n = sum(len(r.t) for mr in measured for r in mr.ramps)

    def cost(settings: MotionSettings, common: bool) -> float:
        total = 0.0
        for sync in _syncs(test, measured, settings, common):
            total += sync.sse
        return total

    def planner(la: float, lj: float) -> MotionSettings:
        return base.with_(accel_mm_s2=math.exp(la), junction_deviation_mm=math.exp(lj))

    lj = math.log(base.junction_deviation_mm)
    _, a_best = min((cost(planner(math.log(a), lj), False), float(a)) for a in A_GRID)
    da, dj = math.log(A_GRID[1] / A_GRID[0]), math.log(JD_GRID[1] / JD_GRID[0])
    la, s_best = _minimise(
        lambda x: cost(planner(x, lj), False), math.log(a_best), da, da / 2, tol=0.005
    )
    s_const = cost(base.with_(constant_speed=True), False)
    c_best = cost(planner(la, lj), True)
    lj2, _ = _minimise(lambda x: cost(planner(la, x), True), lj, 2 * dj, dj / 2, tol=0.02)
    la2, c2 = _minimise(lambda x: cost(planner(x, lj2), True), la, 0.05, 0.005, tol=0.001)
    if c2 < c_best:
        la, lj, c_best = la2, lj2, c2
    la, lj, c_best = _timing_valley(cost, planner, measured, test, la, lj, c_best)
    c_const = cost(base.with_(constant_speed=True), True)
    # constant speed unless the ramp shapes or the timing show the speed-up clearly (two more
    # parameters: a likelihood-ratio margin of 10 noise variances; the timing alone can miss
    # it: with take-ups in a compensated program the valley in junction deviation is narrow
    # too) and it lasts at least two samples
    dt = float(np.median(np.concatenate([np.diff(mr.t) for mr in measured])))

    def clearly(c_plan: float, c_flat: float) -> bool:
        return c_flat - c_plan > 10.0 * min(c_flat, c_plan) / max(n, 1)

    if (
        not (clearly(s_best, s_const) or clearly(c_best, c_const))
        or test.spec.feed_mm_min / 60.0 / math.exp(la) < 2.0 * dt
    ):
        s = base.with_(constant_speed=True, estimated=True)
    else:
        s = base.with_(
            accel_mm_s2=round(math.exp(la), 1),
            junction_deviation_mm=round(math.exp(lj), 5),
            estimated=True,
        )
    test.use(s)
    return s


# ---------------------------------------------------------------------------------------
# traces -> runs


@dataclass
class Mapping:
    """How a trace's samples were put on the nominal circle (for the fit diagnostics)."""

    settings: Optional[MotionSettings]
    sync_ms: Dict[str, float] = field(default_factory=dict)  # tau_out - tau_in per run
    # s per run: the planned time from the end of the feed-in to the start of the feed-out
    planned_s: Dict[str, float] = field(default_factory=dict)
    timed: bool = True  # False: an angle-domain trace (its samples carry no time)
    planned: bool = True  # False: no program plan (angles at a constant feed, or none)
    # um per run: the reading's scatter while the head stands still before the feed-in (the
    # sensor's own noise floor; None when the trace has no such samples)
    still_noise_um: Dict[str, float] = field(default_factory=dict)
    # the commanded radial steps (module ramps): the reading's sign (+1; -1: the readings were
    # inverted to be analysed; 0: no feed-in seen), each run's step before the feed-in in
    # feed-ins, the still readings outside the circle (ramps.still_levels), each run's
    # [feed-in, feed-out] time against the plan, the runs' order against the program's
    sign: int = 1
    feed_in_mm: float = 1.0
    feed_in_steps: List[float] = field(default_factory=list)
    still_levels: List[Dict[str, object]] = field(default_factory=list)
    ramp_speed: Dict[str, List[Optional[float]]] = field(default_factory=dict)
    run_order: Optional[Dict[str, object]] = None
    # angle traces: per run the share of row-to-row steps that advance in the labelled
    # direction (file order); whether only the capture arc was used (no planner known)
    row_order: Dict[str, float] = field(default_factory=dict)
    capture_only: bool = False
    # how the compensated program was taken to be written, and where that came from
    # ("trace": its record, "given": the caller's, "default": the compensator's defaults,
    # "timing": the dead band the ramps' timing fits; None: an uncompensated program)
    sent: Optional[SentWith] = None
    sent_source: Optional[str] = None
    # angle traces: per run the share of samples beyond the program's run (by more than
    # ARC_SLACK_RAD) and the program's run (deg from, to)
    off_arc: Dict[str, float] = field(default_factory=dict)
    arc_span_deg: Dict[str, List[float]] = field(default_factory=dict)

    def as_dict(self) -> Dict[str, object]:
        d: Dict[str, object] = {"motion": self.settings.as_dict() if self.settings else None}
        if self.sync_ms:
            d["sync_mismatch_ms"] = dict(self.sync_ms)
            d["planned_arc_s"] = dict(self.planned_s)
        if self.still_noise_um:
            d["still_noise_um"] = dict(self.still_noise_um)
        if self.timed:
            d["sensor"] = {
                "sign": self.sign,
                "feed_in_steps": [round(x, 4) for x in self.feed_in_steps],
            }
            d["ramp_time_ratio"] = {
                k: [_rounded(x, 3) for x in v] for k, v in self.ramp_speed.items()
            }
            d["run_order"] = self.run_order
        if self.row_order:
            d["row_order"] = {k: round(v, 3) for k, v in self.row_order.items()}
        if self.capture_only:
            d["capture_only"] = True
        if self.off_arc:
            d["off_arc_share"] = {k: round(v, 4) for k, v in self.off_arc.items()}
        if self.sent is not None:
            d["compensated_as"] = dict(self.sent.metadata(), source=self.sent_source)
        return d


def _record_sent(mapping: Mapping, test: PlannedTest, meta, sent: Optional[SentWith]) -> None:
    """How the program of ``test`` was taken to be compensated (None: it was not)."""
    if test.current is None:
        return
    mapping.sent = test.sent
    if any(k in meta for k in SentWith.KEYS):
        mapping.sent_source = "trace"
    else:
        mapping.sent_source = "given" if sent is not None else "default"


def _rounded(v, n: int):
    """``v`` (a number, a dict of numbers or None) rounded to ``n`` decimals."""
    if v is None:
        return None
    if isinstance(v, dict):
        return {k: _rounded(x, n) for k, x in v.items()}
    return round(float(v), n)


def _planned_test(
    meta: Dict[str, str], current: Optional[Params], sent: Optional[SentWith] = None
) -> PlannedTest:
    try:
        spec = spec_from_meta(meta)
    except ProgramError as exc:
        raise TraceError(
            Msg("metadata does not describe a test program: %(error)s", error=str(exc))
        ) from None
    return PlannedTest.build(spec, current, SentWith.from_meta(meta, sent))


def _settings_from_meta(meta: Dict[str, str]) -> Optional[MotionSettings]:
    try:
        return MotionSettings.from_metadata(meta)
    except ValueError as exc:  # ParamsError is a ValueError
        key = getattr(exc, "field", None) or (exc.args[0] if exc.args else "motion")
        raise TraceError(Msg("metadata '%(key)s' is not valid", key=str(key))) from None


def runs_from_native(
    trace: NativeTrace, current: Optional[Params] = None, sent: Optional[SentWith] = None
) -> Tuple[Geometry, List[Run], Mapping]:
    """Map each sample's time to its nominal angle with the planned motion."""
    meta = trace.meta
    geom = geometry_from_meta(meta)
    for key in ("feed_in_mm", "overshoot_deg"):
        meta_float(meta, key)
    if not geom.speed:
        raise TraceError(Msg("metadata 'feed_mm_min' is needed to map time to angle"))
    test = _planned_test(meta, current, sent)
    settings = _settings_from_meta(meta)
    measured = []
    for direction in test.spec.directions:
        sel = [(t, r) for dd, t, r in trace.rows if dd == direction]
        if not sel:
            continue
        arr = np.array(sel)
        order = np.argsort(arr[:, 0], kind="stable")
        t, r = arr[order, 0], arr[order, 1]
        if len(t) < 50:
            raise TraceError(
                Msg("the %(direction)s run has only %(n)s samples", direction=direction, n=len(t))
            )
        measured.append((direction, t, r))
    if not measured:
        raise TraceError(Msg("no cw or ccw samples"))
    dt = float(np.median(np.diff(measured[0][1])))
    sign, steps = ramps.reading_sign(
        measured, test.spec.feed_in_mm, max(3, int(0.3 * test.spec.dwell_s / max(dt, 1e-6)))
    )
    if sign < 0:  # a sensor that reports extension as negative: analysed the right way up
        measured = [(d, t, -r) for d, t, r in measured]
    test.use(settings or MotionSettings(constant_speed=True))
    mruns = [_measured_run(test, d, t, r) for d, t, r in measured]
    if settings is None:
        settings = estimate_motion(test, mruns)
        mruns = [_measured_run(test, d, t, r) for d, t, r in measured]
    mapping = Mapping(settings, sign=sign, feed_in_mm=test.spec.feed_in_mm, feed_in_steps=steps)
    _record_sent(mapping, test, meta, sent)
    mapping.run_order = ramps.run_order(measured, test.spec.directions)
    syncs = [sync_run(test, mr, common=False) for mr in mruns]
    _ramp_evidence(test, mruns, syncs, mapping)
    runs = []
    for mr, sync in zip(mruns, syncs):
        mapping.sync_ms[mr.direction] = float(sync.tau_out - sync.tau_in) * 1e3
        mapping.planned_s[mr.direction] = float(
            sync.t_out - sync.tau_out - (sync.t_in - sync.tau_in)
        )
        noise = _still_noise(test, mr, sync)
        if noise is not None:
            mapping.still_noise_um[mr.direction] = noise
        tp = mr.t - sync.tau(mr.t)
        runs.append(_run_on_arc(test, geom, mr.direction, tp, mr.t, mr.r))
    return geom, runs, mapping


def _ramp_evidence(test: PlannedTest, mruns, syncs, mapping: Mapping) -> None:
    """Each ramp's time against the plan and the still readings outside the circle (for the
    sensor's gain: :mod:`.ramps`) into ``mapping``."""
    for mr, sync in zip(mruns, syncs):
        rp = test.runs[mr.direction]
        mapping.ramp_speed[mr.direction] = [
            ramps.ramp_speed(test, mr.t, mr.r, k0, k1, falling, tau)
            for (k0, k1), tau, falling in (
                (rp.feed_in, sync.tau_in, True),
                (rp.feed_out, sync.tau_out, False),
            )
        ]
        mapping.still_levels += ramps.still_levels(test, mr.direction, mr.t, mr.r, sync)


def _still_noise(test: PlannedTest, mr: MeasuredRun, sync: Sync) -> Optional[float]:
    """um: the robust scatter of the readings while the head stands still before the run's
    feed-in (the dwell), a straight line taken off, at least the rounding noise of the
    reading's smallest step (step / sqrt 12); None with fewer than 20 such samples or a
    reading that does not change at all."""
    k0 = test.runs[mr.direction].feed_in[0]
    t_ramp = test.plan.block_span(k0)[0] + sync.tau_in
    # the dwell block just before the feed-in (a wait: feed 0)
    waits = np.nonzero((test.blocks.feed == 0.0) & (np.arange(len(test.blocks.feed)) < k0))[0]
    if not len(waits):
        return None
    w0, w1 = test.plan.block_span(int(waits[-1]))
    sel = (mr.t >= w0 + sync.tau_in + 0.1 * (w1 - w0)) & (
        mr.t <= min(w1 + sync.tau_in, t_ramp) - 0.01
    )
    if sel.sum() < 20:
        return None
    t, r = mr.t[sel], mr.r[sel]
    steps = np.abs(np.diff(r))
    steps = steps[steps > 1e-9]
    if not len(steps):  # a constant reading: its resolution is not known here
        return None
    coef = np.polyfit(t - t.mean(), r, 1)
    e = r - np.polyval(coef, t - t.mean())
    mad = float(1.4826 * np.median(np.abs(e - np.median(e))))
    # a coarse reading (a 1 um dial) that hardly changes still has its rounding noise
    return max(mad, float(steps.min()) / math.sqrt(12.0)) * 1e3


def chord_sag(spec: TestSpec, direction: str, theta: np.ndarray) -> np.ndarray:
    """How far (mm) the program's chords run inside the circle at nominal angles ``theta``
    (rad): ``R - R cos(d/2) / cos(t - t_mid)`` on the chord from ``t_mid - d/2`` to
    ``t_mid + d/2``."""
    a0, sweep = run_angles(spec, direction)
    ends = np.radians(np.array([a0] + arc_angles(spec, a0, sweep)))
    ends = np.sort(ends)
    i = np.clip(np.searchsorted(ends, theta) - 1, 0, len(ends) - 2)
    half = 0.5 * (ends[i + 1] - ends[i])
    mid = ends[i] + half
    R = spec.radius_mm
    return R - R * np.cos(half) / np.cos(np.clip(theta - mid, -half, half))


# a compensated path further off its chords than this many of its last decimal's units is a
# take-up move, not rounding (rounding both axes puts a point at most 0.71 of them off)
ROUNDING_ULPS = 1.0
AT_SPEED = 0.98  # overshoot samples are fitted where the planned speed is this near nominal


def _run_on_arc(
    test: PlannedTest, geom: Geometry, direction: str, tp: np.ndarray, t: np.ndarray, r: np.ndarray
) -> Run:
    """The samples on the circle: the capture arc, and the overshoot arcs where the head runs
    at its nominal speed (for the fit only; the ISO metrics use the capture arc)."""
    rp = test.runs[direction]
    blk = test.plan.block_at(tp)
    on_arc = (blk > rp.feed_in[1]) & (blk < rp.feed_out[0])
    pos, vel = test.nominal(tp)
    theta = _angles(test, direction, pos)
    return _arc_run(test, geom, direction, theta, r, t, tp, pos, vel, on_arc)


def _angles(test: PlannedTest, direction: str, pos: np.ndarray) -> np.ndarray:
    """Continuous nominal angles (rad) of positions, starting near the run's feed-in angle."""
    a, b = test.spec.axes
    c = test.spec.centre
    theta = np.unwrap(np.arctan2(pos[:, b] - c[b], pos[:, a] - c[a]))
    a0 = math.radians(run_angles(test.spec, direction)[0])
    if len(theta):
        theta = theta + 2 * math.pi * round((a0 - theta[0]) / (2 * math.pi))
    return theta


def _arc_run(
    test: PlannedTest,
    geom: Geometry,
    direction: str,
    theta: np.ndarray,
    dev: np.ndarray,
    t: np.ndarray,
    tp: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    on_arc: np.ndarray,
    overshoot: bool = True,
) -> Run:
    """A run of the samples kept (``overshoot``: also those of the overshoot arcs where the
    plan has the head at its nominal speed); the chords' sag (the program's polyline runs up to
    ``chord_error_um`` inside the circle) is taken off each reading. A compensated program
    runs off the circle by more than its chords: its coordinates are rounded to the
    compensator's decimals (3: up to 0.5 um an axis, 0.29 um rms, which left clean re-tests
    at 1.1 times the noise); there the distance of the nominal path from the circle, as the
    plan has it, is taken off instead (not on the take-up moves, where undoing the
    compensation leaves the nominal path a play's width off: :data:`ROUNDING_ULPS`)."""
    a, b = test.spec.axes
    sag = chord_sag(test.spec, direction, theta)
    if test.current is not None:
        c = test.spec.centre
        off = test.spec.radius_mm - np.hypot(pos[:, a] - c[a], pos[:, b] - c[b])
        ulp = 10.0 ** -(test.sent.decimals if test.sent is not None else 3)
        sag = np.where(np.abs(off - sag) <= ROUNDING_ULPS * ulp, off, sag)
    dev = dev + sag
    c0 = math.radians(geom.capture_start_deg)
    c1 = c0 + math.radians(geom.capture_deg)
    capture = (theta >= c0 - 1e-9) & (theta <= c1 + 1e-9)
    speed = np.hypot(vel[:, a], vel[:, b])
    at_speed = speed >= AT_SPEED * test.plan.vn[test.plan.block_at(tp)]
    keep = on_arc & (capture | (at_speed & overshoot))
    start = math.radians(run_angles(test.spec, direction)[0])
    qa = qb = None
    if test.current is not None:  # compensated: the axes went where the program said
        cmd = test.plan.sample(tp[keep])[0]
        qa, qb = cmd[:, a], cmd[:, b]
    return Run(
        direction,
        theta[keep],
        dev[keep],
        t[keep],
        vel[keep, a],
        vel[keep, b],
        capture[keep],
        start,
        None,
        qa,
        qb,
    )


def runs_from_angle(
    trace: AngleTrace, current: Optional[Params] = None, sent: Optional[SentWith] = None
) -> Tuple[Geometry, List[Run], Mapping]:
    """Angle-domain runs; velocities and times from the planned program when the metadata
    describes one (a constant feed otherwise)."""
    geom = geometry_from_meta(trace.meta)
    if geom.capture_deg is None:
        geom.capture_deg = 360.0
    raw = {}
    for direction in ("ccw", "cw"):
        sel = [(a, v) for dd, a, v in trace.rows if dd == direction]
        if sel:
            arr = np.array(sel)
            raw[direction] = (np.radians(arr[:, 0]), arr[:, 1] * 1e-3)
    if not raw:
        raise TraceError(Msg("no cw or ccw samples"))
    settings = _settings_from_meta(trace.meta)
    test = None
    if geom.feed:
        try:
            test = _planned_test(trace.meta, current, sent)
        except TraceError:
            test = None
    runs = []
    row_order = {
        d: _advancing_share(theta, 1 if d == "ccw" else -1) for d, (theta, _) in raw.items()
    }
    if test is None or any(d not in test.runs for d in raw):
        for d, (theta, dev) in raw.items():
            runs.append(Run(d, theta, dev))
        return geom, runs, Mapping(None, timed=False, planned=False, row_order=row_order)
    # without the printer's planner the head is taken to run at the feed all along: right on
    # the capture arc, wrong where it speeds up and slows down on the overshoot arcs (XZ R50
    # at 500 mm/s^2: the scale mismatch 16-19 ppm off with them, within 0.1 ppm without)
    capture_only = settings is None
    settings = settings or MotionSettings(constant_speed=True)
    test.use(settings)
    mapping = Mapping(settings, timed=False, row_order=row_order, capture_only=capture_only)
    _record_sent(mapping, test, trace.meta, sent)
    for d, (theta, dev) in raw.items():
        rp = test.runs[d]
        t0 = test.span(*rp.feed_in)[1]
        t1 = test.span(*rp.feed_out)[0]
        tp = np.linspace(t0, t1, max(200, int((t1 - t0) * 1000)))
        th = _angles(test, d, test.nominal(tp)[0])
        order = np.argsort(th)
        t_of = np.interp(theta, th[order], tp[order])
        pos, vel = test.nominal(t_of)
        on_arc = (theta >= th.min() - ARC_SLACK_RAD) & (theta <= th.max() + ARC_SLACK_RAD)
        mapping.off_arc[d] = float(np.mean(~on_arc)) if len(theta) else 0.0
        mapping.arc_span_deg[d] = [float(np.degrees(th.min())), float(np.degrees(th.max()))]
        on_arc &= (theta >= th.min()) & (theta <= th.max())
        run = _arc_run(test, geom, d, theta, dev, t_of, t_of, pos, vel, on_arc, not capture_only)
        runs.append(run)
    return geom, runs, mapping


ARC_SLACK_RAD = math.radians(1.0)  # an angle this far beyond the program's run is off its arc


def _advancing_share(theta: np.ndarray, w: int) -> float:
    """The share of row-to-row steps (file order) whose angle moves in direction ``w``."""
    steps = np.diff(theta)
    steps = steps[steps != 0]
    return float(np.mean(w * steps > 0)) if len(steps) else 1.0
