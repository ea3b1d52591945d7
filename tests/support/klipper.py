"""Real Klipper for the tests: G-code through klippy's batch mode, and what Klipper did with it.

Klipper (GPLv3) is a test tool here, like the real OctoPrint of the end-to-end tests: it is
*run* as another process from a copy of ``../shared/klipper`` (read-only in CI: klippy builds
its C helper next to its sources on first use), never imported by the product, and none of its
code is in this project. The child process (``klipper_child.py``) imports the copied klippy and
wraps a few of its methods to watch it; the G-code, the planner and every check are Klipper's.

Use (the session fixture ``klippy`` of ``tests/conftest.py`` makes the copy and builds the C
helper once per session: about 10 s of one core, 2-5 s wall on an idle machine)::

    cfg = stock_config("printer-creality-ender3-v2-2020.cfg", printer={"max_z_accel": 50})
    res = run(klippy, cfg, ["G28", "G1 X10 Y10 F6000"], tmp_path, record_moves=True)
    res.ok, res.first_error          # KlipperError(message, line_no, line): 1-based input line
    res.positions                    # [(line_no, (x, y, z, e) toolhead, (x, y, z, e) gcode)]
    res.moves                        # Klipper's planned moves (record_moves=True)
    res.final["mcu"]["stepper_x"]    # GET_POSITION after the last line (final_position=True)

Positions are mm, times s. A run costs about 0.7 s of CPU to start klippy plus 0.15 ms per
line (recording the planned moves about doubles that); a run that crashes klippy (a heap
overflow in its ``chelper/stepcompress.c`` was seen on 4 of about 350 runs, none of them a
KinComp test program) is run once more and then reported as ``crashed``.

Batch mode differs from a printer fed by a host in two ways the harness removes by default
(``steady_feed``): a 4 KB chunk of input without a move makes klippy's step-flush timer flush
the lookahead as if the input had run dry (a full stop that a printer does not make), and a
100 ms wall-clock priming timer fires whenever klippy runs slower than real time. Everything
else is as Klipper does it: the first ``!!`` error ends the run (as a print from its SD card),
unless ``keep_going`` drops the failed command and goes on.
"""

from __future__ import annotations

import configparser
import fcntl
import json
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

from tests.support import ROOT

KLIPPER = Path(os.environ.get("KINCOMP_KLIPPER", os.path.join(ROOT, "..", "shared", "klipper")))
CHILD = Path(__file__).with_name("klipper_child.py")
PYTHON = sys.executable
# after the caller's lines: wait for the moves, flush the step generation (steps are generated
# lazily, up to 1.5 s of print time behind; enabling an enabled stepper flushes and does
# nothing else), then the positions
FINAL = ("M400", "SET_STEPPER_ENABLE STEPPER={stepper} ENABLE=1", "GET_POSITION")
# the sections of a stock config kept (the others need hardware or are not motion)
KEEP = frozenset({"printer", "safe_z_home", "firmware_retraction", "gcode_arcs", "skew_correction"})
STEPPER = re.compile(r"^stepper_([xyz]\d*|[abc])$")
HEATER_KEYS = frozenset(
    {
        "heater_pin",
        "sensor_type",
        "sensor_pin",
        "control",
        "pid_kp",
        "pid_ki",
        "pid_kd",
        "max_delta",
        "pwm_cycle_time",
        "min_temp",
        "max_temp",
        "max_power",
        "smooth_time",
    }
)
EXTRUDER_KEYS = HEATER_KEYS | {
    "step_pin",
    "dir_pin",
    "enable_pin",
    "microsteps",
    "rotation_distance",
    "gear_ratio",
    "full_steps_per_rotation",
    "nozzle_diameter",
    "filament_diameter",
    "max_extrude_cross_section",
    "max_extrude_only_distance",
    "max_extrude_only_velocity",
    "max_extrude_only_accel",
    "pressure_advance",
    "pressure_advance_smooth_time",
    "instantaneous_corner_velocity",
    "min_extrude_temp",
}
PINS = frozenset({"step_pin", "dir_pin", "enable_pin", "endstop_pin", "heater_pin"})
THERMISTOR = "EPCOS 100K B57560G104F"
# Klipper's [printer] defaults (klippy/toolhead.py, kinematics/*.py)
PRINTER_DEFAULTS = {"square_corner_velocity": 5.0, "minimum_cruise_ratio": 0.5}


