"""Caliper readings of the printed artifact -> squareness and scale mismatch, with uncertainties.

The model of one reading (mm) of a measurement from ``P`` to ``Q`` (:mod:`.program`)::

    reading = | S @ diag(1 + u) @ (Q - P) |  +  k * w_f * |n_h|

* ``S`` is KinComp's alignment (``core/params.py``): ``S[0,1] = xy``, ``S[0,2] = xz``,
  ``S[1,2] = yz`` (um/m: ``actual_x = x + xy*1e-6*y``; positive ``xy`` makes the +X+Y diagonal
  long, the same sign as the ballbar route, Marlin ``M852`` and Klipper's skew factor).
* ``u = (u_x, u_y, u_z)`` (ppm): each axis' scale error *plus* the plastic's isotropic
  shrinkage, which cannot be told apart from a common scale error. Only the differences
  ``u_x - u_y`` (``"x-y"``), ``u_x - u_z``, ``u_y - u_z`` are claimed (positive ``"x-y"``: X
  travels further than Y); the absolute scale is not.
* ``k`` is +1 for an outside reading (the jaws on the walls' outer faces: one wall thickness
  added), -1 inside; ``w_f`` is the printed line width (mm) of the wall family (``vertical``
  walls of the XY part, ``slanted`` 45 deg walls of the towers; separate unknowns), ``|n_h|``
  the horizontal part of the measuring direction (a 45 deg wall is ``w/sqrt 2`` thick along it).

The fit is a Gauss-Newton least squares over the mean of each measurement's repeats (weighted
by their number). The 1-sigma uncertainty of each value is ``sigma * sqrt(g' (J'WJ)^+ g)`` with
``sigma`` per reading the largest of the fit's residual scatter, the repeats' own scatter and
the caliper's resolution / sqrt(12); a scatter estimated from few degrees of freedom ``nu`` is
widened by Student's ``t(0.975, nu) / 1.96`` (:func:`coverage_factor`), so that the value
lies within its 2 sigma about 95 % of the time however few readings there are. Readings that
disagree with their repeats, and measurements that disagree with all the others (externally
studentized residual), are named by their id and left out. A value the measurements cannot
separate (no or dependent readings) is ``None`` with a finding saying so; the rank is decided
on the column-scaled design matrix.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...core.kinematics import changes_nothing
from ...core.messages import Msg
from ...core.params import Params
from .. import findings as fnd
from ..proposal import alignment_matrix, checked_params, proposal_meta, split_alignment
from ..result import result_document
from .program import Measurement

NAMES = ("u_x", "u_y", "u_z", "xy", "xz", "yz", "w_vertical", "w_slanted")
PAIRS = ("x-y", "x-z", "y-z")
RESOLUTION_MM = 0.01
GROSS_MM = 3.0  # a reading this far (or 3 % of the span) from nominal is a typo
GROSS_FRACTION = 0.03  # (ABS shrinks up to ~1.6 %: that must pass)
REPEAT_SIGMAS = 8.0  # a repeat further than this many repeat-sigmas from its median is out
REPEAT_FLOOR_MM = 0.1
OUTLIER_T = 6.0  # externally studentized residual beyond which a measurement is out
# a reading's scatter is taken as at least one caliper digit when a measurement is judged
# against the others (with few readings their own scatter is a poor estimate: a quick
# artifact's 12 readings leave 3 degrees of freedom to judge one by)
OUTLIER_SPREAD_MM = 0.01
MAX_LEVERAGE = 0.95  # above this a measurement has no redundancy: it cannot be checked
# (squareness um/m, mismatch ppm) 1-sigma beyond which a value is poorly determined, per
# mode of the artifact: the quick one's 12 readings give 2 to 7 times the full one's sigma
# (docs/artifact.md), so there only a sigma well beyond that is said to be poorly determined
POOR = {"full": (100.0, 300.0), "quick": (350.0, 500.0)}
Z_975 = 1.959964  # the standard normal's 97.5 % point
ILL_CONDITIONED = 100.0  # condition number of the column-scaled design matrix


class ArtifactFitError(ValueError):
    """The readings cannot be used (malformed, unknown ids, nothing to fit)."""


@dataclass
class _Obs:
    meas: Measurement
    values: List[float]  # kept readings, mm
    excluded: List[Tuple[int, float]] = field(default_factory=list)  # (index, value)

    @property
    def mean(self) -> float:
        return sum(self.values) / len(self.values)


# ---------------------------------------------------------------------------------------
# input


def parse_readings(data) -> Dict[str, List[float]]:
    """``{"<id>": [mm, ...]}`` (or one number per id) -> lists of floats; raises a clear
    :class:`ArtifactFitError` for anything else."""
    if isinstance(data, (str, bytes)):
        try:
            data = json.loads(data)
        except ValueError as exc:
            raise ArtifactFitError(
                Msg("the readings are not valid JSON (%(error)s)", error=str(exc))
            ) from None
    if not isinstance(data, dict):
        raise ArtifactFitError(Msg('the readings must be a JSON object {"<id>": [mm, ...]}'))
    out = {}
    for key, vals in data.items():
        if not isinstance(vals, list):
            vals = [vals]
        clean = []
        for v in vals:
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v <= 0
            ):
                raise ArtifactFitError(
                    Msg(
                        "reading %(value)s of %(id)s is not a positive length in mm",
                        value=json.dumps(v)[:20],
                        id=str(key),
                    )
                )
            clean.append(float(v))
        out[str(key)] = clean
    return out


# ---------------------------------------------------------------------------------------
# the model


def _unit(n: int, i: int) -> np.ndarray:
    g = np.zeros(n)
    g[i] = 1.0
    return g


def _predict(meas: Sequence[Measurement], p: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Readings (mm) and the Jacobian d reading / d p (p: u and squareness as plain
    fractions, line widths in mm)."""
    ux, uy, uz, sxy, sxz, syz, wv, ws = p
    S = np.array([[1.0, sxy, sxz], [0.0, 1.0, syz], [0.0, 0.0, 1.0]])
    D = np.array([1.0 + ux, 1.0 + uy, 1.0 + uz])
    y = np.empty(len(meas))
    J = np.zeros((len(meas), len(NAMES)))
    for i, m in enumerate(meas):
        d = np.subtract(m.end, m.start)
        v = S @ (D * d)
        L = float(np.linalg.norm(v))
        e = v / L
        for k in range(3):
            J[i, k] = float(e @ (S[:, k] * d[k]))
        J[i, 3] = e[0] * D[1] * d[1]
        J[i, 4] = e[0] * D[2] * d[2]
        J[i, 5] = e[1] * D[2] * d[2]
        nh = math.hypot(*m.direction[:2])
        col = 6 if m.family == "vertical" else 7
        J[i, col] = m.sign * nh
        y[i] = L + m.sign * nh * (wv if col == 6 else ws)
    return y, J


