"""ISO 230-4 metrics of ballbar runs and the data of the ballbar plot.

Circular deviation G per direction and bidirectional G(b) with least-squares centres (LSC),
minimum-zone values (MZC, by an L-infinity fit), hysteresis H (CW vs CCW at the same angle,
common centre removed), radial deviation F only for a calibrated bar. G and G(b) are ranges
(max - min) of the raw samples, so the sensor's noise adds to them (about 8 sigma for 36,000
samples); ``circularity_filtered_um`` is the same after a moving average over
:data:`FILTER_DEG` of arc (a step such as backlash keeps its height, white noise shrinks by
the square root of the samples averaged), for before/after comparisons near the noise.
The values describe the path about its own centre: the pivot's offset from that centre
(set-up) is removed exactly, not only to first order (:func:`about_path_centre`; a linear
centre removal leaves ``e^2 / 2R`` of an offset ``e``: 0.8 um for 0.4 mm at R100).
Units: um in the output, mm inside; angles in radians inside, degrees in the plot.
"""

from __future__ import annotations

import dataclasses
from typing import Dict, List, Sequence

import numpy as np

from .model import FitResult, Geometry, Model, Run

FILTER_DEG = 1.0  # deg of arc averaged for circularity_filtered_um


def _smoothed(run: Run, width_deg: float = FILTER_DEG) -> Run:
    """The run with its deviations averaged over about ``width_deg`` of arc: a centred
    window, in angle order, of as many samples as ``width_deg`` takes at the median sample
    spacing (shorter at the ends; it does not stop at a gap in the trace)."""
    n = len(run.theta)
    if n < 3:
        return run
    order = np.argsort(run.w * run.theta, kind="stable")
    th, dv = run.theta[order], run.dev[order]
    step = float(np.median(np.abs(np.diff(th))))
    k = int(round(np.radians(width_deg) / step)) if step > 0 else 1
    if k < 2:
        return run
    half = k // 2
    c = np.concatenate([[0.0], np.cumsum(dv)])
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) + half + 1, 0, n)
    avg = (c[hi] - c[lo]) / (hi - lo)
    return Run(run.direction, th, avg)


def _lsc(theta, dev, fit_radius=True):
    cols = [np.cos(theta), np.sin(theta)]
    if fit_radius:
        cols.insert(0, np.ones_like(theta))
    M = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(M, dev, rcond=None)
    return dev - M @ coef, coef


def about_path_centre(runs: Sequence[Run], radius: float) -> List[Run]:
    """The runs with ``dev`` (mm) the path's radial deviation about its own centre instead of
    the bar's length change about the pivot.

    The bar reads ``d = R + dev = |N - P|`` for the nozzle ``N = C + rho u(t)`` (``u`` the
    unit vector at the nominal angle) and the pivot ``P = C + e``; hence
    ``rho = e.u + sqrt(d^2 - |e|^2 + (e.u)^2)``. ``e`` comes from the linear least-squares
    centre of ``dev`` (``dev ~ r0 - e.u``; the second-order term ``(e x u)^2 / 2R`` is
    orthogonal to ``cos t``, ``sin t`` and does not bias it). ``radius`` (mm) is the
    nominal radius; without one (0) the runs come back unchanged."""
    runs = list(runs)
    if radius <= 0 or not runs:
        return runs
    theta = np.concatenate([r.theta for r in runs])
    if len(theta) < 3:
        return runs
    _, coef = _lsc(theta, np.concatenate([r.dev for r in runs]))
    ea, eb = -float(coef[1]), -float(coef[2])
    out = []
    for r in runs:
        eu = ea * np.cos(r.theta) + eb * np.sin(r.theta)
        d = radius + r.dev
        rho = eu + np.sqrt(np.maximum(d * d - (ea * ea + eb * eb) + eu * eu, 0.0))
        out.append(dataclasses.replace(r, dev=rho - radius))
    return out


def _mzc_range(theta, dev, iters: int = 300) -> float:
    """Minimum-zone circularity (max - min after the best centre) by Lawson's L-infinity IRLS
    (each step a weighted least-squares fit of radius and centre, by its 3x3 normal
    equations)."""
    M = np.stack([np.ones_like(theta), np.cos(theta), np.sin(theta)], axis=1)
    wts = np.full(len(dev), 1.0 / len(dev))
    best = float("inf")
    for _ in range(iters):
        Mw = M * wts[:, None]
        try:
            coef = np.linalg.solve(Mw.T @ M, Mw.T @ dev)
        except np.linalg.LinAlgError:
            break
        e = dev - M @ coef
        best = min(best, float(e.max() - e.min()))
        a = np.abs(e)
        wts = wts * a
        tot = wts.sum()
        if tot <= 0:
            break
        wts /= tot
    return best


