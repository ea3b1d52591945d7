"""Ballbar commands of the CLI: ``program`` (one test or a whole campaign), ``simulate``,
``analyze`` (one trace, or all traces of a campaign jointly), ``closed-loop``, ``artifact``."""

from __future__ import annotations

import json

from ..core.params import Params, ParamsError
from .common import EXIT_OK, EXIT_UNTRUSTED, CliError, floats, load_params, read_text, write_text


def _limits(args):
    """The printer's motion limits from ``--limits FILE`` (M503 answer, printer.cfg),
    ``--max-feed`` and ``--max-accel`` (the lower of each applies); None when none given."""
    from ..firmware.motion_limits import LimitsError, limits_from_sequence, parse_limits

    known = None
    if args.limits:
        try:
            known = parse_limits(read_text(args.limits), args.firmware)
        except LimitsError as exc:
            raise CliError(f"{args.limits}: {exc}") from None
    if args.max_feed or args.max_accel:
        given = limits_from_sequence(
            floats(args.max_feed, 3, "--max-feed") if args.max_feed else None,
            floats(args.max_accel, 3, "--max-accel") if args.max_accel else None,
            "command line",
        )
        known = given.combined(known)
    return known


def _firmware(args, limits):
    """The firmware the program is for (``marlin``, ``klipper``, ``reprapfirmware``; None:
    not known): ``--firmware``, else what ``--limits`` shows (Klipper's printer.cfg...)."""
    from ..firmware.motion_limits import firmware_kind

    return firmware_kind(args.firmware) or (limits.firmware if limits is not None else None)


def _planned_for(args, limits):
    """(pause command, planner settings as metadata or None) of a program for the printer
    ``--limits`` and ``--firmware`` describe (see ``program.pause_for`` and
    ``planner.settings_from_limits``)."""
    from ..calibration.ballbar.program import pause_for
    from ..firmware.planner import settings_from_limits

    firmware = _firmware(args, limits)
    settings = settings_from_limits(limits, firmware)
    return pause_for(firmware), (settings.metadata() if settings is not None else None)


def _feed(args, plane: str, radius: float, overshoot: float, limits):
    """The feed (mm/min) the test runs at and the header lines saying why; refuses (CliError)
    a feed no axis can reach or a vertical test without a known Z max feed."""
    import sys

    from ..firmware.motion_limits import LimitsError, circle_feed, describe, require_known

    try:
        choice = circle_feed(plane, radius, args.feed, limits, overshoot_deg=overshoot)
        require_known(choice, plane)
    except LimitsError as exc:
        raise CliError(str(exc)) from None
    notes = describe(choice)
    if choice.lowered:  # said where it is seen; unknown X/Y limits only in the header
        print(f"note: {notes[0]}", file=sys.stderr)
    return choice.feed_mm_min, notes


def cmd_program(args) -> int:
    from ..calibration.ballbar.program import ProgramError, TestSpec, check_bounds, generate

    if args.campaign:
        return _program_campaign(args)
    if not args.centre:
        raise CliError("--centre is required (or --campaign with --volume)")
    centre = floats(args.centre, 3, "--centre")
    limits = _limits(args)
    params_hash = load_params(args.params).hash() if args.params else "none"
    pause, motion = _planned_for(args, limits)
    try:
        spec = TestSpec(
            plane=args.plane,
            centre=tuple(centre),
            radius_mm=args.radius,
            feed_mm_min=args.feed,
            requested_feed_mm_min=args.feed,
            feed_in_mm=args.feed_in,
            overshoot_deg=args.overshoot,
            capture_deg=args.capture,
            start_deg=args.start,
            mount_pause=args.mount_pause,
            pause_command=pause,
            motion=motion,
            printer=args.printer,
        )
        volume = floats(args.volume, 6, "--volume") if args.volume else None
        check_bounds(spec, volume)
        spec.feed_mm_min, notes = _feed(
            args, spec.plane, spec.radius_mm, spec.overshoot_deg, limits
        )
        text = generate(spec, volume=volume, params_hash=params_hash, feed_notes=notes)
    except ProgramError as exc:
        raise CliError(str(exc)) from None
    write_text(args.output, text)
    return 0


