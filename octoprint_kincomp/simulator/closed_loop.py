"""One calibration round on the simulator, reported like Table 2 of Keaveney et al. (2018).

Single plane (:func:`run_round`): test program -> simulate the printer with true errors ->
analyse -> compensate the program with the proposed parameters -> simulate again -> analyse
the residual. Whole volume (:func:`run_campaign_round`): plan a campaign on the machine volume
(XY R100, XZ and YZ R50, XY again at a second feed), simulate every test with the same
(zero) parameters, fit all traces jointly, apply the ONE proposed parameter set (with and
without servo pre-compensation), re-test every plane and analyse the re-test as a campaign.
Everything here is SIMULATED; the printer moves with the planner of ``firmware/planner.py``.
"""

from __future__ import annotations

import io
from typing import Dict, List, Optional, Tuple

from ..calibration.ballbar.analysis import analyse
from ..calibration.ballbar.campaign import plan_campaign
from ..calibration.ballbar.campaign_analysis import analyse_campaign
from ..calibration.ballbar.formats import parse_csv_trace
from ..calibration.ballbar.program import TestSpec, generate
from ..calibration.ballbar.timing import CONTINUOUS  # (the simulated printer has no steps)
from ..core.compensator import Options
from ..core.kinematics import changes_nothing
from ..core.params import Params
from ..engines.file_loop import compensate_stream
from .printer import Truth, paper_truth, simulate_program, volume_truth

VOLUME = (0.0, 220.0, 0.0, 220.0, 0.0, 250.0)  # mm, the paper's Ultimaker-sized volume


def compensate_text(program: str, params: Params) -> str:
    """``program`` compensated for the simulated printer (:data:`CONTINUOUS`: 4 decimals, a
    1e-6 mm dead band); its header records that (``core/marker.py``), and so do the
    simulator's traces of it."""
    src = io.StringIO(program)
    dst = io.StringIO()
    options = Options(decimals=CONTINUOUS.decimals, deadband_mm=CONTINUOUS.deadband_mm)
    compensate_stream(src, dst, params, options)
    return dst.getvalue()


def run_round(
    truth: Truth,
    spec: Optional[TestSpec] = None,
    servo_precomp: bool = False,
    current: Optional[Params] = None,
) -> Dict[str, object]:
    """Before/after analyses of one calibration round (dicts as returned by ``analyse``)."""
    spec = spec or TestSpec()
    current = current or Params()
    program = generate(spec, date="simulated", params_hash=current.hash())
    run0 = program if changes_nothing(current) else compensate_text(program, current)
    trace0 = simulate_program(run0, truth)
    before = analyse(parse_csv_trace(trace0.to_text()), current=current)
    proposed = Params.from_dict(before["parameters"])
    if servo_precomp:
        proposed = proposed.replace(servo_precomp=True)
    # the re-test's program records the parameters it runs with (as the plugin's does)
    program = generate(spec, date="simulated", params_hash=proposed.hash())
    run1 = compensate_text(program, proposed)
    trace1 = simulate_program(run1, truth)
    after = analyse(parse_csv_trace(trace1.to_text()), current=proposed)
    return {"before": before, "after": after, "params": proposed}


def _campaign_traces(steps, truth: Truth, params: Params):
    out = []
    for step in steps:
        program = generate(step.spec, date="simulated", params_hash=params.hash())
        sent = program if changes_nothing(params) else compensate_text(program, params)
        trace = simulate_program(sent, truth, step.spec, _hash(program))
        out.append((step.file.replace(".gcode", ".csv"), parse_csv_trace(trace.to_text())))
    return out


def _hash(program: str) -> str:
    from ..calibration.ballbar.program import spec_from_program

    return spec_from_program(program)[1]


def run_campaign_round(
    truth: Truth, volume=VOLUME, second_feed: Optional[float] = 3700.0
) -> Dict[str, object]:
    """Before (zero parameters) and after (the proposal applied: kinematic model only and with
    servo pre-compensation) campaign analyses over the whole volume."""
    steps = plan_campaign(volume, second_feed=second_feed, campaign_id="closed-loop")
    current = Params()
    before = analyse_campaign(_campaign_traces(steps, truth, current), current)
    proposed = Params.from_dict(before["parameters"])
    after = {}
    for precomp in (False, True):
        params = proposed.replace(servo_precomp=precomp)
        after[precomp] = analyse_campaign(_campaign_traces(steps, truth, params), params)
    return {"steps": steps, "before": before, "after": after, "params": proposed}