@dataclass
class _Fit:
    p: np.ndarray
    resid: np.ndarray  # mm, mean reading - model, per observation
    weights: np.ndarray  # readings per observation
    Js: np.ndarray  # weighted, column-scaled Jacobian at the solution
    scale: np.ndarray  # column scales
    null: np.ndarray  # null-space basis of the design (columns), Js's scaled coordinates
    cov_s: np.ndarray  # pinv(Js'Js) (scaled coordinates, per unit sigma)
    rank: int
    condition: Optional[float]
    leverage: np.ndarray


def _solve(obs: Sequence[_Obs], w0: float) -> _Fit:
    meas = [o.meas for o in obs]
    y = np.array([o.mean for o in obs])
    wts = np.array([float(len(o.values)) for o in obs])
    sq = np.sqrt(wts)
    p = np.zeros(len(NAMES))
    p[6] = p[7] = w0
    # an unknown the measurements see only through the other errors (at second order: the
    # XY squareness through the towers when no diagonal was measured) counts as not seen
    J0 = _predict(meas, p)[1] * sq[:, None]
    nominal = np.linalg.norm(J0, axis=0)
    unseen = nominal <= 1e-9 * float(np.max(nominal))
    for _ in range(8):
        pred, J = _predict(meas, p)
        J[:, unseen] = 0.0
        Jw = J * sq[:, None]
        scale = np.linalg.norm(Jw, axis=0)
        scale[scale == 0] = 1.0
        Js = Jw / scale
        step = np.linalg.lstsq(Js, (y - pred) * sq, rcond=1e-10)[0] / scale
        p = p + step
        if np.max(np.abs(step * scale)) < 1e-12:
            break
    pred, J = _predict(meas, p)
    J[:, unseen] = 0.0
    Jw = J * sq[:, None]
    scale = np.linalg.norm(Jw, axis=0)
    scale[scale == 0] = 1.0
    Js = Jw / scale
    # what the measurements separate is a question of their design: decided on the
    # Jacobian of the error-free artifact (at the solution, the errors themselves couple the
    # unknowns at second order, and a combination nothing measures would look measured)
    rank, null = _design_null(J0, unseen, scale)
    U, s, Vt = np.linalg.svd(Js, full_matrices=True)
    cov_s = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
    Ur = U[:, :rank]
    lev = np.sum(Ur**2, axis=1)
    cond = float(s[0] / s[rank - 1]) if rank else None
    return _Fit(p, y - pred, wts, Js, scale, null, cov_s, rank, cond, lev)