def _program_campaign(args) -> int:
    import os

    from ..calibration.ballbar.campaign import MANIFEST_NAME, plan_campaign, write_campaign
    from ..calibration.ballbar.program import ProgramError

    if not args.volume:
        raise CliError("--campaign needs the machine volume: --volume X0,X1,Y0,Y1,Z0,Z1")
    if not args.output:
        raise CliError("--campaign needs -o DIRECTORY for its programs and manifest")
    volume = floats(args.volume, 6, "--volume")
    params_hash = load_params(args.params).hash() if args.params else "none"
    limits = _limits(args)
    try:
        steps = plan_campaign(
            volume,
            radius_xy=args.radius,
            radius_vertical=args.radius_vertical,
            feed=args.feed,
            second_height=args.second_height,
            second_feed=args.second_feed,
            limits=limits,
            require_limits=True,
            printer=args.printer,
            firmware=_firmware(args, limits),
        )
        write_campaign(steps, args.output, volume, params_hash=params_hash)
    except ProgramError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"{args.output}: {exc.strerror}") from None
    for i, step in enumerate(steps, 1):
        s = step.spec
        print(
            f"{i}. {os.path.join(args.output, step.file)}: {s.plane} R{s.radius_mm:g} "
            f"F{s.feed_mm_min:g} about {','.join(f'{v:g}' for v in s.centre)}"
        )
    print(f"manifest: {os.path.join(args.output, MANIFEST_NAME)}")
    return 0


def cmd_simulate(args) -> int:
    from ..calibration.ballbar.program import ProgramError
    from ..simulator.printer import Truth, simulate_angle_trace, simulate_program

    try:
        truth = Truth.load(args.truth)
    except (ParamsError, OSError, KeyError, TypeError, ValueError) as exc:
        raise CliError(f"invalid truth file {args.truth}: {exc}") from None
    if args.noise_um is not None:
        truth.noise_um = args.noise_um
    if args.rate is not None:
        truth.sample_rate_hz = args.rate
    text = read_text(args.program)
    try:
        if args.angle:
            comp = load_params(args.compensated_with) if args.compensated_with else None
            trace = simulate_angle_trace(text, truth, compensated_with=comp)
        else:
            trace = simulate_program(text, truth)
    except ProgramError as exc:
        raise CliError(f"{args.program}: {exc}") from None
    write_text(args.output, trace.to_text())
    return 0


def _read_trace(path: str):
    from ..calibration.ballbar.formats import TraceError, load_any

    try:
        with open(path, "rb") as f:
            data = f.read()
        return load_any(data, path)
    except TraceError as exc:
        raise CliError(f"{path}: {exc}") from None
    except OSError as exc:
        raise CliError(f"{path}: {exc.strerror}") from None


def _sent_with(args):
    """--decimals / --steps-per-mm: how ``compensate`` wrote the re-test's program (None:
    the trace's record, else the compensator's defaults)."""
    if args.steps_per_mm is None and args.decimals is None:
        return None
    from ..calibration.ballbar.timing import SentWith
    from ..core.compensator import Options
    from .file_commands import _steps

    try:
        opts = Options(decimals=args.decimals or 3, steps_per_mm=_steps(args.steps_per_mm))
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return SentWith.of_options(opts)


def _firmware_compensation(args):
    """--firmware-compensation: the firmware's compensation state (None: not given)."""
    import os

    from ..firmware.compensation import FirmwareCompensation

    if args.firmware_compensation is None:
        return None
    text = args.firmware_compensation
    if os.path.isfile(text):
        with open(text, encoding="utf-8", errors="replace") as f:
            text = f.read()
    return FirmwareCompensation.from_text(text)


