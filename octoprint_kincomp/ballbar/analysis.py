"""Ballbar trace analysis: from readings to errors, ISO 230-4 metrics and KinComp parameters.

One trace (native time series, angle domain, ``.b5r`` or typed summary) -> :func:`analyse`,
which returns ``{"diagnostics", "parameters", "firmware", "notes", "plot"}``. The pieces:

* :mod:`.timing`: native samples -> nominal angle with the planned motion of the program
  (acceleration, junction speeds, stops; settings from the metadata or the trace itself);
* :mod:`.model`: the exact radial-deviation model, its joint CW+CCW least-squares fit and the
  1-sigma uncertainty of every fitted value (signs and units documented there);
* :mod:`.metrics`: ISO 230-4 circularity (LSC and MZC), hysteresis and the plot data;
* :mod:`.proposal`: residual errors + the parameters active during the test -> a params file.

Several traces of one campaign are fitted jointly by :mod:`.joint`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..core.kinematics import changes_nothing
from ..core.messages import Msg
from ..core.params import AXES, Params
from .formats import (
    AngleTrace,
    NativeTrace,
    Summary,
    TraceError,
    meta_centre,
    meta_float,
    meta_plane,
)
from .metrics import iso_metrics, plot_data
from .model import DEFAULT_MASK_DEG, FitResult, Geometry, Model, Run, fit, reversal_mask
from .model import diagnostic_values, uncertainty_values
from .proposal import propose_params
from .timing import Mapping, runs_from_angle, runs_from_native

__all__ = ["DEFAULT_MASK_DEG", "FitResult", "Geometry", "Model", "PLANE_KEYS", "Run", "analyse",
           "analyse_runs", "fit", "iso_metrics", "load_runs", "plot_data", "propose_params",
           "reversal_mask", "runs_from_angle", "runs_from_native"]

PLANE_KEYS = {"XY": "xy", "XZ": "xz", "YZ": "yz"}


def load_runs(trace, current: Optional[Params] = None) -> Tuple[Geometry, List[Run]]:
    geom, runs, _ = load_runs_mapped(trace, current)
    return geom, runs


def load_runs_mapped(trace, current: Optional[Params] = None
                     ) -> Tuple[Geometry, List[Run], Mapping]:
    if isinstance(trace, NativeTrace):
        loaded = runs_from_native(trace, current)
    elif isinstance(trace, AngleTrace):
        loaded = runs_from_angle(trace, current)
    else:
        raise TraceError(Msg("not a trace"))
    geom, runs, mapping = loaded
    if current is not None and current.servo_precomp:
        runs = [dataclasses.replace(run, known=_lead_speed_error(geom, run, current))
                for run in runs]
    return geom, runs, mapping


def _lead_speed_error(geom: Geometry, run: Run, current: Params) -> Optional[np.ndarray]:
    """mm (+ = bar longer): the deviation of a run measured with servo pre-compensation on
    that comes from the lead's use of the programmed feed (None: not known).

    The compensator leads each axis by ``T * v_programmed`` (the chord's direction at the
    programmed feed); the drive lags by ``T * v_planned`` (the planner accelerates). Besides
    the residual lag, which the fit's ``dT`` models on the planned motion, the axis is then
    off by ``T * (v_programmed - v_planned)``: in the acceleration at the ends of the
    overshoot arcs. Unremoved, the fit took it for a smaller lag (a re-test of the simulated
    printer read -0.087 ms at F3700 and R40 instead of 0, and proposed switching the lead
    off); the ISO metrics keep it, it is there on the printer."""
    if run.vA is None or run.vB is None or not geom.speed:
        return None
    a, b = geom.axes
    t_a = current.servo_lag_ms[AXES[a]] * 1e-3
    t_b = current.servo_lag_ms[AXES[b]] * 1e-3
    s, c = np.sin(run.theta), np.cos(run.theta)
    off_a = t_a * (-run.w * geom.speed * s - run.vA)  # mm, A further than the model has it
    off_b = t_b * (run.w * geom.speed * c - run.vB)
    return off_a * c + off_b * s


def _check_both_directions(runs: Sequence[Run]) -> None:
    """Both directions must have samples: with one, the fit cannot tell squareness from
    servo mismatch (a lag difference dT shows as R * omega * dT / 2 of squareness), so a
    truncated trace or a capture stopped early would propose a wrong squareness."""
    present = {r.direction for r in runs if len(r.theta)}
    for d in ("ccw", "cw"):
        if d not in present:
            raise TraceError(Msg(
                "the trace has no %(direction)s run: with one direction the fit cannot tell "
                "squareness from servo mismatch; test (or export) both directions",
                direction=d.upper()))


def analyse_runs(geom: Geometry, runs: Sequence[Run], meta: Dict[str, str],
                 mask_deg: float = DEFAULT_MASK_DEG, calibrated: bool = False,
                 cyclic_pitch: Optional[float] = None, f: Optional[FitResult] = None,
                 mapping: Optional[Mapping] = None) -> Dict[str, object]:
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
    }
    diag.update(diagnostic_values(v, geom.radius))
    diag["bar_calibrated"] = calibrated
    if cyclic_pitch:
        diag["cyclic_error_um"] = {
            "a": math.hypot(v["cAs"], v["cAc"]) * 1e3, "b": math.hypot(v["cBs"], v["cBc"]) * 1e3,
            "pitch_mm": cyclic_pitch}
    diag["uncertainty"] = uncertainty_values(f.sigma, geom.radius)
    diag.update(iso_metrics(geom, runs, calibrated))
    diag["fit"] = {"rms_um": f.rms_um, "samples": f.samples, "masked": f.masked,
                   "mask_deg": mask_deg, "condition": f.condition, "iterations": f.iterations,
                   "correlation_inflation": f.correlation_inflation,
                   "model": "exact geometry, joint CW+CCW, common centre"}
    if mapping is not None:
        diag["fit"].update(mapping.as_dict())
    return diag


def analyse(trace, current: Optional[Params] = None, mask_deg: float = DEFAULT_MASK_DEG,
            calibrated: bool = False, cyclic_pitch: Optional[float] = None) -> Dict[str, object]:
    """Analyse a trace or summary; returns {"diagnostics", "parameters", "firmware", "notes",
    "plot"}. ``current``: the parameters active during the test (the fit is then a residual
    and the program the printer ran is the compensated one)."""
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
        geom, runs, mapping = load_runs_mapped(trace, current)
        _check_both_directions(runs)
        f = fit(geom, runs, mask_deg, calibrated, cyclic_pitch)
        diag = analyse_runs(geom, runs, trace.meta, mask_deg, calibrated, cyclic_pitch, f,
                            mapping)
        plot = plot_data(geom, runs, f, diag)
        notes += mapping_notes(mapping)
        measured_with = trace.meta.get("params_hash", "").strip()
        if measured_with not in ("", "none", "-") and measured_with != current.hash():
            notes.append(Msg("The trace was measured with parameters %(hash)s, but the "
                             "analysis assumes %(current)s were in force: give the parameters "
                             "that were active during the test, or the residuals are wrong.",
                             hash=measured_with, current=current.hash()))
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


def mapping_notes(mapping: Mapping) -> List[str]:
    s = mapping.settings
    if s is None or not s.estimated:
        return []
    if s.constant_speed:
        return [Msg("The trace records no planner settings; its ramps fit motion at constant "
                    "speed, so time was mapped to angle at the programmed feed.")]
    return [Msg("The trace records no planner settings; estimated from its own start-up and "
                "stop transients: acceleration %(accel)s mm/s^2, junction deviation %(jd)s mm "
                "(90 deg corner speed %(corner)s mm/s).", accel=f"{s.accel_mm_s2:.0f}",
                jd=f"{s.junction_deviation_mm:.4f}", corner=f"{s.corner_speed_90:.1f}")]
