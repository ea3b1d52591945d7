"""Joint least-squares fit of all traces of a campaign: ONE parameter set for the whole volume.

Every trace keeps the exact model of :mod:`.model` (its samples, masks and weights), but the
model parameters of all traces are functions of one campaign vector ``g``:

* squareness ``xy, xz, yz`` (rad): each plane's ``alpha``; the squareness of the other planes
  also moves the third axis out of a vertical plane (YZ: ``X = xy Y + xz Z``; XZ:
  ``Y = yz Z``), which the joint model includes (a single-plane fit cannot);
* per-axis scale ``s_x, s_y, s_z``: each plane's mismatch is ``s_A - s_B``. A ballbar sees only
  differences, so the common part is fixed by a rule: the mean over the measured axes is
  left unchanged (the residual scales sum to zero); with a calibrated bar (known length) the
  mean radius of every trace measures ``(s_A + s_B)/2`` and all scales are absolute;
* servo lag ``T_x, T_y, T_z`` (s): each plane's mismatch is ``T_A - T_B``; only differences
  exist (a lag common to all axes delays the print and changes no path), reported with the
  smallest lag at 0;
* backlash per axis, linear along the axis between the lowest and the highest reversal point
  any trace reaches (constant when all reversals of that axis are at one position): each
  trace's per-side values are that line at its circle's ends;
* per trace: radius and centre offsets, straightness (bow) terms, bar drift: set-up and
  test-local terms.

The weighted least-squares problem (each trace weighted by its own residual noise, inflated for
correlated residuals) is solved by Gauss-Newton on the exact models; the covariance of ``g``
gives every jointly fitted value its 1-sigma uncertainty. Units in reports: um/m, ppm, ms, um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...core.messages import Msg
from ...core.params import AXES
from .formats import TraceError
from .model import (
    FitResult,
    Geometry,
    Model,
    Run,
    diagnostic_values,
    fit_mask,
    out_of_plane_terms,
    uncertainty_values,
)

PLANE_ORDER = ("XY", "XZ", "YZ")
REVERSAL_DEG = {"bAp": 0.0, "bAm": 180.0, "bBp": 90.0, "bBm": 270.0}


@dataclass
class TraceFit:
    """One trace of a campaign with its own (single-trace) fit."""

    name: str
    geom: Geometry
    runs: List[Run]
    fit: FitResult
    model: Optional[Model] = None
    keep: Optional[np.ndarray] = None
    y: Optional[np.ndarray] = None

    @property
    def weight(self) -> float:
        """1 / noise (1/mm) of this trace: its residual rms, inflated for correlation."""
        return 1.0 / max(self.fit.rms_um * 1e-3 * self.fit.correlation_inflation, 1e-6)


@dataclass
class JointResult:
    names: List[str]
    values: np.ndarray
    covariance: np.ndarray
    rms_um: Dict[str, float]
    samples: int
    condition: float
    iterations: int
    layout: Layout
    local: Dict[str, Dict[str, float]] = field(default_factory=dict)  # per trace, fitted
    local_names: List[List[str]] = field(default_factory=list)  # per trace, model names
    radii: List[float] = field(default_factory=list)

    def value(self, row: np.ndarray) -> float:
        return float(row @ self.values)

    def sigma(self, row: np.ndarray) -> float:
        return float(math.sqrt(max(row @ self.covariance @ row, 0.0)))


class Layout:
    """The campaign vector's names and the linear map to each trace's model parameters."""

    def __init__(self, traces: Sequence[TraceFit], calibrated: bool):
        self.calibrated = calibrated
        planes = {t.geom.plane for t in traces}
        self.planes = [p for p in PLANE_ORDER if p in planes]
        axes = set()
        for t in traces:
            axes.update(t.geom.letters)
        self.axes = [a for a in AXES if a in axes]
        self.servo = any("dT" in t.model.names for t in traces)
        names = [f"sq_{p.lower()}" for p in self.planes]
        free_scale = self.axes if calibrated else self.axes[:-1]
        names += [f"s_{a}" for a in free_scale]
        self.lag_axes = [
            a
            for a in self.axes
            if any(a in t.geom.letters and "dT" in t.model.names for t in traces)
        ]
        if self.servo:
            names += [f"T_{a}" for a in self.lag_axes[:-1]]
        self.backlash_span: Dict[str, Tuple[float, float]] = {}
        for a in self.axes:
            pos = _reversal_positions(traces, a)
            if not pos:
                continue
            lo, hi = min(pos), max(pos)
            self.backlash_span[a] = (lo, hi)
            names += [f"b_{a}_lo", f"b_{a}_hi"] if hi - lo >= 1.0 else [f"b_{a}"]
        self.global_names = list(names)
        for i, t in enumerate(traces):
            for n in t.model.names:
                if n in ("r0", "dA", "dB", "kA", "kB", "drift") or n.startswith("c"):
                    names.append(f"t{i}:{n}")
        self.names = names
        self.index = {n: j for j, n in enumerate(names)}
        self.maps = [self._map(i, t) for i, t in enumerate(traces)]

    def unit(self, name: str) -> np.ndarray:
        e = np.zeros(len(self.names))
        if name in self.index:
            e[self.index[name]] = 1.0
        return e

    def scale_row(self, axis: str) -> np.ndarray:
        if self.calibrated or axis != self.axes[-1]:
            return self.unit(f"s_{axis}")
        return -sum((self.unit(f"s_{a}") for a in self.axes[:-1]), np.zeros(len(self.names)))

    def lag_row(self, axis: str) -> np.ndarray:
        return self.unit(f"T_{axis}")  # the last lag axis is the reference (0)

    def backlash_row(self, axis: str, q: float) -> np.ndarray:
        if f"b_{axis}" in self.index:
            return self.unit(f"b_{axis}")
        if axis not in self.backlash_span:
            return np.zeros(len(self.names))
        lo, hi = self.backlash_span[axis]
        f = (q - lo) / (hi - lo)
        return (1 - f) * self.unit(f"b_{axis}_lo") + f * self.unit(f"b_{axis}_hi")

    def _map(self, i: int, t: TraceFit) -> np.ndarray:
        A, B = t.geom.letters
        a, b = t.geom.axes
        c, R = t.geom.centre or (0.0, 0.0, 0.0), t.geom.radius
        rows = []
        for n in t.model.names:
            if n == "ds":
                rows.append(self.scale_row(A) - self.scale_row(B))
            elif n == "sm":
                rows.append(0.5 * (self.scale_row(A) + self.scale_row(B)))
            elif n == "alpha":
                rows.append(self.unit(f"sq_{t.geom.plane.lower()}"))
            elif n == "dT":
                rows.append(self.lag_row(A) - self.lag_row(B))
            elif n in REVERSAL_DEG:
                ax, k = (A, a) if n[1] == "A" else (B, b)
                q = c[k] + R if n.endswith("p") else c[k] - R
                rows.append(self.backlash_row(ax, q))
            else:
                rows.append(self.unit(f"t{i}:{n}"))
        return np.array(rows)

    def out_of_plane(self, plane: str, g: np.ndarray) -> Dict[str, float]:
        """The fixed out-of-plane coupling of a trace in ``plane`` for campaign vector g."""
        sq = {
            p: float(g[self.index[f"sq_{p}"]]) if f"sq_{p}" in self.index else 0.0
            for p in ("xy", "xz", "yz")
        }
        return out_of_plane_terms(plane, sq)


def _reversal_positions(traces: Sequence[TraceFit], axis: str) -> List[float]:
    """Positions (mm) of ``axis`` where some trace's fitted arcs reverse it."""
    out = []
    for t in traces:
        letters = t.geom.letters
        if axis not in letters:
            continue
        k = t.geom.axes[letters.index(axis)]
        tag = "A" if letters.index(axis) == 0 else "B"
        c = (t.geom.centre or (0.0, 0.0, 0.0))[k]
        deg = np.concatenate([np.degrees(r.theta) for r in t.runs])
        lo, hi = deg.min(), deg.max()
        for side in ("p", "m"):
            rev = REVERSAL_DEG[f"b{tag}{side}"]
            if any(lo <= rev + 360.0 * m <= hi for m in (-1, 0, 1)):
                out.append(c + t.geom.radius if side == "p" else c - t.geom.radius)
    return out