def _origin(args, traces):
    """--firmware-compensation (the M503 reply or the commands in force, text or a file)
    and --program (the program that was printed: a trace with its hash is tied to it)."""

    from ..calibration.ballbar.analysis import Provenance
    from ..calibration.ballbar.program import ProgramError, spec_from_program

    fw = _firmware_compensation(args)
    confirmed = None
    if args.program:
        try:
            with open(args.program, encoding="utf-8") as f:
                _, printed = spec_from_program(f.read())
        except (OSError, ProgramError) as exc:
            raise CliError(f"{args.program}: {exc}") from None
        hashes = {getattr(t, "meta", {}).get("program_hash", "").strip() for t in traces}
        if hashes != {printed}:
            raise CliError(
                f"{args.program}: its program_hash {printed} is not the trace's "
                f"({', '.join(sorted(hashes)) or '-'}): not the program that was printed"
            )
        confirmed = "program"
    return Provenance(firmware=fw, confirmed=confirmed)


def cmd_analyze(args) -> int:
    import os

    from ..calibration.ballbar.analysis import analyse
    from ..calibration.ballbar.formats import TraceError

    current = load_params(args.current) if args.current else Params()
    known = out_of_plane_option(args.out_of_plane)
    sent = _sent_with(args)
    if len(args.trace) == 1 and not args.manifest:
        path = args.trace[0]
        trace = _read_trace(path)
        try:
            result = analyse(
                trace,
                current=current,
                mask_deg=args.mask_deg,
                calibrated=args.calibrated_bar,
                cyclic_pitch=args.cyclic_pitch,
                known_squareness_um_per_m=known,
                known_sources=dict.fromkeys(known, "--out-of-plane"),
                sent=sent,
                origin=_origin(args, [trace]),
            )
        except TraceError as exc:
            raise CliError(f"{path}: {exc}") from None
    else:
        if known:
            raise CliError(
                "--out-of-plane is for one trace: a campaign's joint fit measures the "
                "squareness of every plane itself"
            )
        from ..calibration.ballbar.campaign import load_manifest
        from ..calibration.ballbar.campaign_analysis import analyse_campaign

        items = [(os.path.basename(p), _read_trace(p)) for p in args.trace]
        try:
            manifest = load_manifest(args.manifest) if args.manifest else None
            result = analyse_campaign(
                items,
                current=current,
                mask_deg=args.mask_deg,
                calibrated=args.calibrated_bar,
                cyclic_pitch=args.cyclic_pitch,
                manifest=manifest,
                sent=sent,
                firmware=_firmware_compensation(args),
            )
        except TraceError as exc:  # CampaignError names the file itself
            raise CliError(str(exc)) from None
    if args.params_out:
        write_text(args.params_out, json.dumps(result["parameters"], indent=2))
    if args.json:
        print(json.dumps(for_the_terminal(result), indent=2, default=float))
    else:
        print(format_diagnostics(result))
    if result.get("trusted", True):
        return EXIT_OK
    import sys

    errors = [f for f in result["findings"] if f["severity"] == "error"]
    print(
        f"kincomp: untrusted result ({len(errors)} error finding"
        f"{'' if len(errors) == 1 else 's'}: {errors[0]['code']}): do not apply it as it is "
        f"(exit status {EXIT_UNTRUSTED})",
        file=sys.stderr,
    )
    return EXIT_UNTRUSTED


def out_of_plane_option(items) -> dict:
    """``--out-of-plane KEY=UM_PER_M`` (repeatable, or comma-separated: ``xy=-3638.6,xz=800``)
    -> {key: um/m}; a CliError names what is wrong."""
    out = {}
    for item in items or ():
        for part in item.split(","):
            key, sep, value = part.strip().partition("=")
            key = key.strip().lower()
            if not sep or key not in ("xy", "xz", "yz"):
                raise CliError(
                    f"--out-of-plane: expected KEY=UM_PER_M with KEY xy, xz or yz, got {part!r}"
                )
            try:
                v = float(value)
            except ValueError:
                v = float("nan")
            if v != v or v in (float("inf"), float("-inf")):
                raise CliError(f"--out-of-plane: {key} must be a finite number (um/m)")
            out[key] = v
    return out


def _pm(value, sigma, decimals: int = 2) -> str:
    return f"{value:10.{decimals}f}" + ("" if sigma is None else f" +- {sigma:.{decimals}f}")


