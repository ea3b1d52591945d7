"""Ballbar trace analysis: from readings to errors, ISO 230-4 metrics and KinComp parameters.

Geometry and signs (A, B = the plane's first and second axis; angle t from +A towards +B;
``w = +1`` counter-clockwise, ``-1`` clockwise; deviations positive = bar longer):

* squareness ``alpha`` (um/m): actual A = A + alpha*B (KinComp's ``xy``/``xz``/``yz``);
  first-order signature ``(alpha R / 2) sin 2t``, the same in both directions;
* scale mismatch ``sA - sB`` (ppm): ``R (sA - sB)/2 cos 2t``; the mean scale only shows in the
  mean radius, which an uncalibrated bar cannot tell from its own length error;
* servo mismatch ``TA - TB`` (ms): the lagging axis is ``v T`` behind, ``w (v dT / 2) sin 2t``,
  which flips with the direction and so separates from squareness;
* backlash: the carriage lags ``b(q)/2`` behind its drive, ``b`` varying linearly between the
  value at the -end and at the +end of the circle; each per-side value is the local step of the
  trace at that reversal point;
* straightness (bow) ``e_B = kA A^2``, ``e_A = kB B^2`` about the centre: the 3-theta terms
  that partial (220 deg) arcs need to keep the scale mismatch unbiased.

The fit is a joint least-squares fit of both directions with one common centre, iterated on the
exact geometry (Gauss-Newton with the exact model and its numerical Jacobian), so that large
errors such as the paper's -3638.6 um/m squareness do not bias the other terms through
second-order effects. Samples within ``mask_deg`` after each reversal point are left out of the
fit (reversal spikes, backlash take-up). ISO 230-4 metrics are computed on all captured samples
with least-squares (LSC) centres; minimum-zone (MZC) values are given as well.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..core.kinematics import changes_nothing
from ..core.messages import Msg, error_message
from ..core.params import AXES, Params, ParamsError
from .formats import (
    AngleTrace,
    NativeTrace,
    Summary,
    TraceError,
    meta_centre,
    meta_float,
    meta_plane,
)
from .program import PLANES as PROGRAM_PLANES

PLANE_KEYS = {"XY": "xy", "XZ": "xz", "YZ": "yz"}
DEFAULT_MASK_DEG = 15.0


@dataclass
class Run:
    direction: str
    theta: np.ndarray  # rad, nominal commanded angle
    dev: np.ndarray  # mm, bar length change

    @property
    def w(self) -> int:
        return 1 if self.direction == "ccw" else -1


@dataclass
class Geometry:
    plane: str
    radius: float  # mm
    centre: Optional[Tuple[float, float, float]]
    feed: Optional[float]  # mm/min
    capture_start_deg: Optional[float] = None
    capture_deg: Optional[float] = None

    @property
    def axes(self) -> Tuple[int, int]:
        return PROGRAM_PLANES[self.plane]

    @property
    def letters(self) -> Tuple[str, str]:
        a, b = self.axes
        return AXES[a], AXES[b]

    @property
    def speed(self) -> Optional[float]:
        return None if not self.feed else self.feed / 60.0


# ---------------------------------------------------------------------------------------
# traces -> runs


def _geometry(meta: Dict[str, str]) -> Geometry:
    plane = meta_plane(meta)
    radius = meta_float(meta, "radius_mm")
    if not (1.0 <= radius <= 2000.0):
        raise TraceError(Msg("metadata 'radius_mm' %(value)s is out of range (1..2000)",
                             value=f"{radius:g}"))
    feed = meta_float(meta, "feed_mm_min", 0.0) or None
    start = meta_float(meta, "start_deg", 0.0 if plane == "XY" else -20.0)
    cap = meta_float(meta, "capture_deg", 360.0 if plane == "XY" else 220.0)
    return Geometry(plane, radius, meta_centre(meta), feed, start, cap)


def _level(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def _crossing(t: np.ndarray, r: np.ndarray, level: float, i0: int, i1: int,
              falling: bool) -> float:
    """Time where r crosses ``level`` between indices i0 and i1 (linear interpolation)."""
    for i in range(max(i0, 1), min(i1, len(r))):
        a, b = r[i - 1], r[i]
        if (falling and a >= level > b) or (not falling and a <= level < b):
            return float(t[i - 1] + (t[i] - t[i - 1]) * (a - level) / (a - b))
    raise TraceError(Msg("feed-in/feed-out marker not found (is this the right program?)"))


def runs_from_native(trace: NativeTrace) -> Tuple[Geometry, List[Run]]:
    """Map time to angle with the feed-in and feed-out ramps as markers."""
    from .program import TestSpec, run_angles

    meta = trace.meta
    geom = _geometry(meta)
    d = meta_float(meta, "feed_in_mm")
    over = meta_float(meta, "overshoot_deg")
    dwell = meta_float(meta, "dwell_s", 1.0)
    if not geom.speed:
        raise TraceError(Msg("metadata 'feed_mm_min' is needed to map time to angle"))
    v = geom.speed
    spec = TestSpec(plane=geom.plane, centre=geom.centre or (0.0, 0.0, 0.0),
                    radius_mm=geom.radius, feed_mm_min=geom.feed, feed_in_mm=d,
                    overshoot_deg=over, capture_deg=geom.capture_deg,
                    start_deg=geom.capture_start_deg)
    runs = []
    for direction in ("ccw", "cw"):
        sel = [(t, r) for dd, t, r in trace.rows if dd == direction]
        if not sel:
            continue
        arr = np.array(sel)
        order = np.argsort(arr[:, 0], kind="stable")
        t, r = arr[order, 0], arr[order, 1]
        if len(t) < 50:
            raise TraceError(Msg("the %(direction)s run has only %(n)s samples",
                                 direction=direction, n=len(t)))
        dt = float(np.median(np.diff(t)))
        n_dwell = max(3, int(0.5 * dwell / dt)) if dt > 0 else 3
        hi0 = _level(r[:n_dwell])
        below = np.nonzero(r < hi0 - 0.1 * d)[0]
        if len(below) == 0:
            raise TraceError(Msg("%(direction)s run: no radial feed-in found",
                                 direction=direction))
        i_start = int(below[0])
        t_ramp_end = t[i_start] + d / v
        win = (t > t_ramp_end + 0.05) & (t < t_ramp_end + 0.15)
        lo0 = _level(r[win])
        t_in = _crossing(t, r, (hi0 + lo0) / 2, i_start - 5, i_start + int(2 * d / v / dt) + 10,
                         falling=True)
        hi1 = _level(r[-n_dwell:])
        above_out = np.nonzero(r < hi1 - 0.1 * d)[0]
        i_end = int(above_out[-1])
        t_ramp_start = t[i_end] - d / v
        win = (t > t_ramp_start - 0.15) & (t < t_ramp_start - 0.05)
        lo1 = _level(r[win])
        t_out = _crossing(t, r, (hi1 + lo1) / 2, i_end - int(2 * d / v / dt) - 10, i_end + 5,
                          falling=False)
        a0, sweep = run_angles(spec, direction)
        t_arc0 = t_in + (d / 2) / v
        t_arc1 = t_out - (d / 2) / v
        if t_arc1 <= t_arc0:
            raise TraceError(Msg("%(direction)s run: markers out of order",
                                 direction=direction))
        omega = math.radians(abs(sweep)) / (t_arc1 - t_arc0)
        w = 1 if direction == "ccw" else -1
        theta = math.radians(a0) + w * omega * (t - t_arc0)
        c0 = math.radians(geom.capture_start_deg)
        c1 = c0 + math.radians(geom.capture_deg)
        keep = (theta >= c0 - 1e-9) & (theta <= c1 + 1e-9)
        runs.append(Run(direction, theta[keep], r[keep]))
    if not runs:
        raise TraceError(Msg("no cw or ccw samples"))
    return geom, runs


def runs_from_angle(trace: AngleTrace) -> Tuple[Geometry, List[Run]]:
    geom = _geometry(trace.meta)
    runs = []
    for direction in ("ccw", "cw"):
        sel = [(a, v) for dd, a, v in trace.rows if dd == direction]
        if sel:
            arr = np.array(sel)
            runs.append(Run(direction, np.radians(arr[:, 0]), arr[:, 1] * 1e-3))
    if geom.capture_deg is None:
        geom.capture_deg = 360.0
    return geom, runs


# ---------------------------------------------------------------------------------------
# the exact model and the fit

BASE = ("r0", "dA", "dB", "ds", "alpha", "dT", "bAp", "bAm", "bBp", "bBm", "kA", "kB")


class Model:
    """Exact radial deviation (mm) of the circle test for a parameter vector."""

    def __init__(self, geom: Geometry, runs: Sequence[Run], fit_servo: bool,
                 calibrated: bool, cyclic_pitch: Optional[float]):
        self.R = geom.radius
        self.v = geom.speed or 0.0
        self.names = list(BASE)
        if not fit_servo:
            self.names.remove("dT")
        if calibrated:
            self.names.append("sm")
        self.cyclic_pitch = cyclic_pitch
        if cyclic_pitch:
            self.names += ["cAs", "cAc", "cBs", "cBc"]
        self.geom = geom
        self.theta = np.concatenate([r.theta for r in runs])
        self.w = np.concatenate([np.full(len(r.theta), r.w, dtype=float) for r in runs])

    def predict(self, p: np.ndarray, theta=None, w=None) -> np.ndarray:
        theta = self.theta if theta is None else theta
        w = self.w if w is None else w
        P = dict(zip(self.names, p))
        R, v = self.R, self.v
        c, s = np.cos(theta), np.sin(theta)
        A, B = R * c, R * s
        vA, vB = -w * v * s, w * v * c
        bA = P["bAm"] + (P["bAp"] - P["bAm"]) * (1 + c) / 2
        bB = P["bBm"] + (P["bBp"] - P["bBm"]) * (1 + s) / 2
        Ac = A - np.sign(vA) * bA / 2 - P.get("dT", 0.0) * vA + P["kB"] * B * B
        Bc = B - np.sign(vB) * bB / 2 + P["kA"] * A * A
        if self.cyclic_pitch:
            ca, cb = self.geom.centre[self.geom.axes[0]], self.geom.centre[self.geom.axes[1]]
            k = 2 * math.pi / self.cyclic_pitch
            Ac = Ac + P["cAs"] * np.sin(k * (ca + A)) + P["cAc"] * np.cos(k * (ca + A))
            Bc = Bc + P["cBs"] * np.sin(k * (cb + B)) + P["cBc"] * np.cos(k * (cb + B))
        sm = P.get("sm", 0.0)
        sA, sB = sm + P["ds"] / 2, sm - P["ds"] / 2
        X = (1 + sA) * Ac + P["alpha"] * (1 + sB) * Bc - P["dA"]
        Y = (1 + sB) * Bc - P["dB"]
        return np.hypot(X, Y) - R + P["r0"]

    def jacobian(self, p: np.ndarray, mask) -> np.ndarray:
        cols = []
        for j in range(len(p)):
            h = 1e-6 if self.names[j] not in ("alpha", "ds", "sm", "dT") else 1e-7
            if self.names[j] in ("kA", "kB"):
                h = 1e-9
            e = np.zeros_like(p)
            e[j] = h
            cols.append((self.predict(p + e)[mask] - self.predict(p - e)[mask]) / (2 * h))
        return np.stack(cols, axis=1)


def reversal_mask(theta: np.ndarray, w: np.ndarray, mask_deg: float) -> np.ndarray:
    """True for samples kept: not within ``mask_deg`` after a quadrant (reversal) point."""
    deg = np.degrees(theta)
    keep = np.ones(len(theta), dtype=bool)
    for rev in (0.0, 90.0, 180.0, 270.0):
        phi = np.mod(w * (deg - rev), 360.0)
        keep &= ~((phi < mask_deg) | (phi > 359.0))
    return keep


@dataclass
class FitResult:
    values: Dict[str, float]
    rms_um: float
    samples: int
    masked: int
    condition: float
    iterations: int
    residuals: Dict[str, Tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def fit(geom: Geometry, runs: Sequence[Run], mask_deg: float = DEFAULT_MASK_DEG,
        calibrated: bool = False, cyclic_pitch: Optional[float] = None,
        max_iter: int = 12) -> FitResult:
    both = {r.direction for r in runs} == {"cw", "ccw"}
    fit_servo = both and bool(geom.speed)
    model = Model(geom, runs, fit_servo, calibrated, cyclic_pitch)
    y = np.concatenate([r.dev for r in runs])
    keep = reversal_mask(model.theta, model.w, mask_deg)
    if keep.sum() < len(model.names) * 5:
        raise TraceError(Msg("too few samples left after masking the reversal points"))
    p = np.zeros(len(model.names))
    cond = float("nan")
    it = 0
    for it in range(1, max_iter + 1):
        r = (y - model.predict(p))[keep]
        J = model.jacobian(p, keep)
        # column scaling for a meaningful condition number and a stable solve
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        step, *_ = np.linalg.lstsq(J / scale, r, rcond=None)
        step /= scale
        p = p + step
        sv = np.linalg.svd(J / scale, compute_uv=False)
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
        if np.max(np.abs(step * scale)) < 1e-10:
            break
    res = y - model.predict(p)
    rms = float(np.sqrt(np.mean(res[keep] ** 2)) * 1e3)
    values = dict(zip(model.names, p.tolist()))
    out = FitResult(values, rms, int(keep.sum()), int((~keep).sum()), cond, it)
    i = 0
    for run in runs:
        n = len(run.theta)
        out.residuals[run.direction] = (run.theta, res[i:i + n])
        i += n
    return out


# ---------------------------------------------------------------------------------------
# ISO 230-4 metrics


def _lsc(theta, dev, fit_radius=True):
    cols = [np.cos(theta), np.sin(theta)]
    if fit_radius:
        cols.insert(0, np.ones_like(theta))
    M = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(M, dev, rcond=None)
    return dev - M @ coef, coef


def _mzc_range(theta, dev, iters: int = 300) -> float:
    """Minimum-zone circularity (max - min after the best centre) by Lawson's L-infinity IRLS."""
    M = np.stack([np.ones_like(theta), np.cos(theta), np.sin(theta)], axis=1)
    wts = np.full(len(dev), 1.0 / len(dev))
    best = float("inf")
    for _ in range(iters):
        sw = np.sqrt(wts)
        coef, *_ = np.linalg.lstsq(M * sw[:, None], dev * sw, rcond=None)
        e = dev - M @ coef
        best = min(best, float(e.max() - e.min()))
        a = np.abs(e)
        wts = wts * a
        tot = wts.sum()
        if tot <= 0:
            break
        wts /= tot
    return best