def _design_null(J0: np.ndarray, unseen: np.ndarray, scale: np.ndarray) -> Tuple[int, np.ndarray]:
    """(rank, null-space basis) of the weighted Jacobian ``J0`` of the error-free artifact,
    the unknowns ``unseen`` left out; the basis orthonormal in the coordinates scaled by
    ``scale`` (the solution's column scales)."""
    J0 = J0.copy()
    J0[:, unseen] = 0.0
    s0 = np.linalg.norm(J0, axis=0)
    s0[s0 == 0] = 1.0
    _, s, Vt = np.linalg.svd(J0 / s0, full_matrices=True)
    top = s[0] if len(s) else 0.0
    tol = max(J0.shape) * np.finfo(float).eps * 1e3 * top
    rank = int(np.sum(s > max(tol, 1e-9 * top)))
    null = (Vt[rank:] / s0 * scale).T  # to the solution's scaled coordinates
    if null.shape[1]:
        null = np.linalg.qr(null)[0]
    return rank, null


def _estimable(fit: _Fit, g: np.ndarray) -> bool:
    gs = g / fit.scale
    norm = float(np.linalg.norm(gs))
    if norm == 0:
        return False
    return float(np.linalg.norm(fit.null.T @ gs)) <= 1e-6 * norm


def _sigma_of(fit: _Fit, g: np.ndarray, sigma: float) -> float:
    gs = g / fit.scale
    return float(sigma * math.sqrt(max(gs @ fit.cov_s @ gs, 0.0)))


def coverage_factor(nu: int) -> float:
    """Student's ``t(0.975, nu) / 1.96`` (>= 1): how much wider a 1 sigma estimated from a
    scatter with ``nu`` degrees of freedom is made, so that +-2 sigma keeps about 95 %
    coverage (1.42 at nu = 4, 1.02 at nu = 72; 1 without an estimate, ``nu <= 0``). Exact
    for nu = 1, 2; the Cornish-Fisher series beyond (within 0.3 % at nu = 3)."""
    if nu <= 0:
        return 1.0
    if nu == 1:
        return math.tan(math.pi * 0.475) / Z_975
    if nu == 2:
        return 0.95 / math.sqrt(2 * 0.975 * 0.025) / Z_975
    z = Z_975
    t = (
        z
        + (z**3 + z) / (4 * nu)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * nu**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * nu**3)
        + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * nu**4)
    )
    return t / z


# ---------------------------------------------------------------------------------------
# screening


def _left_out(o: _Obs, off) -> List[Tuple[int, float]]:
    """Leaves the readings ``v`` of ``o`` for which ``off(v)`` out (kept in ``o.excluded``);
    returns them as (index among the readings it had, value)."""
    out = [(i, v) for i, v in enumerate(o.values) if off(v)]
    o.excluded.extend(out)
    o.values = [v for v in o.values if not off(v)]
    return out


def _screen_repeats(obs: List[_Obs], found: List[fnd.Finding]) -> Tuple[float, int]:
    """Leave out readings far from nominal or from their repeats' median; returns the pooled
    repeat standard deviation (mm; 0 without repeats) and its degrees of freedom."""
    for o in obs:
        L = o.meas.length
        limit = max(GROSS_MM, GROSS_FRACTION * L)
        for i, v in _left_out(o, lambda v, L=L, limit=limit: abs(v - L) > limit):
            found.append(
                fnd.warning(
                    "artifact.reading_far_from_nominal",
                    Msg(
                        "Reading %(n)s of %(id)s (%(value)s mm) is %(off)s mm from the nominal "
                        "%(nominal)s mm: a typo? It was left out.",
                        n=i + 1,
                        id=o.meas.id,
                        value=f"{v:.2f}",
                        off=f"{v - L:+.2f}",
                        nominal=f"{L:.2f}",
                    ),
                    Msg("Check the reading and measure %(id)s again.", id=o.meas.id),
                    id=o.meas.id,
                    reading=i + 1,
                    value_mm=v,
                    nominal_mm=round(L, 4),
                )
            )
    sds = [float(np.std(o.values, ddof=1)) for o in obs if len(o.values) >= 2]
    typical = float(np.median(sds)) if sds else 0.0
    limit = max(REPEAT_FLOOR_MM, REPEAT_SIGMAS * typical)
    for o in obs:
        if len(o.values) >= 3:
            med = float(np.median(o.values))
            for i, v in _left_out(o, lambda v, med=med: abs(v - med) > limit):
                found.append(
                    fnd.warning(
                        "artifact.reading_disagrees",
                        Msg(
                            "Reading %(n)s of %(id)s (%(value)s mm) is %(off)s mm from its "
                            "repeats (median %(median)s mm): a typo, or the jaws on a seam? It "
                            "was left out.",
                            n=i + 1,
                            id=o.meas.id,
                            value=f"{v:.2f}",
                            off=f"{v - med:+.3f}",
                            median=f"{med:.3f}",
                        ),
                        Msg("Measure %(id)s again.", id=o.meas.id),
                        id=o.meas.id,
                        reading=i + 1,
                        value_mm=v,
                        median_mm=med,
                        limit_mm=round(limit, 4),
                    )
                )
        elif len(o.values) == 2 and abs(o.values[0] - o.values[1]) > limit:
            found.append(
                fnd.warning(
                    "artifact.repeats_disagree",
                    Msg(
                        "The two readings of %(id)s differ by %(diff)s mm; with two it cannot be "
                        "told which is wrong.",
                        id=o.meas.id,
                        diff=f"{abs(o.values[0] - o.values[1]):.3f}",
                    ),
                    Msg("Measure %(id)s a third time.", id=o.meas.id),
                    id=o.meas.id,
                    values_mm=list(o.values),
                )
            )
    resid = [v - o.mean for o in obs if len(o.values) >= 2 for v in o.values]
    dof = sum(len(o.values) - 1 for o in obs if len(o.values) >= 2)
    return (math.sqrt(sum(r * r for r in resid) / dof) if dof else 0.0), dof


