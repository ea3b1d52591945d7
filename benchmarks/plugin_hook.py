"""Per-line cost of KinComp's whole OctoPrint queuing hook (``KinCompPlugin.queuing_hook``).

``python -m octoprint_kincomp bench`` measures the hook's core (``Compensator.process`` and
``QueueCompensator.handle``) without OctoPrint. This script measures the plugin's hook
function itself, as OctoPrint's comm layer calls it for the lines of a print (tags
``source:file`` and ``fileline:N``), on a plugin instance with a real OctoPrint settings
object and mocks for the printer, event bus and file manager
(tests/support/mocked_plugin.py), compensation on with the benchmark's parameters
(squareness + scale + position-dependent backlash) and the bed as limits. Prints p50/p99 in
us over the G1 X/Y lines and the G2/G3 lines of a 200,000-line slicer-like stream with 20 % arcs
(the benchmark's arc file), the best of ``--repeat`` passes (as the bench's figures are).
    .venv/bin/python benchmarks/plugin_hook.py [--lines N] [--python]

``--python`` runs it on the pure-Python paths (no compiled kernel).
"""

import argparse
import os
import sys
import tempfile
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lines", type=int, default=200_000)
    ap.add_argument("--python", action="store_true", help="without the compiled kernel")
    ap.add_argument("--repeat", type=int, default=5, help="passes; each figure is the best")
    args = ap.parse_args()
    if args.python:
        os.environ["KINCOMP_KERNEL"] = "0"

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from octoprint_kincomp.engines import select
    from octoprint_kincomp.service.printing.queue import FILE_TAG
    from octoprint_kincomp.tools.benchmark import BENCH_PARAMS, generate, keep_best, latency_figures
    from tests.support.mocked_plugin import mocked_plugin

    tmp = tempfile.mkdtemp(prefix="kincomp-hook-")
    p = mocked_plugin(tmp, bed_mm=250.0)
    p.on_settings_save({"enabled": True, "params": BENCH_PARAMS})

    src = os.path.join(tmp, "stream.gcode")
    generate(src, args.lines, arc_fraction=0.2)
    with open(src) as f:
        lines = [line.rstrip("\n") for line in f]
    tags = [{FILE_TAG, "fileline:%d" % (i + 1)} for i in range(len(lines))]
    comm = object()
    hook = p.queuing_hook
    clock = time.perf_counter_ns
    best = {}
    for _ in range(args.repeat):  # (the stream starts with G28: each pass starts afresh)
        samples = {"G1": [], "G2": []}
        for line, t in zip(lines, tags):
            t0 = clock()
            hook(comm, "queuing", line, None, None, None, t)
            dt = clock() - t0
            if line.startswith("G1 X"):
                samples["G1"].append(dt)
            elif line.startswith(("G2 ", "G3 ")):
                samples["G2"].append(dt)
        keep_best(best, {kind: latency_figures(got) for kind, got in samples.items()})
    rep = p.queue.comp.report
    print(
        f"engine: {select.engine()}; "
        f"{rep.moves_compensated} moves compensated, {rep.takeup_moves} take-ups, "
        f"{rep.arcs_kept} arcs kept, {rep.arcs_split} split"
    )
    for kind, f in best.items():
        print(
            f"KinCompPlugin.queuing_hook, {kind} line: p50 {f['p50_us']:.2f} us  "
            f"p99 {f['p99_us']:.2f} us ({f['lines']} lines; best of {args.repeat} passes)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
