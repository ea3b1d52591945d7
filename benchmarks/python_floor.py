"""The floor of any pure-Python per-line compensator, against issue 24's "reference path
(no compiler) at most 12x a plain copy".

Times, on the benchmark's generated file (``tools/benchmark.generate``, no arcs) and against
its plain line copy (best of ``--repeat`` alternating runs, as ``bench`` times them), a loop
that does strictly less than any compensator must: for each ``G0``/``G1`` line, split the
words, parse X/Y/Z, apply the benchmark model's affine inverse, write X/Y/Z with
``"%.3f"`` and copy the other words; every other line copied. No backlash, no limits, no
trimmed zeros, no E or F handling, no modal state, no arcs. Whatever ratio it prints is a
lower bound for a pure-Python path with the reference path's semantics. The reference path
itself: ``python -m octoprint_kincomp bench --engine python --lines N``.

    .venv/bin/python benchmarks/python_floor.py [--lines N] [--repeat N]
"""

import argparse
import os
import sys
import tempfile


def floor_copy(src: str, dst: str, rows) -> None:
    """The least per-line work of a compensator (see the module's docstring)."""
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = rows
    x = y = z = 0.0
    with open(src) as f, open(dst, "w") as out:
        write = out.write
        for line in f:
            if line[:3] not in ("G1 ", "G0 "):
                write(line)
                continue
            words = line.split()
            rest = []
            for w in words[1:]:
                c = w[0]
                if c == "X":
                    x = float(w[1:])
                elif c == "Y":
                    y = float(w[1:])
                elif c == "Z":
                    z = float(w[1:])
                else:
                    rest.append(w)
            write(
                "%s X%.3f Y%.3f Z%.3f %s\n"
                % (
                    words[0],
                    a0 * x + a1 * y + a2 * z,
                    a3 * x + a4 * y + a5 * z,
                    a6 * x + a7 * y + a8 * z,
                    " ".join(rest),
                )
            )


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lines", type=int, default=500_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from octoprint_kincomp.core.kinematics import KinematicModel
    from octoprint_kincomp.core.params import Params
    from octoprint_kincomp.tools.benchmark import BENCH_PARAMS, _paired, generate, plain_copy

    params = Params.from_dict(BENCH_PARAMS)
    rows = KinematicModel(params).inverse_rows
    with tempfile.TemporaryDirectory(prefix="kincomp-floor-") as tmp:
        src, dst = os.path.join(tmp, "in.gcode"), os.path.join(tmp, "out.gcode")
        n = generate(src, args.lines)
        t_copy, t_floor = _paired(
            lambda: plain_copy(src, dst), lambda: floor_copy(src, dst, rows), args.repeat
        )
    print(f"{n:,} lines: plain copy {t_copy:.3f} s, floor loop {t_floor:.3f} s")
    print(f"floor of a pure-Python path: {t_floor / t_copy:.1f}x a plain copy (target 12x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