def iso_metrics(geom: Geometry, runs: Sequence[Run], calibrated: bool) -> Dict[str, object]:
    by = {r.direction: r for r in runs}
    circ, mzc = {}, {}
    for d, r in by.items():
        e, _ = _lsc(r.theta, r.dev)
        circ[d] = float(e.max() - e.min()) * 1e3
        mzc[d] = _mzc_range(r.theta, r.dev) * 1e3
    theta = np.concatenate([r.theta for r in runs])
    dev = np.concatenate([r.dev for r in runs])
    e, coef = _lsc(theta, dev)
    circ["bidirectional"] = float(e.max() - e.min()) * 1e3
    mzc["bidirectional"] = _mzc_range(theta, dev) * 1e3
    out: Dict[str, object] = {"circularity_um": circ, "circularity_mzc_um": mzc}
    if len(by) == 2:
        # hysteresis: CW vs CCW at the same angle, common centre removed
        centred = {d: r.dev - coef[1] * np.cos(r.theta) - coef[2] * np.sin(r.theta)
                   for d, r in by.items()}
        a = by["ccw"]
        b = by["cw"]
        order = np.argsort(b.theta)
        lo, hi = b.theta[order][0], b.theta[order][-1]
        inside = (a.theta >= lo) & (a.theta <= hi)
        interp = np.interp(a.theta[inside], b.theta[order], centred["cw"][order])
        out["hysteresis_um"] = float(np.max(np.abs(centred["ccw"][inside] - interp))) * 1e3
    if calibrated:
        radial = dev - coef[1] * np.cos(theta) - coef[2] * np.sin(theta)
        out["radial_deviation_um"] = {"max": float(radial.max()) * 1e3,
                                      "min": float(radial.min()) * 1e3}
    else:
        out["radial_deviation_um"] = None
    out["iso_centre"] = ("least-squares centre (LSC) per direction; common LSC centre for the "
                         "bidirectional value and hysteresis; circularity_mzc_um uses the "
                         "minimum-zone centre")
    return out