def diagnostic_lines(d) -> list:
    """The fitted values of one test's diagnostics, with their 1-sigma uncertainties."""
    u = d.get("uncertainty") or {}
    lines = [
        f"plane {d.get('plane')}, radius {d.get('radius_mm')} mm, "
        f"feed {d.get('feed_mm_min')} mm/min"
    ]
    for key, unit in (
        ("squareness_um_per_m", "um/m"),
        ("scale_mismatch_ppm", "ppm"),
        ("servo_mismatch_ms", "ms"),
        ("mean_scale_ppm", "ppm"),
        ("bar_drift_um_per_min", "um/min"),
    ):
        if d.get(key) is not None:
            lines.append(f"{key:22s} {_pm(d[key], u.get(key), 3 if unit == 'ms' else 2)} {unit}")
    for key in ("backlash_um", "centre_offset_um", "circularity_um", "straightness_um"):
        if isinstance(d.get(key), dict):
            sub = u.get(key) if isinstance(u.get(key), dict) else {}
            lines.append(
                f"{key:22s} "
                + "  ".join(
                    f"{k} {v:.2f}" + (f" +- {sub[k]:.2f}" if sub.get(k) is not None else "")
                    for k, v in d[key].items()
                )
            )
    if d.get("hysteresis_um") is not None:
        lines.append(f"{'hysteresis_um':22s} {d['hysteresis_um']:10.2f}")
    return lines


def format_diagnostics(result) -> str:
    d = result["diagnostics"]
    lines = []
    if d.get("simulated"):
        lines.append("SIMULATED data")
    if "campaign" in d:
        lines += format_campaign(d)
    else:
        lines += diagnostic_lines(d)
        if d.get("uncertainty"):
            lines.append("(+- : 1-sigma uncertainty from the fit's covariance and the noise)")
    lines.append("")
    lines.append("firmware equivalents:")
    for fam in ("marlin", "klipper", "reprapfirmware"):
        lines += ["  " + x for x in result["firmware"][fam]]
    findings = result.get("findings")
    if findings is None:
        findings = [{"severity": "info", "message": n, "advice": ""} for n in result["notes"]]
    if findings:
        lines.append("")
        lines.append(
            "findings (worst first): "
            + ("trusted" if result.get("trusted", True) else "NOT TRUSTED: an error below")
        )
    for f in findings:
        lines.append(f"{f['severity']}: {f['message']}")
        if f.get("advice"):
            lines.append(f"    advice: {f['advice']}")
    need = result.get("needs_confirmation")
    if need:
        stated = need.get("stated") or {}
        lines.append("")
        lines.append(
            "to confirm before applying: "
            + ", ".join(f"{k} {stated.get(k)}" for k in need.get("confirm", []))
        )
    return "\n".join(lines)


def format_campaign(d) -> list:
    """Text of a campaign's diagnostics: each test, then the joint values."""
    lines = []
    for tr in d["traces"]:
        lines.append(f"--- {tr['file']}")
        lines += diagnostic_lines(tr)
    c = d["campaign"]
    u = c["uncertainty"]
    lines.append("")
    lines.append(
        f"--- campaign: {len(d['traces'])} traces, planes {'+'.join(c['planes'])}, "
        "fitted jointly (+- : 1-sigma)"
    )
    for key, unit in (
        ("squareness_um_per_m", "um/m"),
        ("scale_ppm", "ppm"),
        ("scale_mismatch_ppm", "ppm"),
        ("servo_lag_ms", "ms"),
        ("servo_mismatch_ms", "ms"),
    ):
        if isinstance(c.get(key), dict):
            n = 3 if unit == "ms" else 2
            lines.append(
                f"{key:22s} "
                + "  ".join(f"{k} {v:.{n}f} +- {u[key][k]:.{n}f}" for k, v in c[key].items())
                + f" {unit}"
            )
    for axis, v in c.get("backlash_um", {}).items():
        if isinstance(v, list):
            text = "  ".join(
                f"at {p['at_mm']:g} mm {p['um']:.2f} +- {s['um']:.2f}"
                for p, s in zip(v, u["backlash_um"][axis])
            )
        else:
            text = f"{v:.2f} +- {u['backlash_um'][axis]:.2f}"
        lines.append(f"{'backlash_um.' + axis:22s} {text} um")
    lines.append(f"scale: {c['scale_rule']}")
    lines.append(f"servo: {c['servo_rule']}")
    lines.append(
        "servo pre-compensation: "
        + ("proposed" if c["servo_precomp"]["proposed"] else "not proposed")
    )
    return lines


