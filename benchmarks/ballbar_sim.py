"""Speed of the ballbar simulator and analysis on the planner (issue 12).

Times, best of ``--repeat``: planning a two-direction R100 XY program, sampling it at 500 Hz,
the whole simulation (planner, servo lag, play, HTM model, ballbar), the analysis of its native
trace (time-to-angle mapping with the plan, fit, ISO metrics), the same without planner
settings in the metadata (estimated from the trace), and the joint fit of a four-trace
campaign. Everything SIMULATED.

    .venv/bin/python benchmarks/ballbar_sim.py [--repeat N]
"""

import argparse

import numpy as np

from octoprint_kincomp.tools.benchmark import _time as best


def main() -> int:
    from octoprint_kincomp.calibration.ballbar.analysis import analyse
    from octoprint_kincomp.calibration.ballbar.campaign import plan_campaign
    from octoprint_kincomp.calibration.ballbar.campaign_analysis import analyse_campaign
    from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
    from octoprint_kincomp.firmware.planner import MotionSettings, plan_program
    from octoprint_kincomp.simulator.printer import simulate_program, volume_truth

    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    spec = TestSpec()
    program = generate(spec)
    truth = volume_truth(noise_um=0.5)
    plan = plan_program(program, spec.centre, truth.motion)
    ts = np.arange(0, plan.duration, 1 / 500)
    trace = simulate_program(program, truth)
    bare = simulate_program(program, truth)
    for key in MotionSettings.KEYS:
        bare.meta.pop(key, None)
    steps = plan_campaign((0, 220, 0, 220, 0, 250), second_feed=3700)
    items = [(s.name, simulate_program(generate(s.spec), truth)) for s in steps]
    rows = [
        (
            "plan R100 XY program (2774 blocks)",
            best(lambda: plan_program(program, spec.centre, truth.motion), args.repeat),
        ),
        (
            f"sample the plan at 500 Hz ({len(ts)} samples)",
            best(lambda: plan.sample(ts), args.repeat),
        ),
        (
            "simulate R100 XY, both directions, 500 Hz",
            best(lambda: simulate_program(program, truth), args.repeat),
        ),
        ("analyse its native trace", best(lambda: analyse(trace), args.repeat)),
        (
            "analyse it without planner settings (estimated)",
            best(lambda: analyse(bare), args.repeat),
        ),
        ("joint fit of a 4-trace campaign", best(lambda: analyse_campaign(items), args.repeat)),
    ]
    for name, secs in rows:
        print(f"{name:52s} {secs * 1e3:8.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
