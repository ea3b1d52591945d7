"""The exact radial-deviation model of a ballbar test and its least-squares fit.

Geometry and signs (A, B = the plane's first and second axis; angle t from +A towards +B;
``w = +1`` counter-clockwise, ``-1`` clockwise; deviations positive = bar longer):

* squareness ``alpha`` (rad, reported in um/m): actual A = A + alpha*B (KinComp's ``xy``/``xz``/
  ``yz``); first-order signature ``(alpha R / 2) sin 2t``, the same in both directions;
* scale mismatch ``ds = sA - sB`` (reported in ppm): ``R ds/2 cos 2t``; the mean scale ``sm``
  only shows in the mean radius: fitted instead of the radius offset ``r0`` for a calibrated
  bar (whose length is known), otherwise ``r0`` holds both it and the bar's length error;
* servo mismatch ``dT = TA - TB`` (s, reported in ms): the A drive is ``dT * vA`` further
  behind than B, with ``vA, vB`` the commanded velocities of the planned motion at each sample
  (``-w v sin t, w v cos t`` at constant speed), so it flips with the direction;
* backlash: the carriage lags ``b(q)/2`` behind its drive, ``b`` linear between the value at the
  -end (``bAm``, ``bBm``) and the +end (``bAp``, ``bBp``) of the circle (um in reports);
* straightness (bow) ``e_B = kA A^2``, ``e_A = kB B^2`` about the centre: the 3-theta terms that
  partial (220 deg) arcs need to keep the scale mismatch unbiased;
* ``drift`` (mm/s): a bar length change linear in time (thermal drift), when sample times are
  known; ``r0``, ``dA``, ``dB``: radius and centre offsets (set-up, discarded);
* out of the plane (fixed, not fitted from one test): the third axis moves by
  ``oA (1+sA) A + oB (1+sB) B`` (e.g. in YZ, X = xy*Y + xz*Z), which lengthens the bar by the
  second order; a campaign's joint fit ties ``oA, oB`` to the squareness of the other planes.

The fit is a joint least-squares fit of both directions with one common centre, iterated on the
exact geometry (Gauss-Newton with the exact model and its numerical Jacobian). Samples within
``mask_deg`` after each reversal point are left out (spikes, take-up). Every fitted value gets a
1-sigma uncertainty from the covariance ``s^2 (J^T J)^-1`` (``s`` the residual rms), inflated
by ``sqrt((1 + rho) / (1 - rho))`` when the residuals are correlated from sample to sample
(``rho`` their lag-1 autocorrelation, e.g. from stepper quantisation or spikes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...core.messages import Msg
from ...core.params import AXES
from .formats import TraceError
from .program import PLANES as PROGRAM_PLANES

DEFAULT_MASK_DEG = 15.0
# per plane, the squareness (KinComp's key) that moves the third axis with A and with B
# (``oA``, ``oB``): YZ: X = xy*Y + xz*Z; XZ: Y = yz*Z; XY: none
OUT_OF_PLANE: Dict[str, Tuple[Optional[str], Optional[str]]] = {
    "YZ": ("xy", "xz"),
    "XZ": (None, "yz"),
}


def out_of_plane_terms(plane: str, squareness: Dict[str, float]) -> Dict[str, float]:
    """The fixed out-of-plane terms ``{"oA", "oB"}`` (rad) of a test in ``plane`` for the
    squareness ``squareness`` (rad, KinComp's keys; a missing key counts as 0) that moves the
    third axis: what the model adds with ``fixed`` ({} for XY). The one map from squareness to
    those terms: the joint fit and a single test given known squareness both use it."""
    if plane not in OUT_OF_PLANE:
        return {}
    return {
        o: float(squareness.get(k, 0.0)) if k else 0.0
        for o, k in zip(("oA", "oB"), OUT_OF_PLANE[plane])
    }


def out_of_plane_bias(oA: float, oB: float) -> Tuple[float, float]:
    """What a fit without the out-of-plane terms ``oA``, ``oB`` (rad) reads that is not
    there: (scale mismatch ppm, squareness um/m) = ((oA^2 - oB^2) / 2, oA oB), from the
    bar's second-order lengthening ``(oA A + oB B)^2 / 2R``."""
    return (oA * oA - oB * oB) / 2 * 1e6, oA * oB * 1e6


BASE = ("r0", "dA", "dB", "ds", "alpha", "dT", "bAp", "bAm", "bBp", "bBm", "kA", "kB")


@dataclass
class Run:
    direction: str
    theta: np.ndarray  # rad, nominal commanded angle
    dev: np.ndarray  # mm, bar length change
    t: Optional[np.ndarray] = None  # s, sample time (measured, or planned for angle traces)
    vA: Optional[np.ndarray] = None  # mm/s, commanded velocity of axis A (planned motion)
    vB: Optional[np.ndarray] = None
    capture: Optional[np.ndarray] = None  # bool per sample: inside the capture arc (None: all)
    start_theta: Optional[float] = None  # rad, where the arc started (a corner: masked)
    # mm (+ = bar longer): the part of ``dev`` that the settings in force explain besides the
    # fitted terms (analysis._lead_speed_error); the fit takes it off, the ISO metrics do not
    known: Optional[np.ndarray] = None
    # mm: the commanded positions of axes A and B where they differ from the nominal circle
    # (a program compensated with the parameters in force); a cyclic error follows them
    qA: Optional[np.ndarray] = None
    qB: Optional[np.ndarray] = None

    def fit_dev(self) -> np.ndarray:
        """mm: the deviation the fit models."""
        return self.dev if self.known is None else self.dev - self.known

    @property
    def w(self) -> int:
        return 1 if self.direction == "ccw" else -1

    def captured(self) -> Run:
        """The samples inside the capture arc (what the ISO metrics evaluate)."""
        if self.capture is None or self.capture.all():
            return self
        k = self.capture

        def pick(x):
            return None if x is None else x[k]

        return Run(
            self.direction,
            self.theta[k],
            self.dev[k],
            pick(self.t),
            pick(self.vA),
            pick(self.vB),
            None,
            self.start_theta,
            pick(self.known),
            pick(self.qA),
            pick(self.qB),
        )


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


class Model:
    """Exact radial deviation (mm) of the circle test for a parameter vector."""

    def __init__(
        self,
        geom: Geometry,
        runs: Sequence[Run],
        fit_servo: bool,
        calibrated: bool,
        cyclic_pitch: Optional[float],
        fit_drift: bool = False,
        fixed: Optional[Dict[str, float]] = None,
        t_ref: Optional[float] = None,
    ):
        self.R = geom.radius
        self.fixed = dict(fixed or {})
        v = geom.speed or 0.0
        self.names = list(BASE)
        if not fit_servo:
            self.names.remove("dT")
        if calibrated:  # the bar's length is known: the mean radius is the mean scale
            self.names.remove("r0")
            self.names.append("sm")
        if fit_drift:
            self.names.append("drift")
        self.cyclic_pitch = cyclic_pitch
        if cyclic_pitch:
            self.names += ["cAs", "cAc", "cBs", "cBc"]
        self.geom = geom
        self.theta = np.concatenate([r.theta for r in runs])
        self.w = np.concatenate([np.full(len(r.theta), r.w, dtype=float) for r in runs])
        vA, vB, ts, dA, dB = [], [], [], [], []
        for r in runs:
            s, c = np.sin(r.theta), np.cos(r.theta)
            vA.append(r.vA if r.vA is not None else -r.w * v * s)
            vB.append(r.vB if r.vB is not None else r.w * v * c)
            # travel direction of each axis (also known when the feed is not)
            dA.append(np.sign(r.vA) if r.vA is not None else np.sign(-r.w * s))
            dB.append(np.sign(r.vB) if r.vB is not None else np.sign(r.w * c))
            ts.append(r.t if r.t is not None else np.zeros(len(r.theta)))
        self.vA = np.concatenate(vA)
        self.vB = np.concatenate(vB)
        self.dirA = np.concatenate(dA)
        self.dirB = np.concatenate(dB)
        t = np.concatenate(ts)
        if t_ref is None:
            t_ref = 0.5 * (t.min() + t.max()) if len(t) else 0.0
        self.t_ref = float(t_ref)
        self.t = t - self.t_ref
        self._c, self._s = np.cos(self.theta), np.sin(self.theta)
        self.qA = self.qB = None  # commanded positions (mm) for the cyclic phase
        if cyclic_pitch and all(r.qA is not None for r in runs):
            self.qA = np.concatenate([r.qA for r in runs])
            self.qB = np.concatenate([r.qB for r in runs])
        # what does not depend on the parameters, computed once (the same expressions as
        # predict had: the same numbers): the nominal positions, the cyclic phase terms
        self._A, self._B = self.R * self._c, self.R * self._s
        self._1c, self._1s = 1 + self._c, 1 + self._s
        self._cyclic = None
        if cyclic_pitch:
            ca, cb = geom.centre[geom.axes[0]], geom.centre[geom.axes[1]]
            k = 2 * math.pi / cyclic_pitch
            qa = ca + self._A if self.qA is None else self.qA
            qb = cb + self._B if self.qB is None else self.qB
            self._cyclic = (np.sin(k * qa), np.cos(k * qa), np.sin(k * qb), np.cos(k * qb))

    def predict(self, p: np.ndarray) -> np.ndarray:
        P = dict(self.fixed)
        P.update(zip(self.names, p))
        R = self.R
        A, B = self._A, self._B
        vA = self.vA
        bA = P["bAm"] + (P["bAp"] - P["bAm"]) * self._1c / 2
        bB = P["bBm"] + (P["bBp"] - P["bBm"]) * self._1s / 2
        Ac = A - self.dirA * bA / 2 - P.get("dT", 0.0) * vA + P["kB"] * B * B
        Bc = B - self.dirB * bB / 2 + P["kA"] * A * A
        if self._cyclic is not None:
            sin_a, cos_a, sin_b, cos_b = self._cyclic
            Ac = Ac + P["cAs"] * sin_a + P["cAc"] * cos_a
            Bc = Bc + P["cBs"] * sin_b + P["cBc"] * cos_b
        sm = P.get("sm", 0.0)
        sA, sB = sm + P["ds"] / 2, sm - P["ds"] / 2
        X = (1 + sA) * Ac + P["alpha"] * (1 + sB) * Bc - P["dA"]
        Y = (1 + sB) * Bc - P["dB"]
        if P.get("oA") or P.get("oB"):
            Z = P.get("oA", 0.0) * (1 + sA) * Ac + P.get("oB", 0.0) * (1 + sB) * Bc
            out = np.sqrt(X * X + Y * Y + Z * Z) - R + P.get("r0", 0.0)
        else:
            out = np.hypot(X, Y) - R + P.get("r0", 0.0)
        if "drift" in P:
            out = out + P["drift"] * self.t
        return out

    def step(self, name: str) -> float:
        if name in ("alpha", "ds", "sm", "dT"):
            return 1e-7
        if name in ("kA", "kB"):
            return 1e-9
        return 1e-6

    def jacobian(self, p: np.ndarray, mask) -> np.ndarray:
        cols = []
        for j in range(len(p)):
            h = self.step(self.names[j])
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


def fit_mask(runs: Sequence[Run], mask_deg: float) -> np.ndarray:
    """Samples the fit uses: the reversal mask, and ``mask_deg`` after the corner where an
    arc starts (the feed-in corner reverses an axis too) when the run reaches back there."""
    out = []
    for r in runs:
        keep = reversal_mask(r.theta, np.full(len(r.theta), r.w, dtype=float), mask_deg)
        if r.start_theta is not None:
            keep &= r.w * np.degrees(r.theta - r.start_theta) >= mask_deg
        out.append(keep)
    return np.concatenate(out) if out else np.zeros(0, dtype=bool)


@dataclass
class FitResult:
    values: Dict[str, float]
    rms_um: float
    samples: int
    masked: int
    condition: float
    iterations: int
    residuals: Dict[str, Tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    sigma: Dict[str, float] = field(default_factory=dict)  # 1-sigma, same units as values
    correlation_inflation: float = 1.0
    names: List[str] = field(default_factory=list)
    covariance: Optional[np.ndarray] = None  # of the values in ``names`` order
    t_ref: float = 0.0  # s, the time the drift term is counted from
    fixed: Dict[str, float] = field(default_factory=dict)


def correlation_inflation(res_by_run: Sequence[np.ndarray]) -> float:
    """``sqrt((1 + rho) / (1 - rho))`` for the lag-1 autocorrelation ``rho`` of the residuals
    (each run in time order), at least 1."""
    num = den = 0.0
    for r in res_by_run:
        if len(r) < 3:
            continue
        r = r - r.mean()
        num += float(np.dot(r[1:], r[:-1]))
        den += float(np.dot(r, r))
    if den <= 0:
        return 1.0
    rho = min(max(num / den, 0.0), 0.95)
    return math.sqrt((1 + rho) / (1 - rho))


def covariance(J: np.ndarray, rms: float, dof: int, inflation: float) -> np.ndarray:
    """Parameter covariance of a least-squares fit with Jacobian ``J`` (rows = kept samples)."""
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    inv = np.linalg.pinv(Js.T @ Js)
    s2 = (rms**2) * len(J) / max(1, dof)
    return inv / np.outer(scale, scale) * s2 * inflation**2


def fit(
    geom: Geometry,
    runs: Sequence[Run],
    mask_deg: float = DEFAULT_MASK_DEG,
    calibrated: bool = False,
    cyclic_pitch: Optional[float] = None,
    max_iter: int = 12,
    fit_drift: Optional[bool] = None,
    fixed: Optional[Dict[str, float]] = None,
) -> FitResult:
    both = {r.direction for r in runs} == {"cw", "ccw"}
    has_v = all(r.vA is not None for r in runs)
    fit_servo = both and (bool(geom.speed) or has_v)
    if fit_drift is None:
        fit_drift = all(r.t is not None for r in runs)
    model = Model(geom, runs, fit_servo, calibrated, cyclic_pitch, fit_drift, fixed)
    y = np.concatenate([r.fit_dev() for r in runs])
    keep = fit_mask(runs, mask_deg)
    if keep.sum() < len(model.names) * 5:
        raise TraceError(Msg("too few samples left after masking the reversal points"))
    p = np.zeros(len(model.names))
    it = 0
    for it in range(1, max_iter + 1):
        with np.errstate(all="ignore"):
            r = (y - model.predict(p))[keep]
        if not np.all(np.isfinite(r)):
            p = p * np.nan
            break
        if it <= 3:  # the model is mildly non-linear: later steps reuse the Jacobian
            J = model.jacobian(p, keep)
            # column scaling for a meaningful condition number and a stable solve
            scale = np.linalg.norm(J, axis=0)
            scale[scale == 0] = 1.0
            Js = J / scale
            N = Js.T @ Js
        step = np.linalg.lstsq(N, Js.T @ r, rcond=None)[0] / scale
        p = p + step
        if np.max(np.abs(step * scale)) < 1e-10:
            break
    if not np.all(np.isfinite(p)):
        raise TraceError(
            Msg(
                "the fit does not converge: the readings do not look like this "
                "test (check the metadata: plane, radius, feed, angles)"
            )
        )
    ev = np.linalg.eigvalsh(N)
    cond = float(math.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else None  # None: singular
    res = y - model.predict(p)
    rms = float(np.sqrt(np.mean(res[keep] ** 2)))
    values = dict(zip(model.names, p.tolist()))
    out = FitResult(values, rms * 1e3, int(keep.sum()), int((~keep).sum()), cond, it)
    i = 0
    kept_runs = []
    for run in runs:
        n = len(run.theta)
        out.residuals[run.direction] = (run.theta, res[i : i + n])
        kept_runs.append(_time_ordered(run, res[i : i + n], keep[i : i + n]))
        i += n
    out.correlation_inflation = correlation_inflation(kept_runs)
    cov = covariance(J, rms, int(keep.sum()) - len(p), out.correlation_inflation)
    out.sigma = {n: float(math.sqrt(max(cov[j, j], 0.0))) for j, n in enumerate(model.names)}
    out.covariance = cov
    out.names = list(model.names)
    out.t_ref = model.t_ref
    out.fixed = dict(model.fixed)
    return out


def _time_ordered(run: Run, res: np.ndarray, keep: np.ndarray) -> np.ndarray:
    order = np.argsort(run.t if run.t is not None else run.w * run.theta, kind="stable")
    return res[order][keep[order]]


def diagnostic_values(v: Dict[str, float], radius: float) -> Dict[str, object]:
    """Fitted values (model units) -> the diagnostic keys (report units)."""
    d: Dict[str, object] = {
        "squareness_um_per_m": v["alpha"] * 1e6,
        "scale_mismatch_ppm": v["ds"] * 1e6,
        "servo_mismatch_ms": v["dT"] * 1e3 if "dT" in v else None,
        "backlash_um": {
            "a_plus": v["bAp"] * 1e3,
            "a_minus": v["bAm"] * 1e3,
            "b_plus": v["bBp"] * 1e3,
            "b_minus": v["bBm"] * 1e3,
        },
        "centre_offset_um": {"a": v["dA"] * 1e3, "b": v["dB"] * 1e3},
        "radius_offset_um": v.get("r0", 0.0) * 1e3,
        "straightness_um": {"a": v["kA"] * radius**2 * 1e3, "b": v["kB"] * radius**2 * 1e3},
    }
    if "sm" in v:
        d["mean_scale_ppm"] = v["sm"] * 1e6
    if "drift" in v:
        d["bar_drift_um_per_min"] = v["drift"] * 1e3 * 60.0
    return d


def uncertainty_values(sigma: Dict[str, float], radius: float) -> Dict[str, object]:
    """1-sigma uncertainties in the units and key structure of the diagnostics."""
    d = diagnostic_values({k: sigma.get(k, 0.0) for k in set(BASE) | set(sigma)}, radius)
    if "dT" not in sigma:
        d["servo_mismatch_ms"] = None
    for k in ("mean_scale_ppm", "bar_drift_um_per_min"):
        if k in d:
            d[k] = abs(d[k])
    return d
