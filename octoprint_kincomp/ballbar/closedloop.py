"""One calibration round on the simulator, reported like Table 2 of Keaveney et al. (2018).

test program -> simulate the printer with true errors -> analyse -> compensate the program with
the proposed parameters -> simulate again -> analyse the residual. Everything here is SIMULATED.
"""

from __future__ import annotations

import io
from typing import Dict, List, Optional, Tuple

from ..core.compensator import Options
from ..core.kinematics import changes_nothing
from ..core.params import Params
from ..engines.files import compensate_stream
from .analysis import analyse
from .formats import parse_csv_trace
from .program import TestSpec, generate
from .simulator import Truth, paper_truth, simulate_program


def compensate_text(program: str, params: Params) -> str:
    src = io.StringIO(program)
    dst = io.StringIO()
    compensate_stream(src, dst, params, Options(decimals=4))
    return dst.getvalue()


def run_round(truth: Truth, spec: Optional[TestSpec] = None, servo_precomp: bool = False,
              current: Optional[Params] = None) -> Dict[str, object]:
    """Before/after analyses of one calibration round (dicts as returned by ``analyse``)."""
    spec = spec or TestSpec()
    current = current or Params()
    program = generate(spec, date="simulated", params_hash=current.hash())
    run0 = program if changes_nothing(current) else compensate_text(program, current)
    before = analyse(parse_csv_trace(simulate_program(run0, truth).to_text()), current=current)
    proposed = Params.from_dict(before["parameters"])
    if servo_precomp:
        proposed = proposed.replace(servo_precomp=True)
    run1 = compensate_text(program, proposed)
    after = analyse(parse_csv_trace(simulate_program(run1, truth).to_text()), current=proposed)
    return {"before": before, "after": after, "params": proposed}


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
    ("Hysteresis H", "hysteresis_um", "um"),
]


def _get(d: dict, path: str):
    for part in path.split("."):
        if d is None:
            return None
        d = d.get(part)
    return d


def reduction(before: float, after: float) -> Optional[float]:
    if before is None or after is None or before == 0:
        return None
    return (1.0 - abs(after) / abs(before)) * 100.0


def table(before: dict, after: dict) -> List[Dict[str, object]]:
    rows = []
    for label, key, unit in ROWS:
        b, a = _get(before, key), _get(after, key)
        rows.append({"error": label, "key": key, "unit": unit, "before": b, "after": a,
                     "reduction_pct": reduction(b, a)})
    return rows


def format_table(rows, title: str) -> str:
    out = [title, "",
           "| error | unit | before | after | reduction |", "|---|---|---:|---:|---:|"]
    for r in rows:
        red = "" if r["reduction_pct"] is None else f"{r['reduction_pct']:.1f} %"
        b = "" if r["before"] is None else f"{r['before']:.2f}"
        a = "" if r["after"] is None else f"{r['after']:.2f}"
        out.append(f"| {r['error']} | {r['unit']} | {b} | {a} | {red} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m octoprint_kincomp closed-loop")
    ap.add_argument("--noise-um", type=float, default=0.5,
                    help="ballbar measurement noise, um (1 sigma)")
    args = ap.parse_args(argv)
    if not 0.0 <= args.noise_um <= 50.0:
        ap.error("--noise-um must be within 0..50 um")
    truth = paper_truth()
    truth.noise_um = args.noise_um
    for precomp in (False, True):
        res = run_round(truth, servo_precomp=precomp)
        title = (f"SIMULATED one-round calibration, paper's Table 1 errors, "
                 f"{args.noise_um:g} um noise, XY R100 F1850 "
                 + ("with servo pre-compensation" if precomp else "(kinematic model only)"))
        print(format_table(table(res["before"]["diagnostics"], res["after"]["diagnostics"]),
                           title))
    return 0