def available() -> Optional[str]:
    """None when Klipper can run here, else why not (for a skip)."""
    if not (KLIPPER / "klippy" / "klippy.py").exists():
        return f"no Klipper at {KLIPPER} (KINCOMP_KLIPPER)"
    if not (KLIPPER / "out" / "klipper.dict").exists():
        return "Klipper's Linux-process data dictionary (out/klipper.dict) is missing"
    if shutil.which("gcc") is None:
        return "gcc is needed to build klippy's C helper"
    try:
        import cffi  # noqa: F401
        import greenlet  # noqa: F401
        import serial  # noqa: F401
    except ImportError as exc:
        return f"a package klippy needs is missing: {exc.name}"
    return None


def prepare(root: Path) -> Path:
    """Copies ``klippy/`` into ``root`` and builds its C helper there, once (file-locked:
    parallel sessions share a cache directory safely); returns the copy's ``klippy``
    directory. Raises RuntimeError with the compiler's output when the build fails."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    ready = root / ".ready"
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not ready.exists():
            shutil.rmtree(root / "klippy", ignore_errors=True)
            shutil.copytree(
                KLIPPER / "klippy",
                root / "klippy",
                ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.o"),
            )
            r = subprocess.run(
                [PYTHON, "-c", "import chelper; chelper.get_ffi()"],
                cwd=root / "klippy",
                capture_output=True,
                text=True,
            )
            if r.returncode != 0 or not (root / "klippy" / "chelper" / "c_helper.so").exists():
                raise RuntimeError("klippy's C helper did not build:\n" + r.stdout + r.stderr)
            ready.write_text("ok")
    return root / "klippy"


# ---------------------------------------------------------------------------------------
# configs


def parse_config(text: str) -> List[Tuple[str, List[Tuple[str, str]]]]:
    """A Klipper config's sections in order: [(section, [(option, value)])], options lower
    case, comments dropped, continuation lines joined with a newline (the ``#*#`` block of
    saved settings is left out)."""
    sections: List[Tuple[str, List[Tuple[str, str]]]] = []
    items: Optional[List[Tuple[str, str]]] = None
    for raw in text.splitlines():
        if raw.startswith("#*#"):
            break
        stripped = raw.strip()
        if not stripped or stripped[0] in "#;":
            continue
        m = re.match(r"^\[([^\]]+)\]", raw)
        if m:
            items = []
            sections.append((m.group(1).strip(), items))
        elif items is not None and raw[0] in " \t" and items:
            key, value = items[-1]
            items[-1] = (key, value + "\n" + stripped)
        elif items is not None:
            m = re.match(r"^([^:=\s]+)\s*[:=]\s*(.*)$", raw)
            if m:
                value = re.sub(r"\s[#;].*$", "", m.group(2)).strip()
                items.append((m.group(1).strip().lower(), value))
    return sections


def config_values(text: str) -> Dict[str, Dict[str, str]]:
    """{section (lower case): {option: value}} of a config text."""
    return {s.lower(): dict(items) for s, items in parse_config(text)}


def printer_limits(text: str) -> Dict[str, float]:
    """The [printer] motion limits of a config as Klipper takes them (its defaults for what
    the text does not say): max_velocity, max_accel (mm/s, mm/s^2), max_z_velocity,
    max_z_accel, square_corner_velocity, minimum_cruise_ratio. Read here with the standard
    library, apart from KinComp's own reader (``firmware/motion_limits.py``)."""
    cp = configparser.ConfigParser(inline_comment_prefixes=("#", ";"), strict=False)
    cp.read_string("\n".join(ln for ln in text.splitlines() if not ln.startswith("#*#")))
    p = cp["printer"]
    v, a = p.getfloat("max_velocity"), p.getfloat("max_accel")
    return {
        "kinematics": p.get("kinematics"),
        "max_velocity": v,
        "max_accel": a,
        "max_z_velocity": p.getfloat("max_z_velocity", v),
        "max_z_accel": p.getfloat("max_z_accel", a),
        "square_corner_velocity": p.getfloat(
            "square_corner_velocity", PRINTER_DEFAULTS["square_corner_velocity"]
        ),
        "minimum_cruise_ratio": p.getfloat(
            "minimum_cruise_ratio", PRINTER_DEFAULTS["minimum_cruise_ratio"]
        ),
    }


def travel_limits(text: str) -> Dict[str, Tuple[float, float]]:
    """{axis: (position_min, position_max)} (mm) of a cartesian or corexy config."""
    v = config_values(text)
    out = {}
    for axis in "xyz":
        s = v.get("stepper_" + axis)
        if s is not None:
            out[axis] = (float(s.get("position_min", 0.0)), float(s["position_max"]))
    return out


def stock_configs() -> List[str]:
    """The names of Klipper's stock printer configs (``config/printer-*.cfg``)."""
    return sorted(p.name for p in (KLIPPER / "config").glob("printer-*.cfg"))