def for_the_terminal(result: dict) -> dict:
    """A result document as ``--json`` prints it: without the translatable copy of the
    findings (``findings_i18n``, the web UI's)."""
    return {k: v for k, v in result.items() if k != "findings_i18n"}


def cmd_artifact(args) -> int:
    from ..calibration.artifact.diagonals import ArtifactError, analyse_diagonals

    if getattr(args, "artifact_command", None) == "program":
        return cmd_artifact_program(args)
    if getattr(args, "artifact_command", None) == "analyze":
        return cmd_artifact_analyze(args)
    if not args.diagonals:
        raise CliError(
            "artifact: give --diagonals AC,BD,AD (a printed square), or use "
            "'artifact program' / 'artifact analyze' (KinComp's own artifact)"
        )
    current = load_params(args.current) if args.current else Params()
    ac, bd, ad = floats(args.diagonals, 3, "--diagonals")
    lengths = {}
    for spec in args.length or []:
        try:
            axis, nominal, measured = spec.split(":")
            lengths.setdefault(axis.lower(), []).append((float(nominal), float(measured)))
        except ValueError:
            raise CliError(f"--length expects AXIS:NOMINAL:MEASURED, got {spec!r}") from None
    try:
        result = analyse_diagonals(args.plane, ac, bd, ad, lengths, current)
    except ArtifactError as exc:
        raise CliError(str(exc)) from None
    print(json.dumps(for_the_terminal(result), indent=2))
    return 0


def cmd_artifact_program(args) -> int:
    from ..calibration.artifact.program import ArtifactProgramError, ArtifactSpec, generate
    from ..calibration.artifact.stl import binary_stl, solids

    volume = tuple(floats(args.volume, 6, "--volume"))
    planes = tuple(p.strip().upper() for p in args.planes.split(",") if p.strip())
    hotend, bed = floats(args.temps, 2, "--temps")
    try:
        spec = ArtifactSpec(
            volume=volume,
            planes=planes,
            nozzle_mm=args.nozzle,
            hotend_c=hotend,
            bed_c=bed,
            first_layer_mm=args.first_layer,
            layer_mm=args.layer,
            line_width_mm=args.line_width,
            max_span_mm=args.caliper,
            tower_span_mm=args.tower_span,
            mode="quick" if args.quick else "full",
        )
        text = generate(spec)
        stl = binary_stl(solids(spec)) if args.stl else None
    except ArtifactProgramError as exc:
        raise CliError(str(exc)) from None
    write_text(args.output, text)
    if stl is not None:
        try:
            with open(args.stl, "wb") as f:
                f.write(stl)
        except OSError as exc:
            raise CliError(f"{args.stl}: {exc.strerror}") from None
    return 0


def cmd_artifact_analyze(args) -> int:
    from ..calibration.artifact.fit import ArtifactFitError, analyse_artifact, parse_readings
    from ..calibration.artifact.program import (
        ArtifactProgramError,
        read_measurements,
        read_program_info,
    )
    from ..calibration.ballbar.formats import TraceError

    current = load_params(args.artifact_current) if args.artifact_current else Params()
    program = read_text(args.program)
    try:
        measurements = read_measurements(program)
    except ArtifactProgramError as exc:
        raise CliError(f"{args.program}: {exc}") from None
    try:
        readings = parse_readings(read_text(args.measurements))
        result = analyse_artifact(
            measurements, readings, current=current, info=read_program_info(program)
        )
    except ArtifactFitError as exc:
        raise CliError(f"{args.measurements}: {exc}") from None
    except TraceError as exc:  # the proposal is out of range
        raise CliError(str(exc)) from None
    if args.params_out:
        write_text(args.params_out, json.dumps(result["parameters"], indent=2))
    if args.json:
        print(json.dumps(for_the_terminal(result), indent=2, default=float))
    else:
        print(format_artifact(result))
    return 0


