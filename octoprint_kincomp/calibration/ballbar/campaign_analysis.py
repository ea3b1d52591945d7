"""Analysis of a whole campaign: checks, the joint fit, the servo decision, ONE parameter set.

:func:`analyse_campaign` takes the traces of a campaign (file name and parsed trace each) and
the parameters that were in force while they were measured; it returns the result document
(``calibration/result.py``) as :func:`.analysis.analyse` does, where ``diagnostics`` holds
``traces`` (per trace: ``file``, ``plane`` and the single-trace keys) and ``campaign`` (the
joint values with their 1-sigma uncertainties, see :mod:`.joint`).

Parameters the campaign did not measure (a plane without a test, an axis in no plane) keep
their values from ``current``. Servo pre-compensation is decided from data: with XY at two
feeds it is proposed when the servo mismatch is the same at both (within 2 sigma of their
difference) and clearly not zero; a single feed leaves it as it was.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ...core.kinematics import changes_nothing
from ...core.messages import Msg
from ...core.params import AXES, Params
from ...firmware.compensation import FirmwareCompensation
from ..findings import Finding, info
from ..proposal import alignment_matrix, checked_params, proposal_meta, split_alignment
from ..result import result_document
from . import checks, provenance
from .analysis import analyse_runs, checked_fit, load_runs_mapped, mapping_notes, outlier_findings
from .campaign import CampaignError, check_traces
from .formats import TraceError
from .joint import TraceFit, check_coverage, joint_fit, joint_values, summary
from .metrics import plot_data
from .model import DEFAULT_MASK_DEG, fit
from .timing import SentWith

RMS_OUTLIER = 4.0  # a trace whose residual is this many times the campaign's median failed
AGREE_SIGMA = 2.0  # lags at two feeds agree when they differ by less than this many sigma
# ... or by less than this share of the lag: the lead v*T then removes at least 80 % of it at
# every speed (lags are measured to a few um/s: sigma alone would call a lag that differs by
# 2 % between the feeds "not proportional" and throw the whole lead away)
AGREE_FRACTION = 0.2


def analyse_campaign(
    items: Sequence[Tuple[str, object]],
    current: Optional[Params] = None,
    mask_deg: float = DEFAULT_MASK_DEG,
    calibrated: bool = False,
    cyclic_pitch: Optional[float] = None,
    manifest: Optional[Dict[str, object]] = None,
    sent: Optional[SentWith] = None,
    firmware: Optional[FirmwareCompensation] = None,
) -> Dict[str, object]:
    """Joint analysis of a campaign's traces; raises CampaignError (naming the file) when the
    traces are not one complete campaign or a test failed: nothing is proposed then.
    ``sent``: how compensated programs were written (each trace's record first);
    ``firmware``: the firmware's compensation during the tests (the first trace's record
    first)."""

    current = current or Params()
    fw = provenance.firmware_of(items[0][1].meta if items else {}, firmware)
    fw_known = fw if fw.known or fw.active else None
    check_traces(items, current.hash(), manifest)
    notes: List[str] = []
    found: List[Finding] = []
    fits, maps, pitches = _fit_each(items, current, sent, mask_deg, calibrated, cyclic_pitch)
    for t, (_, mapping, cf, _) in zip(fits, maps):
        found += cf.findings
        for n in mapping_notes(mapping):
            n = Msg("%(file)s: %(note)s", file=t.name, note=n)
            notes.append(n)
            found.append(info("motion.estimated", n))
    _check_outliers(fits)
    if pitches and cyclic_pitch is None:
        # one cyclic term for the joint model: the pitch the traces showed (their median)
        cyclic_pitch = float(np.median(pitches))
        fits = [
            TraceFit(
                t.name, t.geom, t.runs, fit(t.geom, t.runs, mask_deg, calibrated, cyclic_pitch)
            )
            for t in fits
        ]
    res = joint_fit(fits, mask_deg, calibrated, cyclic_pitch)
    joint_found, joint_ev = checks.joint_findings(
        [_joint_row(t, res, cf) for t, (_, _, cf, _) in zip(fits, maps)],
        sum(len(t.model.names) for t in fits) - len(res.names),
    )
    found += joint_found
    fitting = (mask_deg, calibrated, cyclic_pitch)
    per_trace, plots = [], []
    for i, (t, (meta, mapping, cf, _)) in enumerate(zip(fits, maps)):
        diag, plot, said = _one_test(t, meta, mapping, cf, res, i, fitting, current, fw_known)
        found += said
        per_trace.append(dict({"file": t.name}, **diag))
        plots.append(plot)
    camp = _campaign_summary(res, len(fits), per_trace, current, calibrated, notes)
    camp["checks"] = {"joint": joint_ev}
    camp["fit"] = {
        "rms_um": res.rms_um,
        "samples": res.samples,
        "condition": res.condition,
        "iterations": res.iterations,
        "model": "joint exact geometry over all traces, one parameter set",
    }
    simulated = any(t.get("simulated") for t in per_trace)
    params = propose_campaign(
        res, len(fits), current, notes, bool(camp["servo_precomp"]["proposed"]), simulated, fw_known
    )
    found += provenance.firmware_findings(fw, "")
    camp["firmware_compensation"] = fw.to_dict()
    if camp["residual"]:
        notes.append(
            Msg(
                "The campaign ran with compensation active: the fitted errors are "
                "residuals and the proposed parameters are current + residual."
            )
        )
    shown = {str(x.message) for x in found}
    found += [info("campaign.note", n) for n in notes if str(n) not in shown]
    diag = {"traces": per_trace, "campaign": camp, "simulated": simulated}
    return result_document(diag, params, found, notes, None, plots)


def _fit_each(items, current: Params, sent, mask_deg, calibrated, cyclic_pitch):
    """Each trace loaded, mapped to angles and fitted on its own: ([TraceFit], [(meta,
    mapping, checked fit, runs)], [the cyclic pitches the traces showed, mm]); a trace that
    cannot be used raises CampaignError naming its file."""
    fits: List[TraceFit] = []
    maps = []
    pitches = []
    for name, trace in items:
        try:
            geom, runs, mapping = load_runs_mapped(trace, current, sent)
            check_coverage(name, geom, runs)
            cf = checked_fit(geom, runs, mapping, mask_deg, calibrated, cyclic_pitch, name)
        except CampaignError:
            raise
        except TraceError as exc:
            raise CampaignError(Msg("%(file)s: %(error)s", file=name, error=str(exc))) from None
        if cf.cyclic_pitch and cyclic_pitch is None:
            pitches.append(cf.cyclic_pitch)
        fits.append(TraceFit(name, geom, cf.runs, cf.fit))
        maps.append((trace.meta, mapping, cf, runs))
    return fits, maps, pitches


def _one_test(t: TraceFit, meta, mapping, cf, res, i: int, fitting, current: Params, fw_known):
    """Test ``i`` of the joint fit ``res`` on its own, with the out-of-plane motion the
    other planes' squareness causes taken into account: (its diagnostics, its plot, its
    findings). ``fitting``: (mask_deg, calibrated, cyclic_pitch)."""
    mask_deg, calibrated, cyclic_pitch = fitting
    fixed = res.layout.out_of_plane(t.geom.plane, res.values)
    f = (
        fit(t.geom, t.runs, mask_deg, calibrated, cyclic_pitch, fixed=fixed)
        if any(fixed.values())
        else t.fit
    )
    # the ISO metrics and the plot of all samples, outliers included (as for one trace)
    raw = cf.all_runs  # every sample, the sensor's gain taken off
    diag = analyse_runs(t.geom, raw, meta, mask_deg, calibrated, cyclic_pitch, f, mapping)
    found = outlier_findings(cf, diag, t.name, t.geom.radius)
    found += checks.backlash_findings(
        diag, checks.reached_sides(t.runs), current.has_backlash, fw_known, t.name
    )
    drift = checks.drift_finding(diag, raw, t.name)
    if drift is not None:
        found.append(drift)
    if f is not t.fit:
        diag["fit"]["out_of_plane_um_per_m"] = {k: v * 1e6 for k, v in fixed.items()}
    diag["joint"] = joint_values(res, i)
    diag["checks"] = cf.checks
    return diag, plot_data(t.geom, raw, f, diag), found


def _campaign_summary(res, traces: int, per_trace, current: Params, calibrated: bool, notes):
    """The campaign's own diagnostics (a dict): the joint values, the rules behind them,
    the closure of the scale mismatches, the servo decision, XY squareness by height (their
    notes appended to ``notes``)."""
    camp = summary(res)
    camp["planes"] = list(res.layout.planes)
    camp["traces"] = traces
    camp["fitted"] = _fitted(res)
    camp["scale_rule"] = (
        Msg("absolute: the calibrated bar's length gives the mean scale")
        if calibrated
        else Msg(
            "a ballbar sees only differences between axes: the mean scale "
            "of the measured axes is left as it was"
        )
    )
    camp["servo_rule"] = Msg(
        "only differences between axes are measurable: the axis that lags least is at 0"
    )
    camp["residual"] = not changes_nothing(current)
    closure = _closure(per_trace)
    if closure is not None:
        camp["closure_ppm"] = closure
        if abs(closure["value"]) > 3 * closure["sigma"] + 1.0:
            notes.append(
                Msg(
                    "The scale mismatches of XY, XZ and YZ do not add up (x-y + y-z - "
                    "x-z = %(value)s ± %(sigma)s ppm): an error the model does not "
                    "describe (non-linear scale, a loose bar); check the set-up.",
                    value=f"{closure['value']:.1f}",
                    sigma=f"{closure['sigma']:.1f}",
                )
            )
    camp["servo_precomp"] = _servo_decision(per_trace, current, notes)
    heights = _xy_heights(per_trace, notes)
    if heights:
        camp["squareness_xy_by_height"] = heights
    return camp


def _joint_row(t: TraceFit, res, cf) -> Dict[str, float]:
    """What :func:`.checks.joint_findings` needs of one trace."""
    return {
        "file": t.name,
        "own_rms_um": t.fit.rms_um,
        "joint_rms_um": res.rms_um[t.name],
        "samples": int(t.keep.sum()),
        "inflation": t.fit.correlation_inflation,
        "floor_um": float(cf.checks["adequacy"]["noise_floor_um"]),
    }


def _fitted(res) -> List[str]:
    lay = res.layout
    out = [f"squareness {p.lower()}" for p in lay.planes]
    out.append("scale " + ", ".join(lay.axes) + ("" if lay.calibrated else " (differences)"))
    if lay.servo:
        out.append("servo lag " + ", ".join(lay.lag_axes) + " (differences)")
    out += [f"backlash {a}" for a in lay.backlash_span]
    return out


def _check_outliers(fits: Sequence[TraceFit]) -> None:
    med = float(np.median([t.fit.rms_um for t in fits]))
    for t in fits:
        if t.fit.rms_um > RMS_OUTLIER * med and t.fit.rms_um > 3.0:
            raise CampaignError(
                Msg(
                    "%(file)s: the fit leaves %(rms)s µm rms (the other tests %(med)s µm): the bar "
                    "slipped or the test failed; repeat this test",
                    file=t.name,
                    rms=f"{t.fit.rms_um:.1f}",
                    med=f"{med:.1f}",
                )
            )


def _closure(per_trace) -> Optional[Dict[str, float]]:
    by = {}
    for d in per_trace:
        by.setdefault(d["plane"], d)
    if set(by) != {"XY", "XZ", "YZ"}:
        return None
    v = (
        by["XY"]["scale_mismatch_ppm"]
        + by["YZ"]["scale_mismatch_ppm"]
        - by["XZ"]["scale_mismatch_ppm"]
    )
    s = math.sqrt(sum(by[p]["uncertainty"]["scale_mismatch_ppm"] ** 2 for p in by))
    return {"value": v, "sigma": s}


def _servo_decision(per_trace, current: Params, notes: List[str]) -> Dict[str, object]:
    xy = [d for d in per_trace if d["plane"] == "XY" and d.get("servo_mismatch_ms") is not None]
    feeds = sorted({round(d["feed_mm_min"] or 0.0, 1) for d in xy})
    by_feed = [
        {
            "feed_mm_min": d["feed_mm_min"],
            "file": d["file"],
            "servo_mismatch_ms": d["servo_mismatch_ms"],
            "sigma": d["uncertainty"]["servo_mismatch_ms"],
        }
        for d in xy
    ]
    out: Dict[str, object] = {"by_feed": by_feed}
    if len(feeds) < 2 or feeds[-1] < 1.2 * feeds[0]:
        out["proposed"] = current.servo_precomp
        out["reason"] = Msg(
            "XY ran at one feed only: one feed cannot show that the lag grows with speed, so "
            "servo pre-compensation stays %(state)s (add XY at a second feed to decide)",
            state=Msg("on") if current.servo_precomp else Msg("off"),
        )
        notes.append(out["reason"])
        return out
    lo = min(xy, key=lambda d: d["feed_mm_min"])
    hi = max(xy, key=lambda d: d["feed_mm_min"])
    a, sa = lo["servo_mismatch_ms"], lo["uncertainty"]["servo_mismatch_ms"]
    b, sb = hi["servo_mismatch_ms"], hi["uncertainty"]["servo_mismatch_ms"]
    diff, sdiff = b - a, math.hypot(sa, sb)
    # measured with the lead on, a and b are residuals: the lag itself is the lead's + them
    lead = current.servo_lag_ms["x"] - current.servo_lag_ms["y"] if current.servo_precomp else 0.0
    size = max(abs(a + lead), abs(b + lead))
    w = 1 / sa**2 + 1 / sb**2
    mean, smean = (a / sa**2 + b / sb**2) / w, 1 / math.sqrt(w)
    fmt = dict(
        f1=f"{lo['feed_mm_min']:g}",
        f2=f"{hi['feed_mm_min']:g}",
        a=f"{a:.3f}",
        sa=f"{sa:.3f}",
        b=f"{b:.3f}",
        sb=f"{sb:.3f}",
    )
    if abs(diff) > max(AGREE_SIGMA * sdiff, AGREE_FRACTION * size):
        out["proposed"] = False
        totals = dict(fmt, a=f"{a + lead:.3f}", b=f"{b + lead:.3f}")  # the lag itself
        out["reason"] = Msg(
            "The XY servo mismatch differs between F%(f1)s (%(a)s ± %(sa)s ms) and F%(f2)s "
            "(%(b)s ± %(sb)s ms): the lag is not proportional to speed, so leading each move "
            "by v*T would be wrong at other speeds; servo pre-compensation is left off",
            **totals,
        )
    elif current.servo_precomp:
        # measured with the lead on: a and b are what it leaves
        out["proposed"] = True
        out["reason"] = Msg(
            "With servo pre-compensation on (%(lag)s ms), the XY servo mismatch left is "
            "%(a)s ± %(sa)s ms at F%(f1)s and %(b)s ± %(sb)s ms at F%(f2)s, within "
            "%(share)s %% of the lag at both feeds: the pre-compensation works; it stays on",
            lag=f"{lead:.3f}",
            share=f"{AGREE_FRACTION * 100:g}",
            **fmt,
        )
    elif abs(mean) < max(3 * smean, 0.01):
        out["proposed"] = False
        out["reason"] = Msg(
            "The XY servo mismatch is the same at F%(f1)s and F%(f2)s (%(a)s ± %(sa)s and "
            "%(b)s ± %(sb)s ms) but not measurably different from zero: servo "
            "pre-compensation would change nothing; left off",
            **fmt,
        )
    else:
        out["proposed"] = True
        out["reason"] = Msg(
            "The XY servo mismatch is the same at F%(f1)s and F%(f2)s (%(a)s ± %(sa)s and "
            "%(b)s ± %(sb)s ms): the lag is proportional to speed, so leading each move by "
            "v*T removes it; servo pre-compensation is proposed",
            **fmt,
        )
    out["difference_ms"] = diff
    out["difference_sigma_ms"] = sdiff
    notes.append(out["reason"])
    return out


def _xy_heights(per_trace, notes: List[str]) -> List[Dict[str, float]]:
    xy = {}
    for d in per_trace:
        if d["plane"] == "XY" and d.get("centre"):
            xy.setdefault(round(d["centre"][2], 1), d)
    if len(xy) < 2:
        return []
    out = [
        {
            "z_mm": z,
            "squareness_um_per_m": d["squareness_um_per_m"],
            "sigma": d["uncertainty"]["squareness_um_per_m"],
            "file": d["file"],
        }
        for z, d in sorted(xy.items())
    ]
    lo, hi = out[0], out[-1]
    diff = hi["squareness_um_per_m"] - lo["squareness_um_per_m"]
    sig = math.hypot(lo["sigma"], hi["sigma"])
    if abs(diff) > 3 * sig + 2.0:
        notes.append(
            Msg(
                "XY squareness changes with height: %(a)s µm/m at Z %(za)s mm, %(b)s µm/m at Z "
                "%(zb)s mm (an axis rolls or pitches); the parameters hold one value for the whole "
                "volume, exact only near the middle.",
                a=f"{lo['squareness_um_per_m']:.1f}",
                za=f"{lo['z_mm']:g}",
                b=f"{hi['squareness_um_per_m']:.1f}",
                zb=f"{hi['z_mm']:g}",
            )
        )
    return out


def propose_campaign(
    res,
    n_traces: int,
    current: Params,
    notes: List[str],
    servo_precomp: bool,
    simulated: bool,
    firmware=None,
) -> Params:
    """``current`` updated with the campaign's jointly fitted residuals (see module doc);
    ``firmware``: the firmware's compensation during the tests (recorded in the meta)."""
    lay = res.layout
    d = current.to_dict()
    A_res = np.eye(3)
    for k, a in enumerate(AXES):
        if a in lay.axes:
            A_res[k, k] = 1 + res.value(lay.scale_row(a))
    for p in lay.planes:
        i, j = {"XY": (0, 1), "XZ": (0, 2), "YZ": (1, 2)}[p]
        A_res[i, j] = res.value(lay.unit(f"sq_{p.lower()}")) * A_res[j, j]
    split_alignment(A_res @ alignment_matrix(current), d)
    frac = current.backlash_fraction if current.has_backlash else 0.0
    for a, (lo, hi) in lay.backlash_span.items():
        table = current.backlash[a]
        pts = [
            (q, res.value(lay.backlash_row(a, q)) * 1e3 + frac * table.um_at(q))
            for q in ((lo, hi) if hi - lo >= 1.0 else (lo,))
        ]
        if min(v for _, v in pts) < -0.5 and frac > 0 and not table.is_zero:
            notes.append(
                Msg(
                    "Negative backlash on %(axis)s: the current value over-compensates.",
                    axis=a.upper(),
                )
            )
        pts = [(q, max(0.0, v)) for q, v in pts]
        d["backlash"][a] = pts[0][1] if len(pts) == 1 else [{"at_mm": q, "um": v} for q, v in pts]
    if lay.backlash_span and current.backlash_fraction == 0:
        d["backlash"]["fraction"] = 1.0
    if lay.servo:
        applied = current.servo_lag_ms if current.servo_precomp else dict.fromkeys(AXES, 0.0)
        true = {a: applied[a] + res.value(lay.lag_row(a)) * 1e3 for a in lay.lag_axes}
        base = min(true.values())
        lag = dict(current.servo_lag_ms)
        lag.update({a: v - base for a, v in true.items()})
        d["servo_lag_ms"] = lag
    d["servo_precomp"] = servo_precomp
    d["meta"] = proposal_meta(
        "ballbar campaign (%d traces)" % n_traces,
        simulated,
        "+".join(lay.planes),
        current,
        firmware,
    )
    return checked_params(d)
