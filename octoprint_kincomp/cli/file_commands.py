"""File verbs of the command line: ``compensate`` (also a slicer post-processing script),
``params`` (create or check a params file) and ``firmware`` (firmware equivalents, or with
``--format`` the ready-to-paste blocks for Klipper, Marlin and RepRapFirmware)."""

from __future__ import annotations

import json
import math
import os
import sys

from ..core.atomic import Interrupted, clean_stale, signals_raise
from ..core.backlash import deadband_steps
from ..core.compensator import CompensationError, Options
from ..core.params import Params
from ..engines.file_loop import AlreadyCompensated, compensate_file
from ..firmware.export import FIRMWARES, format_equivalents, format_export
from .common import EXIT_OK, CliError, floats, load_params


def _options(args) -> Options:
    try:
        return Options(
            chord_tol_mm=args.chord_tol,
            linearise_arcs=args.linearise_arcs,
            limits=tuple(floats(args.limits, 6, "--limits")) if args.limits else None,
            policy=args.policy,
            decimals=args.decimals,
            home_mm=_home(args.home),
            steps_per_mm=_steps(args.steps_per_mm),
        )
    except ValueError as exc:
        raise CliError(str(exc)) from None


def _steps(text):
    """--steps-per-mm N or X,Y,Z: the drives' steps per mm (the reversal deadband is a
    twentieth of a step; from X,Y,Z the finer of X and Y counts); None: not given."""
    if text is None:
        return None
    vals = floats(text, 3 if "," in text else 1, "--steps-per-mm")
    if not all(math.isfinite(v) and v > 0.0 for v in vals):
        raise CliError(f"--steps-per-mm: expected positive numbers, got {text!r}")
    return vals[0] if len(vals) == 1 else deadband_steps(dict(zip("xyz", vals)))


def _home(text):
    """--home X,Y,Z: where G28 leaves each axis (mm); a '?' (or nothing): not known, the
    homed axis stays unknown until an absolute move names it."""
    if not text:
        return (None, None, None)
    parts = text.split(",")
    if len(parts) != 3:
        raise CliError(f"--home: expected 3 comma-separated numbers or '?', got {text!r}")
    out = []
    for part in parts:
        part = part.strip()
        out.append(None if part in ("", "?") else floats(part, 1, "--home")[0])
    return tuple(out)


def cmd_compensate(args) -> int:
    params = load_params(args.params)
    options = _options(args)
    target = os.path.realpath(args.output or args.input)
    new_output = bool(args.output) and not os.path.exists(target)
    if not args.dry_run:
        # leftovers of a run that was killed outright (only our own temp-file pattern)
        clean_stale(os.path.dirname(target) or ".")
    try:
        with signals_raise():
            report = compensate_file(args.input, args.output, params, options, dry_run=args.dry_run)
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else 2
        print(f"kincomp: interrupted; {args.output or args.input} was not changed", file=sys.stderr)
        return 128 + signum
    except AlreadyCompensated as exc:
        raise CliError(f"{args.input}: {exc}") from None
    except CompensationError as exc:
        raise CliError(f"{args.input}: {exc} (nothing was written)") from None
    except OSError as exc:
        raise CliError(f"{exc.filename or args.input}: {exc.strerror}") from None
    if new_output and not args.dry_run:
        _same_mode(args.input, target)
    if args.report or args.dry_run:
        rep = report.to_dict()
        rep["params_hash"] = params.hash()
        print(json.dumps(rep, indent=2))
    else:
        print(summary(args.output or args.input, report, params.hash(), args.policy))
    return EXIT_OK


def _same_mode(source: str, target: str) -> None:
    """A new output file gets the input's permission bits (the temporary file it was
    written as is private, 0600); an existing output keeps its own."""
    try:
        os.chmod(target, os.stat(source).st_mode & 0o777)
    except OSError as exc:
        raise CliError(
            f"{target}: written, but its mode could not be set: {exc.strerror}"
        ) from None


def summary(path: str, report, params_hash: str, policy: str = "clamp") -> str:
    """One line on what ``compensate`` wrote (``report``: its Report; ``policy``: the limits
    policy it ran under)."""
    line = (
        f"kincomp: wrote {path}: {report.moves_compensated} of {report.moves} moves "
        f"compensated (params {params_hash}), {report.lines_out} lines"
    )
    notes = []
    if report.untouched_unknown:
        notes.append(f"{report.untouched_unknown} sent as written (position unknown)")
    if report.malformed:
        notes.append(f"{report.malformed} malformed kept as written")
    if report.limit_hits:
        verb = "sent past" if policy == "warn" else "kept inside"
        notes.append(
            f"{report.limit_hits} coordinates {verb} the travel (worst "
            f"{report.limit_worst_um:.1f} um, {report.limit_worst_axis})"
        )
    return line + ("; " + ", ".join(notes) if notes else "")