def campaign_tables(
    res: Dict[str, object],
) -> List[Tuple[str, List[Dict[str, object]], List[Dict[str, object]]]]:
    """Per test: (title, rows with the kinematic model only, rows with servo
    pre-compensation): the paper's Table 2 for every plane. Parametric rows are the plane's
    values in the joint fit of each campaign; the ISO metrics are those of the trace."""
    out = []
    before = res["before"]["diagnostics"]["traces"]
    kin = res["after"][False]["diagnostics"]["traces"]
    pre = res["after"][True]["diagnostics"]["traces"]
    for b, a0, a1 in zip(before, kin, pre):
        title = (
            f"{b['plane']} R{b['radius_mm']:g} F{b['feed_mm_min']:g} at {_height(b)} ({b['file']})"
        )
        joint = lambda d: dict(d, **d["joint"])  # noqa: E731
        out.append((title, table(joint(b), joint(a0)), table(joint(b), joint(a1))))
    return out


def format_campaign_table(title: str, kin, pre) -> str:
    out = [
        title,
        "",
        "| error | unit | before | after, kinematic | reduction | after, + servo precomp | "
        "reduction |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    num = lambda v: "" if v is None else f"{v:.2f}"  # noqa: E731
    pct = lambda v: "" if v is None else f"{v:.1f} %"  # noqa: E731
    for r0, r1 in zip(kin, pre):
        out.append(
            f"| {r0['error']} | {r0['unit']} | {num(r0['before'])} | {num(r0['after'])} "
            f"| {pct(r0['reduction_pct'])} | {num(r1['after'])} | "
            f"{pct(r1['reduction_pct'])} |"
        )
    return "\n".join(out) + "\n"


def _height(d) -> str:
    c = d.get("centre") or (0, 0, 0)
    other = {"XY": ("Z", c[2]), "XZ": ("Y", c[1]), "YZ": ("X", c[0])}[d["plane"]]
    return f"{other[0]}={other[1]:g} mm"


ROWS: List[Tuple[str, str, str]] = [
    ("Squareness", "squareness_um_per_m", "um/m"),
    ("Scale mismatch", "scale_mismatch_ppm", "ppm"),
    ("Servo mismatch", "servo_mismatch_ms", "ms"),
    ("Backlash +A", "backlash_um.a_plus", "um"),
    ("Backlash -A", "backlash_um.a_minus", "um"),
    ("Backlash +B", "backlash_um.b_plus", "um"),
    ("Backlash -B", "backlash_um.b_minus", "um"),
    ("Circularity CCW", "circularity_um.ccw", "um"),
    ("Circularity CW", "circularity_um.cw", "um"),
    ("Circularity bidirectional G(b)", "circularity_um.bidirectional", "um"),
    ("G(b) filtered (1 deg)", "circularity_filtered_um.bidirectional", "um"),
    ("Hysteresis H", "hysteresis_um", "um"),
]


def _get(d: dict, path: str):
    for part in path.split("."):
        if d is None:
            return None
        d = d.get(part)
    return d


# The smallest value a ballbar tells from zero, per unit (a 0.1 um resolution; over a
# 100 mm radius that is 1 um/m of squareness and 1 ppm of scale; 0.01 ms of servo lag)
RESOLUTION = {"um": 0.1, "um/m": 1.0, "ppm": 1.0, "ms": 0.01}
NOISE_SIGMAS = 3.0  # a before value within this many 1-sigma uncertainties is noise


def reduction(before: float, after: float) -> Optional[float]:
    """How much smaller ``after`` is than ``before`` (%, positive: smaller)."""
    if before is None or after is None or before == 0:
        return None
    return (1.0 - abs(after) / abs(before)) * 100.0


def noise_floor(before: dict, after: dict, key: str, unit: str) -> float:
    """The value (in ``unit``) below which the error at ``key`` cannot be told from noise:
    NOISE_SIGMAS times the two runs' combined 1-sigma uncertainty (their diagnostics'
    ``uncertainty``, where the fit gives one), at least RESOLUTION."""
    sig = [_get(d.get("uncertainty") or {}, key) for d in (before or {}, after or {})]
    combined = sum(float(s) ** 2 for s in sig if isinstance(s, (int, float))) ** 0.5
    return max(NOISE_SIGMAS * combined, RESOLUTION.get(unit, 0.0))


def servo_in_force(run: dict) -> Optional[bool]:
    """Whether servo pre-compensation was on while ``run`` (a stored run document) was
    measured; None when the run does not record its parameters."""
    params = run.get("params_before")
    if not isinstance(params, dict):
        return None
    return bool(params.get("servo_precomp"))


def table(
    before: dict, after: dict, servo_compensated: Optional[bool] = None
) -> List[Dict[str, object]]:
    """Per error of ROWS: before, after and the reduction (%); ``at_noise``: the before value
    is within the noise floor, where a reduction means nothing (``reduction_pct`` None).
    ``servo_compensated`` False (servo pre-compensation was off for the after run): the
    servo mismatch row says ``compensated: False`` and gives no reduction (what it changed
    by is not KinComp's doing)."""
    rows = []
    for label, key, unit in ROWS:
        b, a = _get(before, key), _get(after, key)
        floor = noise_floor(before, after, key, unit)
        at_noise = b is not None and a is not None and abs(b) <= floor
        compensated = not (key == "servo_mismatch_ms" and servo_compensated is False)
        rows.append(
            {
                "error": label,
                "key": key,
                "unit": unit,
                "before": b,
                "after": a,
                "noise_floor": floor,
                "at_noise": at_noise,
                "compensated": compensated,
                "reduction_pct": None if at_noise or not compensated else reduction(b, a),
            }
        )
    return rows


def format_table(rows, title: str) -> str:
    out = [title, "", "| error | unit | before | after | reduction |", "|---|---|---:|---:|---:|"]
    for r in rows:
        red = (
            "at noise level"
            if r.get("at_noise")
            else "not compensated"
            if r.get("compensated") is False
            else ("" if r["reduction_pct"] is None else f"{r['reduction_pct']:.1f} %")
        )
        b = "" if r["before"] is None else f"{r['before']:.2f}"
        a = "" if r["after"] is None else f"{r['after']:.2f}"
        out.append(f"| {r['error']} | {r['unit']} | {b} | {a} | {red} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m octoprint_kincomp closed-loop")
    ap.add_argument(
        "--noise-um", type=float, default=0.5, help="ballbar measurement noise, um (1 sigma)"
    )
    ap.add_argument(
        "--campaign",
        action="store_true",
        help="one campaign over the whole volume (XY, XZ, YZ fitted jointly)",
    )
    args = ap.parse_args(argv)
    if not 0.0 <= args.noise_um <= 50.0:
        ap.error("--noise-um must be within 0..50 um")
    if args.campaign:
        return main_campaign(args.noise_um)
    truth = paper_truth()
    truth.noise_um = args.noise_um
    for precomp in (False, True):
        res = run_round(truth, servo_precomp=precomp)
        title = (
            f"SIMULATED one-round calibration, paper's Table 1 errors, "
            f"{args.noise_um:g} um noise, XY R100 F1850 "
            + ("with servo pre-compensation" if precomp else "(kinematic model only)")
        )
        print(format_table(table(res["before"]["diagnostics"], res["after"]["diagnostics"]), title))
    return 0


def main_campaign(noise_um: float) -> int:
    truth = volume_truth(noise_um=noise_um)
    res = run_campaign_round(truth)
    print(
        f"SIMULATED one-campaign calibration over the volume {VOLUME} mm, {noise_um:g} um "
        "noise; true errors: squareness xy -3638.6, xz +800, yz -500 um/m; scale x -451.7, "
        "y +287, z +150 ppm; backlash X 37.4/4.4 um (-X/+X), Y 5.4/11.3 um (-Y/+Y), Z 8 um; "
        "servo lag X 0.62, Z 0.3 ms; planner 1500 mm/s^2, JD 0.013 mm\n"
    )
    for note in res["before"]["notes"]:
        print(f"note: {note}")
    print()
    for title, kin, pre in campaign_tables(res):
        print(format_campaign_table(f"SIMULATED {title}", kin, pre))
    return 0