# ---------------------------------------------------------------------------------------
# the analysis


def analyse_artifact(
    measurements: Sequence[Measurement],
    readings: Dict[str, List[float]],
    current: Optional[Params] = None,
    info: Optional[Dict[str, str]] = None,
    resolution_mm: float = RESOLUTION_MM,
    simulated: bool = False,
) -> Dict[str, object]:
    """Fit the readings of an artifact program's measurements; returns the result document
    (``calibration/result.py``).
    ``current``: the parameters active while the artifact was printed (the fit is then a
    residual, and the proposal is current + residual)."""
    current = current or Params()
    info = info or {}
    found: List[fnd.Finding] = []
    obs, n_readings = _observations(measurements, readings, found)
    repeat_sd, repeat_dof = _screen_repeats(obs, found)
    obs = [o for o in obs if o.values]
    if len(obs) < 2:
        raise ArtifactFitError(
            Msg("too few readings: at least an outside and an inside measurement are needed")
        )
    try:
        w0 = float(info.get("line_width_mm", "0.45"))
    except ValueError:
        w0 = 0.45
    floor = resolution_mm / math.sqrt(12.0)
    rf = _robust_fit(obs, w0, (repeat_sd, repeat_dof), floor, found)
    planes_made = [p for p in info.get("planes", "XY,XZ,YZ").split(",") if p]
    mode = info.get("mode") if info.get("mode") in POOR else "full"
    values, sigmas = _quantities(rf, planes_made, found, mode)
    est_axes = [k for k in range(3) if _estimable(rf.fit, _unit(len(NAMES), k))]
    mean_u = _mean_scale(rf, est_axes)
    _line_width_check(values, info, found)
    _quality_findings(rf, repeat_sd, floor, found)
    _model_findings(current, found)
    diag: Dict[str, object] = {
        "source": "printed artifact",
        "simulated": simulated,
        "mode": mode,
        "planes": planes_made,
        "squareness_um_per_m": values["squareness_um_per_m"],
        "scale_mismatch_ppm": values["scale_mismatch_ppm"],
        "line_width_mm": values["line_width_mm"],
        "mean_scale_with_shrinkage_ppm": mean_u[0] if mean_u else None,
        "uncertainty": {**sigmas, "mean_scale_with_shrinkage_ppm": mean_u[1] if mean_u else None},
        "fit": _fit_summary(rf, obs, n_readings, repeat_sd),
        "measurements": _per_measurement(obs, rf.fit, rf.dropped, measurements, readings),
    }
    params = _propose(values, rf.fit, est_axes, current, simulated)
    notes = [f.message for f in fnd.worst_first(found) if f.severity != "info"]
    return result_document(diag, params, found, notes)


def _observations(
    measurements: Sequence[Measurement], readings: Dict[str, List[float]], found: List
) -> Tuple[List[_Obs], int]:
    """(the measured measurements with their readings, the number of readings); readings
    for an id the program does not have are an :class:`ArtifactFitError`, measurements
    without readings an info finding."""
    by_id = {m.id: m for m in measurements}
    unknown = sorted(set(readings) - set(by_id))
    if unknown:
        raise ArtifactFitError(
            Msg(
                "readings for ids the program does not have: %(ids)s "
                "(check the program given with the readings)",
                ids=", ".join(unknown[:8]),
            )
        )
    obs = [_Obs(m, list(readings[m.id])) for m in measurements if readings.get(m.id)]
    missing = [m.id for m in measurements if not readings.get(m.id)]
    if missing:
        found.append(
            fnd.info(
                "artifact.not_measured",
                Msg("Not measured: %(ids)s.", ids=", ".join(missing)),
                ids=missing,
            )
        )
    return obs, sum(len(o.values) for o in obs)