# ---------------------------------------------------------------------------------------
# the whole analysis


def analyse_runs(geom: Geometry, runs: Sequence[Run], meta: Dict[str, str],
                 mask_deg: float = DEFAULT_MASK_DEG, calibrated: bool = False,
                 cyclic_pitch: Optional[float] = None, f: Optional[FitResult] = None
                 ) -> Dict[str, object]:
    if f is None:
        f = fit(geom, runs, mask_deg, calibrated, cyclic_pitch)
    v = f.values
    la, lb = geom.letters
    diag: Dict[str, object] = {
        "plane": geom.plane,
        "axes": {"a": la.upper(), "b": lb.upper()},
        "radius_mm": geom.radius,
        "feed_mm_min": geom.feed,
        "centre": list(geom.centre) if geom.centre else None,
        "simulated": meta.get("simulated", "").lower() == "true",
        "squareness_um_per_m": v["alpha"] * 1e6,
        "scale_mismatch_ppm": v["ds"] * 1e6,
        "servo_mismatch_ms": v["dT"] * 1e3 if "dT" in v else None,
        "backlash_um": {"a_plus": v["bAp"] * 1e3, "a_minus": v["bAm"] * 1e3,
                        "b_plus": v["bBp"] * 1e3, "b_minus": v["bBm"] * 1e3},
        "centre_offset_um": {"a": v["dA"] * 1e3, "b": v["dB"] * 1e3},
        "radius_offset_um": v["r0"] * 1e3,
        "bar_calibrated": calibrated,
        "straightness_um": {"a": v["kA"] * geom.radius ** 2 * 1e3,
                            "b": v["kB"] * geom.radius ** 2 * 1e3},
    }
    if calibrated:
        diag["mean_scale_ppm"] = v["sm"] * 1e6
    if cyclic_pitch:
        diag["cyclic_error_um"] = {
            "a": math.hypot(v["cAs"], v["cAc"]) * 1e3, "b": math.hypot(v["cBs"], v["cBc"]) * 1e3,
            "pitch_mm": cyclic_pitch}
    diag.update(iso_metrics(geom, runs, calibrated))
    diag["fit"] = {"rms_um": f.rms_um, "samples": f.samples, "masked": f.masked,
                   "mask_deg": mask_deg, "condition": f.condition, "iterations": f.iterations,
                   "model": "exact geometry, joint CW+CCW, common centre"}
    return diag