def format_artifact(result) -> str:
    """Text of an artifact analysis: values +- 1 sigma, then the findings."""
    d = result["diagnostics"]
    u = d["uncertainty"]
    lines = []
    if d.get("simulated"):
        lines.append("SIMULATED data")
    verdict = result.get("verdict") or {}
    reason = verdict.get("reason")
    reason = reason.get("text") if isinstance(reason, dict) else reason
    lines.append(
        "verdict: "
        + str(verdict.get("decision", "")).replace("_", " ")
        + (f": {reason}" if reason else "")
    )
    for key, unit, n in (
        ("squareness_um_per_m", "um/m", 1),
        ("scale_mismatch_ppm", "ppm", 1),
        ("line_width_mm", "mm", 3),
    ):
        parts = [
            f"{k} {v:.{n}f} +- {u[key][k]:.{n}f}" if v is not None else f"{k} -"
            for k, v in d[key].items()
        ]
        lines.append(f"{key:22s} " + "  ".join(parts) + f" {unit}")
    f = d["fit"]
    lines.append(
        f"fit: {f['readings_used']} of {f['readings']} readings, rms {f['rms_um']:.1f} "
        f"um, sigma per reading {f['sigma_reading_um']:.1f} um (from "
        f"{f['sigma_from']}); +- : 1 sigma"
    )
    lines.append("trusted" if result["trusted"] else "NOT trusted (see the errors below)")
    for item in result["findings"]:
        lines.append(
            f"{item['severity']}: {item['message']}"
            + (f" {item['advice']}" if item["advice"] else "")
        )
    lines.append("")
    lines.append("firmware equivalents:")
    for fam in ("marlin", "klipper", "reprapfirmware"):
        lines += ["  " + x for x in result["firmware"][fam]]
    return "\n".join(lines)


def cmd_closed_loop(args) -> int:
    from ..simulator.closed_loop import main

    return main(["--noise-um", str(args.noise_um)] + (["--campaign"] if args.campaign else []))


def add_ballbar_commands(sub) -> None:
    """The calibration verbs: program, simulate, analyze, closed-loop, artifact."""
    _add_program(sub)
    _add_simulate(sub)
    _add_analyze(sub)
    _add_closed_loop(sub)
    _add_artifact(sub)


def _add_program(sub) -> None:
    p = sub.add_parser("program", help="generate an ISO 230-4 ballbar test program")
    p.add_argument("--plane", default="XY", choices=("XY", "XZ", "YZ"))
    p.add_argument("--centre", metavar="X,Y,Z", help="pivot position, mm")
    p.add_argument(
        "--radius",
        type=float,
        default=100.0,
        help="mm (default 100; with --campaign: the XY tests)",
    )
    p.add_argument("--feed", type=float, default=1850.0, help="mm/min (default 1850)")
    p.add_argument(
        "--max-feed",
        metavar="FX,FY,FZ",
        help="axis max feeds in mm/min: the feed is capped at the slowest",
    )
    p.add_argument(
        "--max-accel",
        metavar="AX,AY,AZ",
        help="axis max accelerations in mm/s^2: the feed is lowered so that the "
        "circle's acceleration stays within them",
    )
    p.add_argument(
        "--limits",
        metavar="FILE",
        help="the printer's motion limits: its answer to M503 (M201/M203/M204/"
        "M205 lines) or Klipper's printer.cfg; needed for XZ/YZ tests unless "
        "--max-feed gives Z",
    )
    p.add_argument(
        "--firmware",
        metavar="NAME",
        help="the firmware (Marlin, Klipper, RepRapFirmware): its pause (M0, PAUSE, M291) "
        "and, with --limits, its planner (recorded in the program for the analysis) and "
        "M203's unit when the text does not state it; --limits with Klipper's printer.cfg "
        "says Klipper by itself",
    )
    p.add_argument("--feed-in", type=float, default=1.0, help="radial feed-in, mm")
    p.add_argument("--overshoot", type=float, default=20.0, help="overshoot arcs, deg")
    p.add_argument("--capture", type=float, help="capture arc, deg (360 XY, 220 vertical)")
    p.add_argument("--start", type=float, help="capture start angle, deg (0 XY, -20 vertical)")
    p.add_argument(
        "--volume",
        metavar="X0,X1,Y0,Y1,Z0,Z1",
        help="machine volume in mm: refuse a circle that does not fit",
    )
    p.add_argument(
        "--mount-pause",
        action="store_true",
        help="pause to mount the ballbar at the start and unmount at the end (M0; Klipper: "
        "PAUSE; RepRapFirmware: M291 S2)",
    )
    p.add_argument("--params", help="the params that will be in force (their hash is recorded)")
    p.add_argument("--printer", help="printer name to record (campaign checks)")
    p.add_argument(
        "--campaign",
        action="store_true",
        help="write a whole campaign (XY, XZ, YZ on --volume) into the -o directory",
    )
    p.add_argument(
        "--radius-vertical",
        type=float,
        default=50.0,
        help="campaign: radius of the XZ and YZ tests, mm (default 50)",
    )
    p.add_argument(
        "--second-height",
        type=float,
        metavar="Z",
        help="campaign: XY again at this height (mm), squareness against Z",
    )
    p.add_argument(
        "--second-feed",
        type=float,
        metavar="F",
        help="campaign: XY again at this feed (mm/min, e.g. 3700), decides servo pre-compensation",
    )
    p.add_argument("-o", "--output", help="output file (campaign: directory)")
    p.set_defaults(func=cmd_program)