@dataclass
class _RobustFit:
    """The fit left when the measurements that disagree were left out: ``fit`` of the
    measurements kept (``obs``, changed in place), ``dof`` its redundancy, ``s_res`` the
    residual scatter (mm), ``sigma`` the reading's standard deviation used (mm, widened by
    :func:`coverage_factor`), ``dropped`` the measurements left out, ``repeat_dof`` the
    repeats' degrees of freedom."""

    fit: _Fit
    dof: int
    s_res: float
    sigma: float
    dropped: List[_Obs]
    repeat_dof: int = 0


def _worst_measurement(
    fit: _Fit, dof: int, rss: float, spread: float
) -> Tuple[Optional[int], float]:
    """(index, studentised residual) of the measurement that disagrees most with the others
    (leave-one-out; measurements nothing else checks are not judged); (None, 0) without
    redundancy. ``spread``: the least scatter a reading has (mm)."""
    worst, worst_t = None, 0.0
    if dof < 2:
        return worst, worst_t
    for i in range(len(fit.resid)):
        h = fit.leverage[i]
        if h > MAX_LEVERAGE:
            continue
        e2 = fit.weights[i] * fit.resid[i] ** 2
        s_i = math.sqrt(max(rss - e2 / (1 - h), 0.0) / (dof - 1))
        t = math.sqrt(e2) / (max(s_i, spread) * math.sqrt(1 - h))
        if t > worst_t:
            worst, worst_t = i, t
    return worst, worst_t