def _section(name: str, items: List[Tuple[str, str]], pins) -> Optional[List[Tuple[str, str]]]:
    """The options of one stock section kept for batch mode (pins renamed to the Linux
    process's), None for a section left out."""
    low = name.lower()
    if low in KEEP:
        return list(items)
    if STEPPER.match(low):
        kept = [(k, pins("gpio") if k in PINS else v) for k, v in items]
        keys = {k for k, _ in kept}
        if "endstop_pin" not in keys:  # a probe or sensorless endstop: a plain pin
            kept.append(("endstop_pin", pins("gpio")))
        if low == "stepper_z" and "position_endstop" not in keys:
            kept.append(
                ("position_endstop", repr(max(0.0, float(dict(kept).get("position_min", 0)))))
            )
        return kept
    if low in ("extruder", "heater_bed"):
        allowed = EXTRUDER_KEYS if low == "extruder" else HEATER_KEYS
        kept = []
        for k, v in items:
            if k in allowed:
                v = pins("gpio") if k in PINS else pins("analog") if k == "sensor_pin" else v
                kept.append((k, THERMISTOR if k == "sensor_type" else v))
        keys = {k for k, _ in kept}
        kept += [("sensor_type", THERMISTOR)] * ("sensor_type" not in keys)
        kept += [("sensor_pin", pins("analog"))] * ("sensor_pin" not in keys)
        kept += [("control", "watermark")] * ("control" not in keys)
        return kept
    return None


def stock_config(
    name: str,
    printer: Optional[Dict[str, object]] = None,
    sections: Optional[Dict[str, Dict[str, object]]] = None,
    add: Iterable[str] = ("gcode_arcs",),
    extra: str = "",
) -> str:
    """A stock printer config (``name`` in Klipper's ``config/``, or a path) made to run in
    batch mode on the Linux-process dictionary: [printer], the steppers (every option, pins
    renamed), [extruder] and [heater_bed] (motion and extrusion limits; a thermistor on an
    analog pin, so M104/M109/M140/M190 work and their waits return at once), [safe_z_home],
    [firmware_retraction], [gcode_arcs], [skew_correction] kept; probes, bed mesh, drivers,
    displays, fans, LEDs, sensors, macros and extra MCUs left out (a probe as Z endstop
    becomes a plain pin at ``max(0, position_min)``). ``printer``: [printer] options set;
    ``sections``: options of kept sections set ({"stepper_x": {"position_min": -5}});
    ``add``: empty sections added (``gcode_arcs``, ``skew_correction``, ``pause_resume``,
    ``force_move``, ``virtual_sdcard`` needs a path: give it in ``extra``); ``extra``: text
    appended as it is."""
    path = Path(name) if os.path.sep in name else KLIPPER / "config" / name
    counters = {"gpio": iter(range(1, 280)), "analog": iter(range(8))}

    def pins(kind: str) -> str:
        return f"{kind}{next(counters[kind])}"

    out = [f"# {path.name} for klippy's batch mode (tests/support/klipper.py)", "[mcu]"]
    out += ["serial: /dev/null", ""]
    seen = set()
    for sec, items in parse_config(path.read_text(errors="replace")):
        kept = _section(sec, items, pins)
        if kept is None:
            continue
        low = sec.lower()
        changes = dict(printer or {}) if low == "printer" else (sections or {}).get(low, {})
        kept = [(k, v) for k, v in kept if k not in changes] + [
            (k, str(v)) for k, v in changes.items()
        ]
        seen.add(low)
        out.append(f"[{sec}]")
        out += [f"{k}: {v}".replace("\n", "\n  ") for k, v in kept]
        out.append("")
    for sec in add:
        if sec not in seen:
            out += [f"[{sec}]", ""]
    return "\n".join(out) + "\n" + (extra + "\n" if extra else "")


# ---------------------------------------------------------------------------------------
# running


@dataclass
class KlipperError:
    """A ``!!`` response: Klipper's message and the input line (1-based, 0: before it)."""

    message: str
    line_no: int
    line: str