def load_runs(trace) -> Tuple[Geometry, List[Run]]:
    if isinstance(trace, NativeTrace):
        return runs_from_native(trace)
    if isinstance(trace, AngleTrace):
        return runs_from_angle(trace)
    raise TraceError(Msg("not a trace"))


def analyse(trace, current: Optional[Params] = None, mask_deg: float = DEFAULT_MASK_DEG,
            calibrated: bool = False, cyclic_pitch: Optional[float] = None) -> Dict[str, object]:
    """Analyse a trace or summary; returns {"diagnostics", "parameters", "firmware", "notes"}."""
    from ..core.firmware import equivalents

    current = current or Params()
    notes: List[str] = []
    plot = None
    if isinstance(trace, Summary):
        diag = dict(trace.diagnostics)
        geom = Geometry(meta_plane(trace.meta),
                        meta_float(trace.meta, "radius_mm", 0.0),
                        meta_centre(trace.meta),
                        meta_float(trace.meta, "feed_mm_min", 0.0) or None)
        diag.setdefault("plane", geom.plane)
        diag["source"] = trace.meta.get("source", "summary")
        notes += trace.notes
    else:
        geom, runs = load_runs(trace)
        f = fit(geom, runs, mask_deg, calibrated, cyclic_pitch)
        diag = analyse_runs(geom, runs, trace.meta, mask_deg, calibrated, cyclic_pitch, f)
        plot = plot_data(geom, runs, f, diag)
        if not calibrated:
            notes.append(Msg("The bar is not calibrated: the mean radius mixes the bar's own "
                             "length error with the mean axis scale, so only the scale "
                             "mismatch is used."))
    if current is not None and not changes_nothing(current):
        notes.append(Msg("The test ran with compensation active: the fitted errors are "
                         "residuals and the proposed parameters are current + residual."))
    params = propose_params(diag, geom, current, notes)
    return {
        "diagnostics": diag,
        "parameters": params.to_dict(),
        "firmware": equivalents(params),
        "notes": notes,
        "plot": plot,
    }


