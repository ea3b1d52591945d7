"""Ballbar trace analysis: from readings to errors, ISO 230-4 metrics and KinComp parameters.

One trace (native time series, angle domain, ``.b5r`` or typed summary) -> :func:`analyse`,
which returns the result document (``calibration/result.py``: diagnostics, proposed
parameters, firmware equivalents, findings, trusted, verdict, notes, plot). The pieces:

* :mod:`.timing`: native samples -> nominal angle with the planned motion of the program
  (acceleration, junction speeds, stops; settings from the metadata or the trace itself);
* :mod:`.model`: the exact radial-deviation model, its joint CW+CCW least-squares fit and the
  1-sigma uncertainty of every fitted value (signs and units documented there);
* :mod:`.metrics`: ISO 230-4 circularity (LSC and MZC), hysteresis and the plot data;
* ``proposal.py``: residual errors + the parameters active during the test -> a params file;
* :mod:`.checks`: what is checked before the result is trusted (timing against the plan,
  the residual against the noise floor, cyclic error, outliers) -> ``findings`` (see
  ``findings.py``); ``trusted`` is False when a finding is an error. ``notes`` (the info
  findings' messages) stays for older readers.

Several traces of one campaign are fitted jointly by :mod:`.joint`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...core.kinematics import changes_nothing
from ...core.messages import Msg
from ...core.params import AXES, Params
from ...firmware.compensation import FirmwareCompensation
from ..findings import Finding, info, warning
from ..proposal import propose_params
from ..result import result_document
from . import checks, provenance
from .formats import (
    AngleTrace,
    NativeTrace,
    Summary,
    TraceError,
    meta_centre,
    meta_float,
    meta_plane,
)
from .metrics import circularity, iso_metrics, plot_data
from .model import (
    DEFAULT_MASK_DEG,
    FitResult,
    Geometry,
    Model,
    Run,
    diagnostic_values,
    fit,
    reversal_mask,
    uncertainty_values,
)
from .timing import (
    CONTINUOUS_DEADBAND_MM,
    Mapping,
    SentWith,
    runs_from_angle,
    runs_from_native,
)

__all__ = [
    "DEFAULT_MASK_DEG",
    "FitResult",
    "Geometry",
    "Model",
    "PLANE_KEYS",
    "Run",
    "analyse",
    "analyse_runs",
    "fit",
    "iso_metrics",
    "load_runs",
    "plot_data",
    "propose_params",
    "reversal_mask",
    "runs_from_angle",
    "runs_from_native",
]

PLANE_KEYS = {"XY": "xy", "XZ": "xz", "YZ": "yz"}


def load_runs(trace, current: Optional[Params] = None) -> Tuple[Geometry, List[Run]]:
    geom, runs, _ = load_runs_mapped(trace, current)
    return geom, runs


def load_runs_mapped(
    trace, current: Optional[Params] = None, sent: Optional[SentWith] = None
) -> Tuple[Geometry, List[Run], Mapping]:
    """The runs of a trace on the nominal circle; ``current``: the parameters in force,
    ``sent``: how the compensated program was written (the trace's record first)."""
    if isinstance(trace, NativeTrace):
        loaded = _native_sent(trace, current, sent)
    elif isinstance(trace, AngleTrace):
        loaded = runs_from_angle(trace, current, sent)
    else:
        raise TraceError(Msg("not a trace"))
    geom, runs, mapping = loaded
    if current is not None and current.servo_precomp:
        runs = [
            dataclasses.replace(run, known=_lead_speed_error(geom, run, current)) for run in runs
        ]
    return geom, runs, mapping


# a compensated time series whose runs' timing is off by more than this (ms) with the assumed
# dead band, and by less than half of it with the one of a stepless printer (1e-6 mm), was
# compensated with that one (the command line's compensate --steps-per-mm 50000 writes it)
SENT_PROBE_MS = 3.0


def _native_sent(trace: NativeTrace, current, sent: Optional[SentWith]):
    """``runs_from_native`` with the compensator's dead band the trace records or the caller
    gives; with neither (the compensator's defaults assumed), when the timing says the
    program was written with the stepless dead band instead, with that one."""
    loaded = runs_from_native(trace, current, sent)
    mapping = loaded[2]
    worst = max((abs(v) for v in mapping.sync_ms.values()), default=0.0)
    if mapping.sent_source != "default" or worst <= SENT_PROBE_MS:
        return loaded
    alt = SentWith(mapping.sent.decimals, CONTINUOUS_DEADBAND_MM)
    try:
        other = runs_from_native(trace, current, alt)
    except TraceError:
        return loaded
    if max((abs(v) for v in other[2].sync_ms.values()), default=0.0) < 0.5 * worst:
        other[2].sent_source = "timing"
        return other
    return loaded


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
            raise TraceError(
                Msg(
                    "the trace has no %(direction)s run: with one direction the fit cannot tell "
                    "squareness from servo mismatch; test (or export) both directions",
                    direction=d.upper(),
                )
            )


@dataclass
class CheckedFit:
    """A fit after the trust checks: the fit the values come from (outliers left out, the
    cyclic term added when the residual showed one, the readings corrected for a sensor gain
    the feed-in showed), its findings and diagnostics."""

    fit: FitResult
    runs: List[Run]  # the runs the fit used (outliers left out)
    cyclic_pitch: Optional[float]
    findings: List[Finding] = field(default_factory=list)
    checks: Dict[str, object] = field(default_factory=dict)  # diag["checks"]
    robust_runs: Optional[List[Run]] = None  # for the circularity without outliers
    all_runs: List[Run] = field(default_factory=list)  # every sample (gain-corrected)
    gain: float = 1.0  # the sensor gain taken off the readings (1: none)


def _scaled(runs: Sequence[Run], factor: float) -> List[Run]:
    """The runs with their readings multiplied by ``factor`` (a sensor gain taken off)."""
    return [dataclasses.replace(r, dev=r.dev * factor) for r in runs]


def checked_fit(
    geom: Geometry,
    runs: Sequence[Run],
    mapping: Optional[Mapping],
    mask_deg: float = DEFAULT_MASK_DEG,
    calibrated: bool = False,
    cyclic_pitch: Optional[float] = None,
    label: str = "",
    fixed: Optional[Dict[str, float]] = None,
) -> CheckedFit:
    """Fit, then check the evidence (see :mod:`.checks`): outliers are left out and the fit
    repeated; a clear cyclic error in the residual is fitted (when ``cyclic_pitch`` is not
    given); a sensor gain the feed-in shows is taken off the readings; the timing, the labels
    and the residual against the noise floor become findings."""
    runs = list(runs)
    found: List[Finding] = list(checks.motion_findings(geom, mapping, label))
    found += checks.ramp_findings(geom, mapping, label)
    found += checks.run_order_findings(mapping, label)
    found += checks.arc_findings(mapping, label)
    f = fit(geom, runs, mask_deg, calibrated, cyclic_pitch, fixed=fixed)
    floor, source = checks.noise_floor(f, runs, mapping)
    out = CheckedFit(f, runs, cyclic_pitch, all_runs=runs)
    drop = checks.find_outliers(f, runs, floor)
    n_out = int(sum(int(m.sum()) for m in drop.values()))
    out.checks["outliers"] = n_out
    if n_out:
        runs = checks.without(runs, drop)
        out.robust_runs = runs
        f = fit(geom, runs, mask_deg, calibrated, cyclic_pitch, fixed=fixed)
        if source == "residual":
            floor = max(checks.residual_floor(f, runs) * 1e3, checks.FLOOR_MIN_UM)
    keep = checks.keep_mask(runs, mask_deg)
    scan = checks.scan_cyclic(geom, runs, f, keep)
    if scan is not None:
        out.checks["cyclic_scan"] = {
            "pitch_mm": round(scan["pitch_mm"], 4),
            "amplitude_um": {k: round(v, 3) for k, v in scan["amplitude_um"].items()},
        }
    if cyclic_pitch is None and checks.cyclic_detected(
        scan, floor, checks.excess_mm2(runs, f, keep, floor)
    ):
        cyclic_pitch = float(scan["pitch_mm"])
        f2 = fit(geom, runs, mask_deg, calibrated, cyclic_pitch, fixed=fixed)
        if f2.rms_um < f.rms_um:
            f = f2
            out.cyclic_pitch = cyclic_pitch
            found.append(checks.cyclic_finding(scan, label))
            scan = checks.scan_cyclic(geom, runs, f, keep)
    f, runs, floor = _sensor_gain(geom, runs, mapping, f, out, floor, mask_deg, calibrated, fixed)
    found += checks.sensor_findings(
        mapping, out.checks.get("sensor_gain"), getattr(mapping, "feed_in_mm", 1.0), label
    )
    misfit_floor, misfit_source, vibration, moving_ev = checks.misfit_floor(
        f, runs, floor, source, label
    )
    found += vibration
    adequacy, ev = checks.adequacy_findings(
        geom,
        runs,
        f,
        keep,
        misfit_floor,
        misfit_source,
        scan if checks.cyclic_detected(scan, floor) else None,
        label,
    )
    found += adequacy
    ev.update(moving_ev)
    out.checks["adequacy"] = ev
    found += _stability(geom, runs, f, out, mask_deg, calibrated, fixed, label)
    out.fit = f
    out.runs = runs
    out.findings = found
    return out


def _sensor_gain(geom, runs, mapping, f, out: CheckedFit, floor, mask_deg, calibrated, fixed):
    """The sensor's gain from the still readings outside the circle (``checks.sensor_gain``)
    into ``out.checks``; one clearly off 1 is taken off every reading (the fit repeated):
    returns the fit, the runs and the noise floor (um) to go on with."""
    if mapping is None or not mapping.timed:
        return f, runs, floor
    gain = checks.sensor_gain(geom, f, out.cyclic_pitch, mapping.still_levels, mapping.feed_in_mm)
    out.checks["sensor_gain"] = gain
    if not checks.gain_significant(gain, mapping.feed_in_mm):
        return f, runs, floor
    out.gain = float(gain["value"])
    k = 1.0 / out.gain
    runs = _scaled(runs, k)
    out.all_runs = _scaled(out.all_runs, k)
    if out.robust_runs is not None:
        out.robust_runs = runs
    f = fit(geom, runs, mask_deg, calibrated, out.cyclic_pitch, fixed=fixed)
    return f, runs, floor * k


def _stability(geom, runs, f, out: CheckedFit, mask_deg, calibrated, fixed, label):
    """The stability check against a wider reversal mask (``checks.stability_findings``)."""
    wider = mask_deg + checks.STABILITY_EXTRA_DEG
    try:
        f_wide = fit(geom, runs, wider, calibrated, out.cyclic_pitch, fixed=fixed)
    except TraceError:
        return []
    return checks.stability_findings(
        diagnostic_values(f.values, geom.radius),
        diagnostic_values(f_wide.values, geom.radius),
        uncertainty_values(f.sigma, geom.radius),
        uncertainty_values(f_wide.sigma, geom.radius),
        mask_deg,
        wider,
        label,
        checks.reached_sides(runs),
        plane=geom.plane,
    )


def analyse_runs(
    geom: Geometry,
    runs: Sequence[Run],
    meta: Dict[str, str],
    mask_deg: float = DEFAULT_MASK_DEG,
    calibrated: bool = False,
    cyclic_pitch: Optional[float] = None,
    f: Optional[FitResult] = None,
    mapping: Optional[Mapping] = None,
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
    }
    diag.update(diagnostic_values(v, geom.radius))
    diag["bar_calibrated"] = calibrated
    if cyclic_pitch:
        diag["cyclic_error_um"] = {
            "a": math.hypot(v["cAs"], v["cAc"]) * 1e3,
            "b": math.hypot(v["cBs"], v["cBc"]) * 1e3,
            "pitch_mm": cyclic_pitch,
        }
    diag["uncertainty"] = uncertainty_values(f.sigma, geom.radius)
    diag.update(iso_metrics(geom, runs, calibrated))
    diag["fit"] = {
        "rms_um": f.rms_um,
        "samples": f.samples,
        "masked": f.masked,
        "mask_deg": mask_deg,
        "condition": f.condition,
        "iterations": f.iterations,
        "correlation_inflation": f.correlation_inflation,
        "model": "exact geometry, joint CW+CCW, common centre",
    }
    if mapping is not None:
        diag["fit"].update(mapping.as_dict())
    return diag


@dataclass
class Provenance:
    """Where a trace comes from, as the caller knows it (``provenance.py``): the firmware's
    compensation during the test (the trace's own record wins), and how the trace is tied
    to the program KinComp printed (``confirmed``: e.g. ``"capture"``, ``"printed"``;
    None: it is not, and the result says what to confirm)."""

    firmware: Optional[FirmwareCompensation] = None
    confirmed: Optional[str] = None


def analyse(
    trace,
    current: Optional[Params] = None,
    mask_deg: float = DEFAULT_MASK_DEG,
    calibrated: bool = False,
    cyclic_pitch: Optional[float] = None,
    known_squareness_um_per_m: Optional[Dict[str, float]] = None,
    known_sources: Optional[Dict[str, str]] = None,
    sent: Optional[SentWith] = None,
    origin: Optional[Provenance] = None,
) -> Dict[str, object]:
    """Analyse a trace or summary; returns the result document (``calibration/result.py``).
    ``current``: the parameters active during the test (the fit is then a residual and the
    program the printer ran is the compensated one, written as ``sent`` says: the trace's
    record first, else the compensator's defaults).

    ``known_squareness_um_per_m``: the printer's squareness (um/m, keys ``xy``, ``xz``,
    ``yz``, as KinComp's parameters state it: e.g. an XY result's proposal) that a vertical
    test cannot see but that moves its third axis (:data:`.model.OUT_OF_PLANE`); less what
    ``current`` corrects, it is fitted as a fixed motion (as the joint fit does) instead of
    biasing the scale mismatch and squareness; ``known_sources``: per key, where the value
    came from (said in the ``model.out_of_plane_used`` finding). ``origin``: the firmware's
    compensation and the program's confirmation (:class:`Provenance`)."""

    current = current or Params()
    origin = origin or Provenance()
    notes: List[str] = []
    found: List[Finding] = []
    plot = None
    need = None
    fw = provenance.firmware_of(trace.meta, origin.firmware)
    if isinstance(trace, Summary):
        diag, geom = _summary(trace, notes, found)
    else:
        known = checked_known_squareness(known_squareness_um_per_m)
        geom, diag, plot, mapping = _trace(
            trace, current, mask_deg, calibrated, cyclic_pitch, known, known_sources, sent, found
        )
        found += provenance.program_findings(trace.meta)
        found += checks.backlash_findings(
            diag, _reached(diag), current.has_backlash, fw if fw.known or fw.active else None
        )
        found += provenance.firmware_findings(fw, geom.plane)
        extra = provenance.with_firmware(diag, fw, geom.letters)
        diag["firmware_compensation"] = fw.to_dict()
        if extra:
            diag["with_firmware"] = extra
        for n in mapping_notes(mapping):
            notes.append(n)
            found.append(info("motion.estimated", n))
        found += _params_findings(trace.meta, current, calibrated, notes)
        timing_ok = not any(x.code in ("motion.timing", "motion.ramp") for x in found)
        need = provenance.needs_confirmation(
            trace.meta, mapping.timed, timing_ok, origin.confirmed, fw.known or fw.active
        )
        if need is not None:
            found.append(provenance.confirmation_finding(need))
    if current is not None and not changes_nothing(current):
        n = Msg(
            "The test ran with compensation active: the fitted errors are "
            "residuals and the proposed parameters are current + residual."
        )
        notes.append(n)
        found.append(info("params.residual", n))
    before = len(notes)
    params = propose_params(diag, geom, current, notes, fw if fw.known or fw.active else None)
    found += [info("proposal.note", n) for n in notes[before:]]
    return result_document(diag, params, found, notes, plot, needs_confirmation=need)


def _reached(diag: Dict[str, object]) -> List[str]:
    """The backlash sides the test reached (``diag["checks"]["reached_sides"]``)."""
    return list((diag.get("checks") or {}).get("reached_sides") or [])


def _summary(trace: Summary, notes: List[str], found: List[Finding]):
    """(diagnostics, geometry) of a summary: its numbers, nothing behind them checked."""
    diag = dict(trace.diagnostics)
    geom = Geometry(
        meta_plane(trace.meta),
        meta_float(trace.meta, "radius_mm", 0.0),
        meta_centre(trace.meta),
        meta_float(trace.meta, "feed_mm_min", 0.0) or None,
    )
    diag.setdefault("plane", geom.plane)
    diag["source"] = trace.meta.get("source", "summary")
    notes += trace.notes
    found.append(
        info(
            "source.summary",
            Msg(
                "These values come from another program's summary, not from a trace: KinComp "
                "could not check the motion, the fit or the noise behind them."
            ),
        )
    )
    return diag, geom


def _trace(trace, current, mask_deg, calibrated, cyclic_pitch, known, known_sources, sent, found):
    """The checked fit of one trace: (geometry, diagnostics, plot, mapping); its findings
    go into ``found``."""
    geom, runs, mapping = load_runs_mapped(trace, current, sent)
    _check_both_directions(runs)
    fixed, used = checks.out_of_plane_used(
        geom.plane, known, current.squareness_um_per_m, known_sources or {}
    )
    cf = checked_fit(geom, runs, mapping, mask_deg, calibrated, cyclic_pitch, fixed=fixed or None)
    runs = cf.all_runs
    f = cf.fit
    diag = analyse_runs(geom, runs, trace.meta, mask_deg, calibrated, cf.cyclic_pitch, f, mapping)
    found += cf.findings
    found += outlier_findings(cf, diag, radius=geom.radius)
    cf.checks["reached_sides"] = checks.reached_sides(cf.runs)
    diag["checks"] = cf.checks
    drift = checks.drift_finding(diag, runs)
    if drift is not None:
        found.append(drift)
    oop = checks.out_of_plane_finding(geom.plane, current.squareness_um_per_m, list(known))
    if oop is not None:
        found.append(oop)
    if used is not None:
        found.append(used)
    if fixed:
        diag["fit"]["out_of_plane_um_per_m"] = {k: v * 1e6 for k, v in fixed.items()}
    plot = plot_data(geom, runs, f, diag)
    return geom, diag, plot, mapping


def _params_findings(meta, current: Params, calibrated: bool, notes: List[str]) -> List[Finding]:
    """The parameters the trace records against those in force, and the bar's calibration."""
    out: List[Finding] = []
    measured_with = meta.get("params_hash", "").strip()
    if measured_with not in ("", "none", "-") and measured_with != current.hash():
        n = Msg(
            "The trace was measured with parameters %(hash)s, but the "
            "analysis assumes %(current)s were in force: give the parameters "
            "that were active during the test, or the residuals are wrong.",
            hash=measured_with,
            current=current.hash(),
        )
        notes.append(n)
        out.append(
            warning("params.mismatch", n, evidence_hash=measured_with, current_hash=current.hash())
        )
    if not calibrated:
        n = Msg(
            "The bar is not calibrated: the mean radius mixes the bar's own "
            "length error with the mean axis scale, so only the scale "
            "mismatch is used."
        )
        notes.append(n)
        out.append(info("bar.uncalibrated", n))
    return out


def checked_known_squareness(values: Optional[Dict[str, float]]) -> Dict[str, float]:
    """``values`` (um/m by KinComp's squareness key) checked: ValueError naming a key that is
    not ``xy``, ``xz`` or ``yz`` or a value that is not a finite number."""
    out: Dict[str, float] = {}
    for k, v in (values or {}).items():
        if k not in PLANE_KEYS.values():
            raise ValueError(Msg("known squareness: %(key)s is not one of xy, xz, yz", key=str(k)))
        try:
            f = float(v)
        except (TypeError, ValueError):
            f = math.nan
        if not math.isfinite(f) or isinstance(v, bool):
            raise ValueError(Msg("known squareness: %(key)s must be a finite number (µm/m)", key=k))
        out[k] = f
    return out


def outlier_findings(
    cf: CheckedFit, diag: Dict[str, object], label: str = "", radius: float = 0.0
) -> List[Finding]:
    """The circularity without the outliers the checks left out of the fit, and a finding
    saying how much they weigh (a warning when they dominate G(b)); ``label`` prefixes the
    message (a campaign's file name); ``radius`` (mm): the nominal radius (see
    :func:`.metrics.circularity`)."""
    if not cf.robust_runs:
        return []
    pre = (label + ": ") if label else ""
    robust = circularity([r.captured() for r in cf.robust_runs], radius)
    diag["circularity_robust_um"] = robust
    g, gr = diag["circularity_um"]["bidirectional"], robust["bidirectional"]
    n = cf.checks.get("outliers", 0)
    ev = dict(outliers=n, g_b_um=round(g, 2), g_b_without_um=round(gr, 2))
    if g > checks.OUTLIER_DOMINATE * gr:
        return [
            warning(
                "data.outliers",
                Msg(
                    "%(pre)s%(n)s isolated samples lie far from their neighbours (a sensor "
                    "glitch, a knock): the circularity G(b) is %(g)s µm with them and %(gr)s µm "
                    "without. They dominate G(b) and any before/after comparison of it; the fit "
                    "left them out.",
                    pre=pre,
                    n=n,
                    g=f"{g:.1f}",
                    gr=f"{gr:.1f}",
                ),
                Msg(
                    "Compare the circularity without them (the value above), or repeat the test "
                    "with the sensor's cable and mount secured."
                ),
                **ev,
            )
        ]
    return [
        info(
            "data.outliers",
            Msg(
                "%(pre)s%(n)s isolated samples far from their neighbours were left out of the fit "
                "(G(b) %(g)s µm with them, %(gr)s µm without).",
                pre=pre,
                n=n,
                g=f"{g:.1f}",
                gr=f"{gr:.1f}",
            ),
            **ev,
        )
    ]


def mapping_notes(mapping: Mapping) -> List[str]:
    s = mapping.settings
    if s is None or not s.estimated:
        return []
    if s.constant_speed:
        return [
            Msg(
                "The trace records no planner settings; its ramps fit motion at constant "
                "speed, so time was mapped to angle at the programmed feed."
            )
        ]
    return [
        Msg(
            "The trace records no planner settings; estimated from its own start-up and "
            "stop transients: acceleration %(accel)s mm/s², junction deviation %(jd)s mm "
            "(90° corner speed %(corner)s mm/s).",
            accel=f"{s.accel_mm_s2:.0f}",
            jd=f"{s.junction_deviation_mm:.4f}",
            corner=f"{s.corner_speed_90:.1f}",
        )
    ]