@dataclass
class Result:
    """What one klippy run did (see the module docstring)."""

    errors: List[KlipperError]
    positions: List[Tuple[int, Tuple[float, ...], Tuple[float, ...]]]
    moves: List[dict]
    final: Dict[str, Dict[str, float]]
    responses: List[Tuple[int, str]]
    returncode: int
    crashed: bool
    wall_s: float
    workdir: str
    log_tail: str = ""
    attempts: int = 1
    notes: List[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.errors

    @property
    def first_error(self) -> Optional[KlipperError]:
        return self.errors[0] if self.errors else None

    def moves_of(self, lines: Iterable[int]) -> List[dict]:
        """The kinematic moves Klipper planned for the input lines ``lines`` (1-based)."""
        want = set(lines)
        return [m for m in self.moves if m["kin"] and m["line"] in want]

    def line_times(self) -> Dict[int, float]:
        """Seconds of motion Klipper planned per input line (kinematic moves)."""
        out: Dict[int, float] = {}
        for m in self.moves:
            if m["kin"]:
                out[m["line"]] = out.get(m["line"], 0.0) + m["t"]
        return out


def _positions(text: str) -> Dict[str, Dict[str, float]]:
    """GET_POSITION's answer: {"mcu": {"stepper_x": steps, ...}, "toolhead": {"X": mm}...}."""
    out: Dict[str, Dict[str, float]] = {}
    for ln in text.splitlines():
        m = re.match(
            r"^(mcu|stepper|kinematic|toolhead|gcode|gcode base|gcode homing):\s*(.*)$",
            ln.strip().lstrip("/").strip(),
        )
        if m:
            vals = {}
            for tok in m.group(2).split():
                key, _, value = tok.rpartition(":")
                vals[key] = float(value)
            out[m.group(1)] = vals
    return out


def _once(klippy: Path, workdir: Path, lines: List[str], options: dict, timeout: float):
    for old in ("klippy.log", "result.json", "out.serial"):
        (workdir / old).unlink(missing_ok=True)
    args = dict(
        options,
        klippy=str(klippy),
        config=str(workdir / "printer.cfg"),
        gcode=str(workdir / "in.gcode"),
        serial=str(workdir / "out.serial"),
        dictionary=str(KLIPPER / "out" / "klipper.dict"),
        log=str(workdir / "klippy.log"),
        result=str(workdir / "result.json"),
    )
    try:
        p = subprocess.run(
            [PYTHON, str(CHILD), json.dumps(args)],
            cwd=str(workdir),
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        rc = p.returncode
    except subprocess.TimeoutExpired:
        rc = -999
    data = {}
    if (workdir / "result.json").exists():
        data = json.loads((workdir / "result.json").read_text())
    (workdir / "out.serial").unlink(missing_ok=True)
    return rc, data


def run(
    klippy: Path,
    config: str,
    lines: Sequence[str],
    workdir,
    record_moves: bool = False,
    positions: bool = True,
    final_position: bool = True,
    keep_going: bool = False,
    steady_feed: bool = True,
    timeout: float = 600.0,
) -> Result:
    """Runs ``lines`` through klippy (``klippy``: :func:`prepare`'s copy) with the config text
    ``config`` in ``workdir``. ``positions``: the toolhead position (after Klipper's move
    transform, i.e. what the kinematics get, [skew_correction] applied) and the G-code
    position after every G0-G3 line; ``record_moves``: every move Klipper's lookahead plans
    (its input line, start and end point, length ``d``, speeds ``v0 vc v1``, acceleration
    ``a``, phase times ``ta tc td``, start time ``t0`` and duration ``t``); ``final_position``:
    GET_POSITION after the last line (mcu step counts, stepper, kinematic, toolhead and G-code
    positions). ``keep_going``: an error does not end the run (the failed command is
    dropped). ``steady_feed``: see the module docstring."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    body = [ln.rstrip("\r\n") for ln in lines]
    n = len(body)
    stepper = "stepper_a" if "[stepper_a]" in config else "stepper_x"
    body += [c.format(stepper=stepper) for c in FINAL] if final_position else ["M400"]
    (workdir / "printer.cfg").write_text(config)
    (workdir / "in.gcode").write_text("\n".join(body) + "\n")  # (klippy drops a last line)
    options = dict(
        positions=positions,
        record_moves=record_moves,
        steady_feed=steady_feed,
        keep_going=keep_going,
    )
    t0 = time.monotonic()
    attempts = 0
    while True:
        attempts += 1
        rc, data = _once(klippy, workdir, body, options, timeout)
        crashed = rc < 0 or rc in (134, 139)
        if not crashed or attempts == 2:
            break
    responses = [(int(ln), str(text)) for ln, text in data.get("responses", [])]
    errors = [
        KlipperError(text[2:].strip(), ln, body[ln - 1] if 0 < ln <= len(body) else "")
        for ln, text in responses
        if text.startswith("!!")
    ]
    final = {}
    for ln, text in responses:
        if ln > n and "mcu:" in text and "toolhead:" in text:
            final = _positions(text)
    log = workdir / "klippy.log"
    return Result(
        errors=errors,
        positions=[(int(p[0]), tuple(p[1:5]), tuple(p[5:9])) for p in data.get("positions", [])],
        moves=data.get("moves", []),
        final=final,
        responses=responses,
        returncode=rc,
        crashed=crashed,
        wall_s=time.monotonic() - t0,
        workdir=str(workdir),
        log_tail=log.read_text(errors="replace")[-3000:] if log.exists() else "",
        attempts=attempts,
    )