def plot_data(geom: Geometry, runs: Sequence[Run], f: FitResult, diag: Dict[str, object],
              bins: int = 720) -> Dict[str, object]:
    """What a ballbar plot shows: per direction the deviation (um) against the angle (deg)
    with the common least-squares centre and the mean radius removed, and the fitted model
    on the same footing (the fitted ellipse), averaged into ``bins`` angle bins."""
    theta = np.concatenate([r.theta for r in runs])
    dev = np.concatenate([r.dev for r in runs])
    _, coef = _lsc(theta, dev)
    model = Model(geom, runs, "dT" in f.values, "sm" in f.values, None)
    names = [n for n in model.names if n in f.values]
    model.names = names
    pred = model.predict(np.array([f.values[n] for n in names]))
    out: Dict[str, object] = {
        "plane": geom.plane, "axes": diag.get("axes"), "radius_mm": geom.radius,
        "simulated": bool(diag.get("simulated")), "directions": {},
        "centre_removed_um": {"a": float(coef[1]) * 1e3, "b": float(coef[2]) * 1e3},
    }
    i = 0
    for run in runs:
        n = len(run.theta)
        th = run.theta
        base = coef[0] + coef[1] * np.cos(th) + coef[2] * np.sin(th)
        d = (run.dev - base) * 1e3
        m = (pred[i:i + n] - base) * 1e3
        i += n
        deg = np.degrees(th)
        lo, hi = float(deg.min()), float(deg.max())
        edges = np.linspace(lo, hi, min(bins, max(2, n)) + 1)
        which = np.clip(np.searchsorted(edges, deg, side="right") - 1, 0, len(edges) - 2)
        cnt = np.bincount(which, minlength=len(edges) - 1)
        ok = cnt > 0
        mean = lambda v: (np.bincount(which, weights=v, minlength=len(edges) - 1)[ok]
                          / cnt[ok])
        out["directions"][run.direction] = {
            "angle_deg": np.round(mean(deg), 3).tolist(),
            "dev_um": np.round(mean(d), 3).tolist(),
            "fit_um": np.round(mean(m), 3).tolist(),
        }
    return out