def joint_fit(
    traces: Sequence[TraceFit],
    mask_deg: float,
    calibrated: bool,
    cyclic_pitch: Optional[float] = None,
    max_iter: int = 15,
) -> JointResult:
    for t in traces:
        both = {r.direction for r in t.runs} == {"cw", "ccw"}
        fit_servo = both and (bool(t.geom.speed) or all(r.vA is not None for r in t.runs))
        t.model = Model(
            t.geom,
            t.runs,
            fit_servo,
            calibrated,
            cyclic_pitch,
            "drift" in t.fit.values,
            None,
            t.fit.t_ref,
        )
        t.keep = fit_mask(t.runs, mask_deg)
        t.y = np.concatenate([r.fit_dev() for r in t.runs])
    lay = Layout(traces, calibrated)
    # start: the campaign vector that best reproduces the single-trace fits
    M = np.vstack(lay.maps)
    p0 = np.concatenate([[t.fit.values.get(n, 0.0) for n in t.model.names] for t in traces])
    g = np.linalg.lstsq(M, p0, rcond=None)[0]
    it = 0
    N = None
    for it in range(1, max_iter + 1):
        rebuild = it <= 3
        if rebuild:
            N = np.zeros((len(g), len(g)))
            JS = []
        rhs = np.zeros(len(g))
        for i, t in enumerate(traces):
            t.model.fixed = lay.out_of_plane(t.geom.plane, g)
            p = lay.maps[i] @ g
            r = (t.y - t.model.predict(p))[t.keep] * t.weight
            if rebuild:
                Jg = (t.model.jacobian(p, t.keep) @ lay.maps[i]) * t.weight
                JS.append(Jg)
                N += Jg.T @ Jg
            rhs += JS[i].T @ r
        scale = np.sqrt(np.diag(N))
        scale[scale == 0] = 1.0
        Ns = N / np.outer(scale, scale)
        step = np.linalg.lstsq(Ns, rhs / scale, rcond=None)[0] / scale
        g = g + step
        if np.max(np.abs(step * scale)) < 1e-7:
            break
    cov = np.linalg.pinv(Ns) / np.outer(scale, scale)
    ev = np.linalg.eigvalsh(Ns)
    cond = float(math.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else None  # None: singular
    rms = {}
    local = {}
    for i, t in enumerate(traces):
        t.model.fixed = lay.out_of_plane(t.geom.plane, g)
        p = lay.maps[i] @ g
        res = (t.y - t.model.predict(p))[t.keep]
        rms[t.name] = float(np.sqrt(np.mean(res**2))) * 1e3
        local[t.name] = dict(zip(t.model.names, p.tolist()))
    n = int(sum(t.keep.sum() for t in traces))
    return JointResult(
        lay.names,
        g,
        cov,
        rms,
        n,
        cond,
        it,
        lay,
        local,
        [list(t.model.names) for t in traces],
        [t.geom.radius for t in traces],
    )


def lag_values(res: JointResult) -> Tuple[Dict[str, float], Dict[str, float]]:
    """Per-axis lag (ms) with the smallest at 0, and the 1-sigma of each relative to it."""
    lay = res.layout
    rows = {a: lay.lag_row(a) for a in lay.lag_axes}
    vals = {a: res.value(r) for a, r in rows.items()}
    if not vals:
        return {}, {}
    ref = min(vals, key=vals.get)
    out = {a: (v - vals[ref]) * 1e3 for a, v in vals.items()}
    sig = {a: res.sigma(rows[a] - rows[ref]) * 1e3 for a in vals}
    return out, sig


def summary(res: JointResult) -> Dict[str, object]:
    """The jointly fitted values (report units) and their 1-sigma uncertainties."""
    lay = res.layout
    d: Dict[str, object] = {}
    u: Dict[str, object] = {}
    d["squareness_um_per_m"] = {
        p.lower(): res.value(lay.unit(f"sq_{p.lower()}")) * 1e6 for p in lay.planes
    }
    u["squareness_um_per_m"] = {
        p.lower(): res.sigma(lay.unit(f"sq_{p.lower()}")) * 1e6 for p in lay.planes
    }
    d["scale_ppm"] = {a: res.value(lay.scale_row(a)) * 1e6 for a in lay.axes}
    u["scale_ppm"] = {a: res.sigma(lay.scale_row(a)) * 1e6 for a in lay.axes}
    pairs = [(x, y) for i, x in enumerate(lay.axes) for y in lay.axes[i + 1 :]]
    d["scale_mismatch_ppm"] = {
        f"{x}-{y}": res.value(lay.scale_row(x) - lay.scale_row(y)) * 1e6 for x, y in pairs
    }
    u["scale_mismatch_ppm"] = {
        f"{x}-{y}": res.sigma(lay.scale_row(x) - lay.scale_row(y)) * 1e6 for x, y in pairs
    }
    if lay.servo:
        d["servo_lag_ms"], u["servo_lag_ms"] = lag_values(res)
        lp = [(x, y) for i, x in enumerate(lay.lag_axes) for y in lay.lag_axes[i + 1 :]]
        d["servo_mismatch_ms"] = {
            f"{x}-{y}": res.value(lay.lag_row(x) - lay.lag_row(y)) * 1e3 for x, y in lp
        }
        u["servo_mismatch_ms"] = {
            f"{x}-{y}": res.sigma(lay.lag_row(x) - lay.lag_row(y)) * 1e3 for x, y in lp
        }
    d["backlash_um"], u["backlash_um"] = {}, {}
    for a, (lo, hi) in lay.backlash_span.items():
        if f"b_{a}" in lay.index:
            d["backlash_um"][a] = res.value(lay.unit(f"b_{a}")) * 1e3
            u["backlash_um"][a] = res.sigma(lay.unit(f"b_{a}")) * 1e3
        else:
            d["backlash_um"][a] = [
                {"at_mm": q, "um": res.value(lay.backlash_row(a, q)) * 1e3} for q in (lo, hi)
            ]
            u["backlash_um"][a] = [
                {"at_mm": q, "um": res.sigma(lay.backlash_row(a, q)) * 1e3} for q in (lo, hi)
            ]
    d["uncertainty"] = u
    return d


def joint_values(res: JointResult, i: int) -> Dict[str, object]:
    """Trace ``i``'s own diagnostic values as the joint fit has them (one consistent set for
    all planes), with their 1-sigma uncertainties."""
    lay = res.layout
    rows = dict(zip(res.local_names[i], lay.maps[i]))
    vals = {n: res.value(r) for n, r in rows.items()}
    sig = {n: res.sigma(r) for n, r in rows.items()}
    radius = res.radii[i]
    keys = (
        "squareness_um_per_m",
        "scale_mismatch_ppm",
        "servo_mismatch_ms",
        "backlash_um",
        "mean_scale_ppm",
    )
    d = {k: v for k, v in diagnostic_values(vals, radius).items() if k in keys}
    d["uncertainty"] = {k: v for k, v in uncertainty_values(sig, radius).items() if k in keys}
    return d


def check_coverage(name: str, geom: Geometry, runs: Sequence[Run]) -> None:
    """A test that did not complete: a direction missing or the capture arc not covered."""
    directions = {r.direction for r in runs}
    for d in ("ccw", "cw"):
        if d not in directions:
            raise TraceError(
                Msg(
                    "%(file)s: the %(direction)s run is missing (the test did not complete)",
                    file=name,
                    direction=d,
                )
            )
    for r in runs:
        cap = r.captured()
        if len(cap.theta) < 10:
            raise TraceError(
                Msg(
                    "%(file)s: the %(direction)s run has no samples on the capture arc",
                    file=name,
                    direction=r.direction,
                )
            )
        deg = np.sort(np.degrees(cap.theta))
        span = float(deg[-1] - deg[0])
        gap = float(np.max(np.diff(deg))) if len(deg) > 1 else 360.0
        if span < 0.95 * (geom.capture_deg or 360.0) or gap > 5.0:
            raise TraceError(
                Msg(
                    "%(file)s: the %(direction)s run covers %(span)s of the %(capture)s° "
                    "capture arc (largest gap %(gap)s°): the test did not complete",
                    file=name,
                    direction=r.direction,
                    span=f"{span:.0f}",
                    capture=f"{geom.capture_deg:g}",
                    gap=f"{gap:.1f}",
                )
            )