def _add_simulate(sub) -> None:
    s = sub.add_parser("simulate", help="run a ballbar program on the simulated printer")
    s.add_argument("program")
    s.add_argument("--truth", required=True, help="JSON with the printer's true errors")
    s.add_argument("--noise-um", type=float, help="measurement noise (standard deviation), um")
    s.add_argument("--rate", type=float, help="ballbar sample rate, Hz (default 500)")
    s.add_argument(
        "--angle",
        action="store_true",
        help="write the angle-domain trace (direction,angle_deg,deviation_um)",
    )
    s.add_argument(
        "--compensated-with",
        metavar="P.json",
        help="--angle: the params the program was compensated with",
    )
    s.add_argument("-o", "--output")
    s.set_defaults(func=cmd_simulate)


def _add_analyze(sub) -> None:
    a = sub.add_parser(
        "analyze",
        help="fit a ballbar trace, .b5r or typed summary; several "
        "traces of a campaign are fitted jointly",
    )
    a.add_argument("trace", nargs="+")
    a.add_argument("--manifest", help="the campaign's campaign.json (checks every test is there)")
    a.add_argument("--current", help="params that were active during the test (residual fit)")
    a.add_argument("--json", action="store_true", help="print one JSON object")
    a.add_argument(
        "--mask-deg",
        type=float,
        default=15.0,
        help="ignore this many degrees after each reversal (default 15)",
    )
    a.add_argument(
        "--calibrated-bar",
        action="store_true",
        help="the bar length is calibrated: also fit the mean scale",
    )
    a.add_argument(
        "--cyclic-pitch",
        type=float,
        help="fit a cyclic error of this pitch, mm (default: fitted when the "
        "residual shows one; 0: never)",
    )
    a.add_argument(
        "--out-of-plane",
        action="append",
        metavar="KEY=UM_PER_M",
        help="the printer's squareness that a vertical test cannot see but that moves its "
        "third axis (YZ: xy, xz; XZ: yz), um/m as the params state it, e.g. an XY "
        "result's xy=-3638.6 (repeatable or comma-separated); the part --current corrects "
        "is taken off, the rest fitted as a known motion",
    )
    a.add_argument("--params-out", help="write the proposed params file here")
    a.add_argument(
        "--steps-per-mm",
        metavar="N|X,Y,Z",
        help="a re-test's program was compensated with this --steps-per-mm (its reversal "
        "dead band; default: as the trace records, else compensate's default)",
    )
    a.add_argument(
        "--decimals", type=int, help="a re-test's program was compensated with these decimals"
    )
    a.add_argument(
        "--firmware-compensation",
        metavar="TEXT|FILE",
        help="the firmware's compensation during the test: its M503 reply or the commands in "
        "force (M852, M425, M556, M579, SET_SKEW), text or a file; 'none' for none "
        "(default: as the trace records, else unknown)",
    )
    a.add_argument(
        "--program",
        help="the program that was printed (a trace with its program_hash is then tied to it: "
        "nothing left to confirm)",
    )
    a.set_defaults(func=cmd_analyze)


