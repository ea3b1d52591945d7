"""Command line: ``python -m octoprint_kincomp <command> ...``.

One module per verb group: :mod:`.file_commands` (``compensate``, ``params``, ``firmware``),
:mod:`.calibration_commands` (``program``, ``simulate``, ``analyze``, ``closed-loop``,
``artifact``), :mod:`.sensor_commands` (``sensor-ports``, ``sensor-capture``, ``sensor-trace``,
``sensor-virtual``); ``bench`` and ``demo-server`` hand over to the developer tools. Errors are
reported in one line on stderr with a non-zero exit status.
"""

from __future__ import annotations

import argparse
import sys
from typing import Optional, Sequence

from .calibration_commands import add_ballbar_commands
from .common import EXIT_ERROR, EXIT_OK, CliError
from .file_commands import add_file_commands
from .sensor_commands import add_sensor_commands


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m octoprint_kincomp",
        description="KinComp: kinematic error compensation of G-code "
        "(squareness, scale, backlash).",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    add_file_commands(sub)
    sub.add_parser("bench", help="speed/memory benchmark (bench --help for its options)")
    sub.add_parser("demo-server", help="OctoPrint + KinComp on the virtual printer (demo)")

    add_ballbar_commands(sub)
    add_sensor_commands(sub)
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bench"]:
        from ..tools.benchmark import main as bench_main

        return bench_main(argv[1:])
    if argv[:1] == ["demo-server"]:
        from ..tools.devserver import main as demo_main

        return demo_main(argv[1:])
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except CliError as exc:
        print(f"kincomp: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