def _robust_fit(
    obs: List[_Obs], w0: float, repeat: Tuple[float, int], floor: float, found
) -> _RobustFit:
    """Fit, then leave out the worst measurement while one disagrees with the others (at
    most a fifth of them; a warning each), an error when one still does. ``repeat``: the
    repeats' pooled standard deviation (mm) and its degrees of freedom; ``floor``: the least
    standard deviation of a reading (mm)."""
    repeat_sd, repeat_dof = repeat
    spread = max(repeat_sd, floor, OUTLIER_SPREAD_MM)
    dropped: List[_Obs] = []
    while True:
        fit = _solve(obs, w0)
        dof = len(obs) - fit.rank
        rss = float(np.sum(fit.weights * fit.resid**2))
        s_res = math.sqrt(rss / dof) if dof > 0 else 0.0
        # (each scatter widened for the few degrees of freedom it was estimated from)
        sigma = max(s_res * coverage_factor(dof), repeat_sd * coverage_factor(repeat_dof), floor)
        worst, worst_t = _worst_measurement(fit, dof, rss, spread)
        if worst is None or worst_t <= OUTLIER_T or len(dropped) >= max(1, len(obs) // 5):
            break
        suspects = _consistent_drops(fit, dof, rss, spread)
        if len(suspects) > max(2, len(obs) // 3):  # (too many to leave out: an error below)
            break
        if len(suspects) > 1:  # leaving out any of them would do: which is wrong is unknown
            found.append(_ambiguous_finding([obs[i] for i in suspects]))
            dropped += [obs[i] for i in suspects]
            obs[:] = [o for i, o in enumerate(obs) if i not in suspects]
            continue
        o = obs.pop(worst)
        dropped.append(o)
        found.append(_outlier_finding(o, float(fit.resid[worst]), worst_t))
    if worst is not None and worst_t > OUTLIER_T:
        found.append(_too_many_finding(obs[worst], worst_t, len(dropped)))
    unchecked = [o.meas.id for o, h in zip(obs, fit.leverage) if h > MAX_LEVERAGE]
    if unchecked:
        found.append(
            fnd.info(
                "artifact.unchecked",
                Msg(
                    "No other measurement checks %(ids)s: a typo there would go unnoticed.",
                    ids=", ".join(unchecked),
                ),
                ids=unchecked,
            )
        )
    return _RobustFit(fit, dof, s_res, sigma, dropped, repeat_dof)


def _consistent_drops(fit: _Fit, dof: int, rss: float, spread: float) -> List[int]:
    """The measurements whose leaving out alone would leave the others consistent (their
    residual scatter within 3 x ``spread``, mm): one when the readings can tell which is
    wrong; several when they cannot (a quick artifact has no second span of the same
    direction: a typo in an outside reading is as well explained by its inside reading)."""
    out = []
    for i in range(len(fit.resid)):
        h = fit.leverage[i]
        if h > MAX_LEVERAGE:
            continue
        left = rss - fit.weights[i] * fit.resid[i] ** 2 / (1 - h)
        if math.sqrt(max(left, 0.0) / max(dof - 1, 1)) <= 3 * spread:
            out.append(i)
    return out


def _ambiguous_finding(suspects: List[_Obs]) -> fnd.Finding:
    ids = [o.meas.id for o in suspects]
    return fnd.warning(
        "artifact.outlier_ambiguous",
        Msg(
            "One of %(ids)s disagrees with the others (a typo?), and the readings cannot tell "
            "which: all of them were left out, and what only they measure stays as it was.",
            ids=", ".join(ids),
        ),
        Msg("Measure %(ids)s again.", ids=", ".join(ids)),
        ids=ids,
        readings_mm={o.meas.id: list(o.values) for o in suspects},
    )


def _too_many_finding(o: _Obs, t: float, n: int) -> fnd.Finding:
    return fnd.error(
        "artifact.too_many_outliers",
        Msg(
            "%(id)s still disagrees with the others (%(t)s sigma) after %(n)s measurements "
            "were left out: the readings do not fit one printed artifact.",
            id=o.meas.id,
            t=f"{t:.0f}",
            n=n,
        ),
        Msg("Check that the readings belong to this program and were typed in the right fields."),
        id=o.meas.id,
    )


def _outlier_finding(o: _Obs, resid_mm: float, t: float) -> fnd.Finding:
    return fnd.warning(
        "artifact.measurement_outlier",
        Msg(
            "%(id)s (mean %(mean)s mm) disagrees with the other measurements by %(off)s mm "
            "(%(t)s sigma): a typo, a jaw on a seam or a damaged wall? It was left out.",
            id=o.meas.id,
            mean=f"{o.mean:.3f}",
            off=f"{resid_mm:+.3f}",
            t=f"{t:.0f}",
        ),
        Msg("Check the readings of %(id)s and measure it again.", id=o.meas.id),
        id=o.meas.id,
        residual_um=round(resid_mm * 1e3, 1),
        t=round(t, 1),
        readings_mm=list(o.values),
    )


def _quantities(rf: _RobustFit, planes_made: List[str], found, mode: str = "full"):
    """(values, 1-sigma uncertainties) of the reported quantities: squareness um/m per
    plane, scale mismatch ppm per pair of axes, line width mm per wall family (None where
    the measurements do not determine one); ``mode``: the artifact's (full, quick), whose
    precision the poorly-determined findings go by."""
    n = len(NAMES)
    quantities = {
        ("squareness_um_per_m", "xy"): (_unit(n, 3), 1e6),
        ("squareness_um_per_m", "xz"): (_unit(n, 4), 1e6),
        ("squareness_um_per_m", "yz"): (_unit(n, 5), 1e6),
        ("scale_mismatch_ppm", "x-y"): (_unit(n, 0) - _unit(n, 1), 1e6),
        ("scale_mismatch_ppm", "x-z"): (_unit(n, 0) - _unit(n, 2), 1e6),
        ("scale_mismatch_ppm", "y-z"): (_unit(n, 1) - _unit(n, 2), 1e6),
        ("line_width_mm", "vertical_walls"): (_unit(n, 6), 1.0),
        ("line_width_mm", "slanted_walls"): (_unit(n, 7), 1.0),
    }
    values: Dict[str, Dict[str, Optional[float]]] = {}
    sigmas: Dict[str, Dict[str, Optional[float]]] = {}
    for (key, sub), (g, unit) in quantities.items():
        values.setdefault(key, {})
        sigmas.setdefault(key, {})
        if _estimable(rf.fit, g):
            values[key][sub] = float(g @ rf.fit.p) * unit
            sigmas[key][sub] = _sigma_of(rf.fit, g, rf.sigma) * unit
        else:
            values[key][sub] = sigmas[key][sub] = None
    _separability(values, sigmas, planes_made, found, POOR[mode])
    return values, sigmas


def _mean_scale(rf: _RobustFit, est_axes: List[int]) -> Optional[Tuple[float, float]]:
    """(the mean scale of the axes it determines, ppm, with the print's shrinkage; its
    1-sigma uncertainty), None when it determines none."""
    if not est_axes:
        return None
    n = len(NAMES)
    g = sum(_unit(n, k) for k in est_axes) / len(est_axes)
    return float(g @ rf.fit.p) * 1e6, _sigma_of(rf.fit, g, rf.sigma) * 1e6


def _quality_findings(rf: _RobustFit, repeat_sd: float, floor: float, found) -> None:
    """What the fit's scatter, conditioning and redundancy say about the result."""
    fit, dof, s_res = rf.fit, rf.dof, rf.s_res
    if dof >= 3 and repeat_sd > 0 and s_res > 3 * max(repeat_sd, floor):
        found.append(
            fnd.warning(
                "artifact.features_disagree",
                Msg(
                    "The measurements scatter about the fit by %(rms)s µm, %(ratio)s times more "
                    "than the repeats of one measurement (%(rep)s µm): the part may be warped, or "
                    "errors other than squareness and scale shaped it. The uncertainties use the "
                    "larger scatter.",
                    rms=f"{s_res * 1e3:.0f}",
                    ratio=f"{s_res / repeat_sd:.0f}",
                    rep=f"{repeat_sd * 1e3:.0f}",
                ),
                rms_um=round(s_res * 1e3, 2),
                repeat_um=round(repeat_sd * 1e3, 2),
            )
        )
    if fit.condition is not None and fit.condition > ILL_CONDITIONED:
        found.append(
            fnd.warning(
                "artifact.ill_conditioned",
                Msg(
                    "The measurements barely separate the unknowns (condition number %(cond)s): "
                    "spans nearly parallel, or too few directions. Small reading errors move the "
                    "result a lot; the uncertainties say how much.",
                    cond=f"{fit.condition:.0f}",
                ),
                Msg("Measure the spans of every direction the artifact has."),
                condition=round(fit.condition, 1),
            )
        )
    if dof < 3:
        found.append(
            fnd.warning(
                "artifact.little_redundancy",
                Msg(
                    "Only %(dof)s more measurements than unknowns: the uncertainties rest on the "
                    "repeats and the caliper's resolution, not on the fit.",
                    dof=max(dof, 0),
                ),
                Msg("Measure every span of the artifact, outside and inside."),
                dof=max(dof, 0),
            )
        )


def _model_findings(current: Params, found) -> None:
    """What the artifact's model assumes and cannot see."""
    found.append(
        fnd.info(
            "artifact.absolute_scale",
            Msg(
                "The plastic's shrinkage cannot be told from a common scale error: only the scale "
                "differences between the axes are used; the proposal keeps the mean scale as it "
                "was."
            ),
        )
    )
    found.append(
        fnd.info(
            "artifact.model",
            Msg(
                "Assumed: straight axes with squareness and scale errors, shrinkage the same in "
                "every direction, one line width per wall family. Backlash and non-linear errors "
                "are not measured by this artifact."
            ),
        )
    )
    if not changes_nothing(current):
        found.append(
            fnd.info(
                "artifact.residual",
                Msg(
                    "The artifact was printed with compensation active: the fitted errors are "
                    "residuals and the proposed parameters are current + residual."
                ),
            )
        )


def _fit_summary(rf: _RobustFit, obs: List[_Obs], n_readings: int, repeat_sd: float) -> dict:
    """The fit's figures for the result (um where named so)."""
    fit, sigma, s_res = rf.fit, rf.sigma, rf.s_res
    if sigma == s_res * coverage_factor(rf.dof) and s_res > 0:
        sigma_from, nu = "residual", rf.dof
    elif sigma == repeat_sd * coverage_factor(rf.repeat_dof) and repeat_sd > 0:
        sigma_from, nu = "repeats", rf.repeat_dof
    else:
        sigma_from, nu = "resolution", 0
    return {
        "readings": n_readings,
        "readings_used": int(sum(len(o.values) for o in obs)),
        "measurements_used": len(obs),
        "dof": rf.dof,
        "rank": fit.rank,
        "condition": fit.condition,
        "rms_um": s_res * 1e3,
        "repeat_sd_um": repeat_sd * 1e3,
        "sigma_reading_um": sigma * 1e3,
        "sigma_from": sigma_from,
        "coverage_factor": coverage_factor(nu),
        "model": "affine errors (squareness, scale) + isotropic shrinkage + line width",
    }


def _separability(values, sigmas, planes_made, found, poor=POOR["full"]) -> None:
    """Findings for the values the readings do not separate, and for those whose 1 sigma is
    beyond ``poor`` (squareness um/m, mismatch ppm)."""
    for plane in ("xy", "xz", "yz"):
        made = plane.upper() in planes_made
        v, s = values["squareness_um_per_m"][plane], sigmas["squareness_um_per_m"][plane]
        if v is None:
            if made:
                found.append(
                    fnd.warning(
                        "artifact.not_separable",
                        Msg(
                            "The readings cannot separate the %(plane)s squareness (measurements "
                            "missing or left out); it stays as it was.",
                            plane=plane.upper(),
                        ),
                        Msg(
                            "Measure the %(plane)s diagonals, outside and inside.",
                            plane=plane.upper(),
                        ),
                        quantity="squareness." + plane,
                    )
                )
            else:
                found.append(
                    fnd.info(
                        "artifact.not_measured_plane",
                        Msg(
                            "This artifact has no %(plane)s part: the %(plane)s squareness stays "
                            "as it was.",
                            plane=plane.upper(),
                        ),
                        plane=plane.upper(),
                    )
                )
        elif s > poor[0]:
            found.append(
                fnd.warning(
                    "artifact.poorly_determined",
                    Msg(
                        "The %(plane)s squareness is poorly determined (± %(sigma)s µm/m, 1 "
                        "sigma): too few or too short spans.",
                        plane=plane.upper(),
                        sigma=f"{s:.0f}",
                    ),
                    Msg(
                        "Print the full artifact: its 36 spans read three times each give "
                        "several times the precision."
                    )
                    if poor == POOR["quick"]
                    else Msg(
                        "Measure more repeats, or print the artifact larger (a longer caliper)."
                    ),
                    quantity="squareness." + plane,
                    sigma_um_per_m=round(s, 1),
                )
            )
    for pair in PAIRS:
        v, s = values["scale_mismatch_ppm"][pair], sigmas["scale_mismatch_ppm"][pair]
        axes = pair.replace("-", "").upper()
        if v is None:
            if all(any(a in p for p in planes_made) for a in axes):
                found.append(
                    fnd.warning(
                        "artifact.not_separable",
                        Msg(
                            "The readings cannot separate the scale mismatch %(pair)s; it stays as "
                            "it was.",
                            pair=pair,
                        ),
                        quantity="scale_mismatch." + pair,
                    )
                )
        elif s > poor[1]:
            found.append(
                fnd.warning(
                    "artifact.poorly_determined",
                    Msg(
                        "The scale mismatch %(pair)s is poorly determined (± %(sigma)s ppm, 1 "
                        "sigma).",
                        pair=pair,
                        sigma=f"{s:.0f}",
                    ),
                    quantity="scale_mismatch." + pair,
                    sigma_ppm=round(s, 1),
                )
            )


FAMILY_NAMES = {
    "vertical_walls": Msg("walls of the flat part"),
    "slanted_walls": Msg("45° walls"),
}


def _line_width_check(values, info, found) -> None:
    try:
        nozzle = float(info.get("nozzle_mm", ""))
    except ValueError:
        return
    for fam, w in values["line_width_mm"].items():
        if w is not None and not 0.5 * nozzle <= w <= 2.5 * nozzle:
            found.append(
                fnd.error(
                    "artifact.line_width_implausible",
                    Msg(
                        "The fitted line width of the %(family)s is %(width)s mm with a %(nozzle)s "
                        "mm nozzle: outside and inside readings swapped or typed in the wrong "
                        "fields?",
                        family=FAMILY_NAMES[fam],
                        width=f"{w:.3f}",
                        nozzle=f"{nozzle:g}",
                    ),
                    Msg("Outside readings are the larger ones of each span; check the fields."),
                    family=fam,
                    line_width_mm=round(w, 4),
                    nozzle_mm=nozzle,
                )
            )


def _per_measurement(obs, fit, dropped, measurements, readings) -> Dict[str, dict]:
    out = {}
    res = {o.meas.id: float(r) for o, r in zip(obs, fit.resid)}
    left = {o.meas.id for o in dropped}
    for m in measurements:
        vals = readings.get(m.id) or []
        o = next((x for x in obs + dropped if x.meas.id == m.id), None)
        out[m.id] = {
            "nominal_mm": round(m.length, 4),
            "readings": len(vals),
            "mean_mm": o.mean if o and o.values else None,
            "residual_um": res[m.id] * 1e3 if m.id in res else None,
            "left_out": m.id in left,
            "readings_left_out": [i + 1 for i, _ in o.excluded] if o else [],
        }
    return out


def _propose(values, fit: _Fit, est_axes: List[int], current: Params, simulated: bool) -> Params:
    """current + residual: squareness as fitted (0 where not separable), scales with their
    mean removed (only the mismatch is measured)."""
    u = np.zeros(3)
    if est_axes:
        mean = sum(fit.p[k] for k in est_axes) / len(est_axes)
        for k in est_axes:
            u[k] = fit.p[k] - mean
    sq = {k: (v or 0.0) * 1e-6 for k, v in values["squareness_um_per_m"].items()}
    S = np.array([[1.0, sq["xy"], sq["xz"]], [0.0, 1.0, sq["yz"]], [0.0, 0.0, 1.0]])
    A_res = S @ np.diag(1.0 + u)
    d = current.to_dict()
    split_alignment(A_res @ alignment_matrix(current), d)
    d["meta"] = proposal_meta("printed artifact", simulated, "XYZ", current)
    return checked_params(d)