def _add_closed_loop(sub) -> None:
    c = sub.add_parser("closed-loop", help="print the simulated one-round before/after table")
    c.add_argument(
        "--noise-um",
        type=float,
        default=0.5,
        help="ballbar measurement noise, um (1 sigma; default 0.5)",
    )
    c.add_argument(
        "--campaign",
        action="store_true",
        help="one campaign over the whole volume, a table per plane",
    )
    c.set_defaults(func=cmd_closed_loop)


def _add_artifact(sub) -> None:
    t = sub.add_parser(
        "artifact",
        help="parameters from a printed square (and lengths), or "
        "KinComp's own artifact: 'artifact program', "
        "'artifact analyze'",
    )
    t.add_argument("--plane", default="XY", choices=("XY", "XZ", "YZ"))
    t.add_argument("--diagonals", metavar="AC,BD,AD", help="mm")
    t.add_argument(
        "--length",
        action="append",
        metavar="AXIS:NOMINAL:MEASURED",
        help="a measured length along an axis, mm (repeatable)",
    )
    t.add_argument("--current", help="params active when the artifact was printed")
    t.set_defaults(func=cmd_artifact, artifact_command=None)
    ts = t.add_subparsers(dest="artifact_command", metavar="{program,analyze}")
    _add_artifact_program(ts)
    _add_artifact_analyze(ts)


def _add_artifact_program(ts) -> None:
    tp = ts.add_parser("program", help="write KinComp's caliper artifact as G-code")
    tp.add_argument(
        "--volume",
        default="0,220,0,220,0,250",
        metavar="X0,X1,Y0,Y1,Z0,Z1",
        help="the printer's volume, mm (default 0,220,0,220,0,250)",
    )
    tp.add_argument("--planes", default="XY,XZ,YZ", help="parts to print (default XY,XZ,YZ)")
    tp.add_argument("--nozzle", type=float, default=0.4, help="nozzle diameter, mm")
    tp.add_argument(
        "--temps",
        default="210,60",
        metavar="NOZZLE,BED",
        help="temperatures, deg C (default 210,60)",
    )
    tp.add_argument("--first-layer", type=float, default=0.2, help="first layer height, mm")
    tp.add_argument("--layer", type=float, help="layer height, mm (default min(0.2, nozzle/2))")
    tp.add_argument("--line-width", type=float, help="mm (default 1.125 x nozzle)")
    tp.add_argument(
        "--caliper",
        type=float,
        default=150.0,
        help="the caliper's range, mm: no span is longer (default 150)",
    )
    tp.add_argument(
        "--tower-span",
        type=float,
        default=100.0,
        help="longest XZ/YZ tower span, mm (sets their height; default 100)",
    )
    tp.add_argument(
        "--quick",
        action="store_true",
        help="the quick artifact: one diagonal each way and the four towers, 12 readings "
        "(docs/artifact.md states both modes' precision)",
    )
    tp.add_argument(
        "--stl",
        metavar="ARTIFACT.stl",
        help="also write the artifact's walls as binary STL, to slice with your own profile "
        "(measure it with the G-code's sheet: keep the G-code for 'artifact analyze')",
    )
    tp.add_argument("-o", "--output", help="output file (default: standard output)")
    tp.set_defaults(func=cmd_artifact)


def _add_artifact_analyze(ts) -> None:
    ta = ts.add_parser("analyze", help="fit the caliper readings of KinComp's artifact")
    ta.add_argument("measurements", help='JSON {"<id>": [reading_mm, ...], ...}')
    ta.add_argument("--program", required=True, help="the artifact's G-code (its header)")
    ta.add_argument(
        "--current",
        dest="artifact_current",
        help="params active when the artifact was printed (residual fit)",
    )
    ta.add_argument("--json", action="store_true", help="print one JSON object")
    ta.add_argument("--params-out", help="write the proposed params file here")
    ta.set_defaults(func=cmd_artifact)