def cmd_params(args) -> int:
    if args.init:
        sys.stdout.write(Params().to_json())
        return EXIT_OK
    if args.check:
        p = load_params(args.check)
        print(f"ok: {args.check} is valid (hash {p.hash()})")
        return EXIT_OK
    raise CliError("params: use --init or --check FILE")


# --format choices and the firmwares they print; which current values each one uses
FORMATS = {
    "klipper": ("klipper",),
    "marlin": ("marlin",),
    "rrf": ("reprapfirmware",),
    "all": FIRMWARES,
}
CURRENT = (
    ("steps_per_mm", "--steps-per-mm", ("marlin", "all")),
    ("rotation_distance", "--rotation-distance", ("klipper", "all")),
)


def _positive(text: str, flag: str):
    vals = floats(text, 3, flag)
    if not all(math.isfinite(v) and v > 0.0 for v in vals):
        raise CliError(f"{flag}: expected 3 positive numbers (X,Y,Z), got {text!r}")
    return vals


def cmd_firmware(args) -> int:
    current = {}
    for name, flag, formats in CURRENT:
        text = getattr(args, name)
        if text is None:
            continue
        if args.format not in formats:
            raise CliError(f"{flag} needs --format {' or '.join(formats)}")
        current[name] = _positive(text, flag)
    params = load_params(args.params)
    if args.format is None:
        sys.stdout.write(format_equivalents(params))
    else:
        sys.stdout.write(format_export(params, FORMATS[args.format], **current))
    return EXIT_OK


def add_file_commands(sub) -> None:
    c = sub.add_parser(
        "compensate",
        help="compensate a G-code file (edits it in place without -o, like slicer scripts)",
    )
    c.add_argument("input", help="G-code file")
    c.add_argument("-o", "--output", help="output file (default: edit INPUT in place)")
    c.add_argument("--params", help="params JSON file (see: params --init)")
    c.add_argument(
        "--limits",
        metavar="X0,X1,Y0,Y1,Z0,Z1",
        help="machine limits in mm; compensated points outside are handled by --policy",
    )
    c.add_argument(
        "--policy",
        choices=("warn", "clamp", "error"),
        default="clamp",
        help="what to do when compensation pushes a point outside --limits (default "
        "clamp: keep it inside and report the shortfall)",
    )
    c.add_argument(
        "--chord-tol",
        type=float,
        default=0.01,
        metavar="MM",
        help="how far a compensated arc may deviate from the true arc (default 0.01 mm)",
    )
    c.add_argument(
        "--linearise-arcs",
        action="store_true",
        help="write G2/G3 as G1 segments (firmware without arc support)",
    )
    c.add_argument("--decimals", type=int, default=3, help="X/Y/Z decimals in mm (default 3)")
    c.add_argument(
        "--home",
        metavar="X,Y,Z",
        help="position after G28 in mm, '?' for an axis whose home is not known "
        "(default: none known; homed axes are then compensated from their "
        "first absolute move on)",
    )
    c.add_argument(
        "--steps-per-mm",
        metavar="N|X,Y,Z",
        help="the printer's steps per mm (M92): the reversal deadband is a twentieth of a "
        "step (default 80 steps/mm: 0.625 um)",
    )
    c.add_argument("--report", action="store_true", help="print the report as JSON")
    c.add_argument("--dry-run", action="store_true", help="only print the report, write nothing")
    c.set_defaults(func=cmd_compensate)

    p = sub.add_parser("params", help="create or check a params file")
    p.add_argument("--init", action="store_true", help="print a default (all-zero) params file")
    p.add_argument("--check", metavar="FILE", help="validate a params file")
    p.set_defaults(func=cmd_params)

    f = sub.add_parser(
        "firmware",
        help="print firmware equivalents (M852, M425, SET_SKEW, ...); with --format "
        "the ready-to-paste blocks",
    )
    f.add_argument("--params", required=True)
    f.add_argument(
        "--format",
        choices=tuple(FORMATS),
        help="ready-to-paste blocks: Klipper printer.cfg and commands, Marlin "
        "commands with M500, RepRapFirmware config.g (default: one line per "
        "command for every firmware)",
    )
    f.add_argument(
        "--steps-per-mm",
        metavar="X,Y,Z",
        help="the printer's current steps/mm (Marlin): print the new M92 values",
    )
    f.add_argument(
        "--rotation-distance",
        metavar="X,Y,Z",
        help="the current rotation_distance in mm (Klipper): print the new values",
    )
    f.set_defaults(func=cmd_firmware)