def circularity(runs: Sequence[Run], radius: float = 0.0) -> Dict[str, float]:
    """G per direction and G(b) (um, LSC) of the samples given (captured ones: see
    :meth:`.Run.captured`); with the nominal ``radius`` (mm) about the path's own centre
    (:func:`about_path_centre`)."""
    runs = about_path_centre(runs, radius)
    out = {}
    for r in runs:
        e, _ = _lsc(r.theta, r.dev)
        out[r.direction] = float(e.max() - e.min()) * 1e3
    e, _ = _lsc(np.concatenate([r.theta for r in runs]), np.concatenate([r.dev for r in runs]))
    out["bidirectional"] = float(e.max() - e.min()) * 1e3
    return out


def iso_metrics(geom: Geometry, runs: Sequence[Run], calibrated: bool) -> Dict[str, object]:
    runs = about_path_centre([r.captured() for r in runs], geom.radius)
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
    out: Dict[str, object] = {
        "circularity_um": circ,
        "circularity_mzc_um": mzc,
        "circularity_filtered_um": circularity([_smoothed(r) for r in runs]),
        "filter_deg": FILTER_DEG,
    }
    if len(by) == 2:
        # hysteresis: CW vs CCW at the same angle, common centre removed
        centred = {
            d: r.dev - coef[1] * np.cos(r.theta) - coef[2] * np.sin(r.theta) for d, r in by.items()
        }
        a = by["ccw"]
        b = by["cw"]
        order = np.argsort(b.theta)
        lo, hi = b.theta[order][0], b.theta[order][-1]
        inside = (a.theta >= lo) & (a.theta <= hi)
        interp = np.interp(a.theta[inside], b.theta[order], centred["cw"][order])
        out["hysteresis_um"] = float(np.max(np.abs(centred["ccw"][inside] - interp))) * 1e3
    if calibrated:
        radial = dev - coef[1] * np.cos(theta) - coef[2] * np.sin(theta)
        out["radial_deviation_um"] = {
            "max": float(radial.max()) * 1e3,
            "min": float(radial.min()) * 1e3,
        }
    else:
        out["radial_deviation_um"] = None
    out["iso_centre"] = (
        "least-squares centre (LSC) per direction; common LSC centre for the "
        "bidirectional value and hysteresis; circularity_mzc_um uses the "
        "minimum-zone centre"
    )
    return out


def plot_data(
    geom: Geometry, runs: Sequence[Run], f: FitResult, diag: Dict[str, object], bins: int = 720
) -> Dict[str, object]:
    """What a ballbar plot shows: per direction the deviation (um) against the angle (deg)
    with the common least-squares centre and the mean radius removed, and the fitted model
    on the same footing (the fitted ellipse), averaged into ``bins`` angle bins."""
    runs = [r.captured() for r in runs]
    theta = np.concatenate([r.theta for r in runs])
    dev = np.concatenate([r.dev for r in runs])
    _, coef = _lsc(theta, dev)
    model = Model(
        geom, runs, "dT" in f.values, "sm" in f.values, None, "drift" in f.values, f.fixed, f.t_ref
    )
    names = [n for n in model.names if n in f.values]
    model.names = names
    pred = model.predict(np.array([f.values[n] for n in names]))
    out: Dict[str, object] = {
        "plane": geom.plane,
        "axes": diag.get("axes"),
        "radius_mm": geom.radius,
        "simulated": bool(diag.get("simulated")),
        "directions": {},
        "centre_removed_um": {"a": float(coef[1]) * 1e3, "b": float(coef[2]) * 1e3},
    }
    i = 0
    for run in runs:
        n = len(run.theta)
        th = run.theta
        base = coef[0] + coef[1] * np.cos(th) + coef[2] * np.sin(th)
        d = (run.dev - base) * 1e3
        m = (pred[i : i + n] - base) * 1e3
        i += n
        deg = np.degrees(th)
        lo, hi = float(deg.min()), float(deg.max())
        edges = np.linspace(lo, hi, min(bins, max(2, n)) + 1)
        which = np.clip(np.searchsorted(edges, deg, side="right") - 1, 0, len(edges) - 2)
        cnt = np.bincount(which, minlength=len(edges) - 1)
        ok = cnt > 0
        nbins = len(edges) - 1

        def mean(v, which=which, ok=ok, cnt=cnt, nbins=nbins):
            return np.bincount(which, weights=v, minlength=nbins)[ok] / cnt[ok]

        out["directions"][run.direction] = {
            "angle_deg": np.round(mean(deg), 3).tolist(),
            "dev_um": np.round(mean(d), 3).tolist(),
            "fit_um": np.round(mean(m), 3).tolist(),
        }
    return out