def propose_params(diag: Dict[str, object], geom: Geometry, current: Params,
                   notes: List[str]) -> Params:
    """Current parameters updated with the residual errors of one test (see module doc)."""
    a, b = geom.axes
    d = current.to_dict()
    # Linear part: compose the residual machine with the current model exactly, then split it
    # back into alignment (unit upper triangular) times scale (diagonal).
    A_cur = np.eye(3)
    sq = current.squareness_um_per_m
    S = np.array([[1, sq["xy"] * 1e-6, sq["xz"] * 1e-6], [0, 1, sq["yz"] * 1e-6], [0, 0, 1]])
    D = np.diag([1 + current.scale_ppm[k] * 1e-6 for k in AXES])
    A_cur = S @ D
    alpha = float(diag.get("squareness_um_per_m") or 0.0) * 1e-6
    ds = float(diag.get("scale_mismatch_ppm") or 0.0) * 1e-6
    sm = float(diag.get("mean_scale_ppm") or 0.0) * 1e-6
    sA, sB = sm + ds / 2, sm - ds / 2
    A_res = np.eye(3)
    A_res[a, a] = 1 + sA
    A_res[b, b] = 1 + sB
    absolute = diag.get("scale_ppm")  # per-axis absolute scales (printed artifacts)
    if isinstance(absolute, dict):
        for k, letter in enumerate(AXES):
            if absolute.get(letter) is not None:
                A_res[k, k] = 1 + float(absolute[letter]) * 1e-6
    A_res[a, b] = alpha * A_res[b, b]
    A_true = A_res @ A_cur
    Dn = np.diag(A_true)
    Sn = A_true / Dn[None, :]
    d["squareness_um_per_m"] = {"xy": Sn[0, 1] * 1e6, "xz": Sn[0, 2] * 1e6, "yz": Sn[1, 2] * 1e6}
    d["scale_ppm"] = {k: (Dn[i] - 1) * 1e6 for i, k in enumerate(AXES)}
    # Backlash: true = residual step + what was applied, per end of the circle.
    bl = diag.get("backlash_um")
    if isinstance(bl, dict) and bl:
        frac = current.backlash_fraction if current.has_backlash else 0.0
        for ax, tag in ((a, "a"), (b, "b")):
            plus = bl.get(f"{tag}_plus")
            minus = bl.get(f"{tag}_minus")
            if plus is None and minus is None:
                continue
            plus = minus if plus is None else plus
            minus = plus if minus is None else minus
            table = current.backlash[AXES[ax]]
            if geom.centre is not None and geom.radius:
                lo = geom.centre[ax] - geom.radius
                hi = geom.centre[ax] + geom.radius
                vals = (max(0.0, minus + frac * table.um_at(lo)),
                        max(0.0, plus + frac * table.um_at(hi)))
                d["backlash"][AXES[ax]] = [{"at_mm": lo, "um": vals[0]},
                                           {"at_mm": hi, "um": vals[1]}]
            else:
                mean_cur = sum(um for _, um in table.points) / len(table.points)
                d["backlash"][AXES[ax]] = max(0.0, (plus + minus) / 2 + frac * mean_cur)
                notes.append(Msg("Backlash of %(axis)s set to the mean of both ends: the "
                                 "test centre is unknown.", axis=AXES[ax].upper()))
            if min(plus, minus) < -0.5:
                notes.append(Msg("Negative residual backlash on %(axis)s: the current value "
                                 "over-compensates.", axis=AXES[ax].upper()))
        if current.backlash_fraction == 0:
            d["backlash"]["fraction"] = 1.0
        elif current.backlash_fraction < 1.0:
            notes.append(Msg("Backlash values are the measured lost motion; the fraction "
                             "stays at %(fraction)s, so %(fraction)s of it is taken up (set "
                             "the fraction to 1 for all of it).",
                             fraction=f"{current.backlash_fraction:g}"))
    # Servo lag: mismatch assigned to the first axis of the plane.
    dT = diag.get("servo_mismatch_ms")
    if dT is not None:
        applied = current.servo_lag_ms if current.servo_precomp else {k: 0.0 for k in AXES}
        lag = dict(applied)
        lag[AXES[a]] = applied[AXES[a]] + float(dT)
        d["servo_lag_ms"] = lag
        d["servo_precomp"] = current.servo_precomp
    d["meta"] = {
        "source": str(diag.get("source") or "ballbar analysis")
        + (" (SIMULATED data)" if diag.get("simulated") else ""),
        "plane": geom.plane,
        "date": _dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "based_on": current.hash(),
    }
    try:
        return Params.from_dict(d)
    except ParamsError as exc:
        raise TraceError(Msg("the proposed parameters are out of range (%(error)s); errors "
                             "this large are implausible: check the set-up and the "
                             "measurement", error=error_message(exc))) from None
