"""Live-sensor commands of the CLI: ``sensor-ports``, ``sensor-capture``, ``sensor-trace``,
``sensor-virtual`` (see the README's "Live ballbar capture"). Readings are mm, positive =
bar longer; times in s."""

from __future__ import annotations

import sys
import time

from .common import CliError, read_text, write_text


def _spec(path: str):
    from ..calibration.ballbar.program import ProgramError, spec_from_program

    text = read_text(path)
    try:
        spec, prog_hash = spec_from_program(text)
    except ProgramError as exc:
        raise CliError(f"{path}: {exc}") from None
    return text, spec, prog_hash


def _config(args):
    from ..sensor import SensorConfig, SensorError

    try:
        return SensorConfig.from_dict(
            dict(
                port=args.port,
                baudrate=args.baud,
                protocol=args.protocol,
                units=args.units,
                positive=args.positive,
                pattern=args.pattern or "",
                scale=args.scale,
                range=args.range or "",
                sample_rate_hz=args.rate or 0.0,
            )
        )
    except SensorError as exc:
        option = {"baudrate": "--baud", "sample_rate_hz": "--rate", "port": "port"}.get(
            exc.field, "--" + exc.field
        )
        raise CliError(f"{option}: {exc.message}" if exc.field else str(exc)) from None


def cmd_ports(args) -> int:
    from ..sensor import list_ports

    for p in list_ports():
        print(f"{p['device']}\t{p['description']}\t{p['hwid']}")
    return 0


def _line(st) -> str:
    reading = st.get("reading_mm")
    noise = st.get("noise_um")
    diag = st.get("diagnostics") or {}
    return (
        f"{st['state']:9s} reading {'-' if reading is None else f'{reading:+.4f}'} mm  "
        f"noise {'-' if noise is None else f'{noise:.2f}'} um  "
        f"samples {st.get('samples', 0)}  bad lines {diag.get('bad_lines', 0)}  "
        f"runs {st.get('runs_found', 0)}"
    )


def cmd_capture(args) -> int:
    from ..sensor import Capture

    _, spec, prog_hash = _spec(args.program)
    cap = Capture(_config(args))
    cap.open()
    end = time.monotonic() + args.preview_s
    try:
        while time.monotonic() < end and cap.state != "failed":
            time.sleep(min(1.0, args.preview_s))
            print(_line(cap.status()), file=sys.stderr)
        if cap.state != "failed":
            cap.arm(spec, prog_hash, max_duration_s=args.timeout)
            print("armed: start the test program now (Ctrl-C stops)", file=sys.stderr)
            while cap.wait(("done", "failed"), 2.0) not in ("done", "failed"):
                print(_line(cap.status()), file=sys.stderr)
    except KeyboardInterrupt:
        cap.stop()
        cap.wait(("done", "failed"), 10.0)
    finally:
        cap.close(wait_s=2.0)
    res = cap.result
    if res is None:
        raise CliError(str(cap.status()["message"]))
    if args.raw and res.stream is not None:
        write_text(args.raw, res.stream.to_text())
    if not res.ok:
        raise CliError(
            f"capture failed: {res.message}"
            + (f" (raw stream kept in {args.raw})" if args.raw and res.stream else "")
        )
    write_text(args.output, res.trace.to_text())
    print(f"captured {len(res.trace.rows)} samples in {len(res.runs)} runs", file=sys.stderr)
    return 0


def cmd_trace(args) -> int:
    from ..calibration.ballbar.formats import TraceError
    from ..sensor import SensorError, parse_raw_stream, trace_from_stream

    _, spec, prog_hash = _spec(args.program)
    raw = read_text(args.raw)
    try:
        stream = parse_raw_stream(raw)
        trace, _ = trace_from_stream(stream, spec, prog_hash, args.rate or None)
    except (TraceError, SensorError) as exc:
        raise CliError(f"{args.raw}: {exc}") from None
    write_text(args.output, trace.to_text())
    return 0


def cmd_virtual(args) -> int:
    from ..calibration.ballbar.program import ProgramError
    from ..core.params import ParamsError
    from ..sensor.virtual import VirtualSensor
    from ..simulator.printer import Truth

    text, spec, prog_hash = _spec(args.program)
    try:
        truth = Truth.load(args.truth) if args.truth else None
    except (ParamsError, OSError, KeyError, TypeError, ValueError) as exc:
        raise CliError(f"invalid truth file {args.truth}: {exc}") from None
    vs = VirtualSensor(
        truth, transport="tcp" if args.tcp else "pty", protocol=args.protocol, speedup=args.speedup
    )
    print(f"SIMULATED ballbar streaming on {vs.start()} (Ctrl-C stops)", flush=True)
    try:
        time.sleep(args.delay)
        vs.play(text.splitlines(), spec=spec, program_hash=prog_hash)
        print("playing the program", flush=True)
        time.sleep(max(0.0, vs.program_end - time.monotonic()) + args.hold)
    except ProgramError as exc:
        raise CliError(f"{args.program}: {exc}") from None
    except KeyboardInterrupt:
        pass
    finally:
        vs.stop()
    return 0


def add_sensor_commands(sub) -> None:
    sub.add_parser("sensor-ports", help="list the serial ports").set_defaults(func=cmd_ports)

    p = sub.add_parser(
        "sensor-capture",
        help="capture a ballbar test live from a serial sensor into a native trace",
    )
    p.add_argument("port", help="device path or pyserial URL (socket://host:port, ...)")
    p.add_argument(
        "program", help="the ballbar program being printed (its '; ballbar' header gives the test)"
    )
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--protocol", choices=("kincomp", "plain", "pattern"), default="kincomp")
    p.add_argument("--pattern", help="pattern protocol: regex with a (?P<value>...) group")
    p.add_argument("--scale", type=float, default=1.0, help="pattern protocol: value factor")
    p.add_argument("--units", choices=("mm", "um", "inch"), default="mm")
    p.add_argument(
        "--positive",
        choices=("longer", "shorter"),
        default="longer",
        help="what a positive reading means",
    )
    p.add_argument("--range", help="the sensor's range low,high in its units")
    p.add_argument(
        "--rate",
        type=float,
        help="the device's sample rate, Hz (host-timed protocols; else fitted)",
    )
    p.add_argument(
        "--preview-s", type=float, default=3.0, help="seconds of live readings before arming"
    )
    p.add_argument("--timeout", type=float, default=None, help="give up after this many s")
    p.add_argument("-o", "--output", help="native trace file (default: stdout)")
    p.add_argument("--raw", help="also write the raw stream (kept when the capture fails)")
    p.set_defaults(func=cmd_capture)

    p = sub.add_parser("sensor-trace", help="turn a saved raw stream into a native trace")
    p.add_argument("raw")
    p.add_argument("program")
    p.add_argument("--rate", type=float, help="declared sample rate for host-timed streams")
    p.add_argument("-o", "--output")
    p.set_defaults(func=cmd_trace)

    p = sub.add_parser(
        "sensor-virtual",
        help="a SIMULATED ballbar on a pty or loopback socket that plays a program",
    )
    p.add_argument("program")
    p.add_argument("--truth", help="the simulated printer's errors (default: the demo's)")
    p.add_argument("--tcp", action="store_true", help="loopback socket instead of a pty")
    p.add_argument("--protocol", choices=("kincomp", "plain"), default="kincomp")
    p.add_argument("--speedup", type=float, default=1.0)
    p.add_argument("--delay", type=float, default=5.0, help="s before the program starts")
    p.add_argument("--hold", type=float, default=5.0, help="s to stream after the program")
    p.set_defaults(func=cmd_virtual)
