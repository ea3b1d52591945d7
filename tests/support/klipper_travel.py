"""Compensated files on real Klipper at the travel's edges (issue 36): the pieces the tests in
``tests/firmware/test_klipper_travel.py`` share.

A file is run twice through klippy (``tests/support/klipper.py``): as written and compensated
by KinComp (the engine the plugin uses, line by line, so every output line is known by its
input line), both on the same stock config whose travel (``position_min``/``position_max``)
is set tight to the file's own extent (what real start and end code does: purge lines and
wipers at the printer's edge), with ``keep_going`` so that every error is seen. An error of
the compensated run is KinComp's when the input line it came from has none uncompensated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Move
from tests.support import klipper

# the realistic parameters (um/m, ppm, um)
REALISTIC = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": 1500.0, "xz": -800.0, "yz": 600.0},
        "scale_ppm": {"x": 300.0, "y": -200.0, "z": 150.0},
        "backlash": {"x": 60.0, "y": 40.0},
    }
)


# lines of other firmware that mean something else to Klipper, the same in both runs:
# Prusa's and Bambu's "M84 E" / "M18 E" turn the extruder's motor off; Klipper's M84 and M18
# take no axis and turn every motor off, forgetting the homing (every later move: "Must
# home axis first"). Bambu's "G28 X" re-homes X on a printer whose own start code homed Y
# and Z its own way; on Klipper it is G28 (all axes).
_E_MOTOR_OFF = re.compile(r"M(?:84|18)\s+E", re.IGNORECASE)
_HOME_X_ONLY = re.compile(r"G28\s+X", re.IGNORECASE)


def for_klipper(lines: Sequence[str]) -> List[str]:
    """``lines`` as a Klipper user would run them (see the rules above); each changed line
    keeps its place (so errors still name the file's own line numbers)."""
    out = []
    for line in lines:
        code = line.split(";", 1)[0].strip()
        if _E_MOTOR_OFF.fullmatch(code):
            out.append("; (for Klipper) " + line)
        elif _HOME_X_ONLY.fullmatch(code):
            out.append("G28 ; (for Klipper) " + line)
        else:
            out.append(line)
    return out


def home_after_g28(config: str) -> Tuple[float, float, float]:
    """Where the toolhead is after ``G28`` on a (batch-mode) config, mm: each axis at its
    ``position_endstop``; with ``[safe_z_home]`` X/Y at ``home_xy_position`` and Z lifted to
    ``z_hop`` when that is above the endstop."""
    v = klipper.config_values(config)
    home = [float(v["stepper_" + a]["position_endstop"]) for a in "xyz"]
    safe = v.get("safe_z_home")
    if safe is not None:
        home[0], home[1] = (float(t) for t in safe["home_xy_position"].split(","))
        home[2] = max(home[2], float(safe.get("z_hop", 0.0)))
    return tuple(home)


def extent(lines: Sequence[str], home: Sequence[float]) -> List[Tuple[float, float]]:
    """Per axis (min, max) mm of every point the program commands (arcs as chords of 1 um
    sagitta, so their apex is in), the home included."""
    lo, hi = list(home), list(home)
    for ev in FirmwareInterpreter(home_mm=tuple(home), arc_tol_mm=1e-3).run(lines):
        if isinstance(ev, Move):
            for k in range(3):
                lo[k] = min(lo[k], ev.end[k])
                hi[k] = max(hi[k], ev.end[k])
    return list(zip(lo, hi))


def tight_config(name: str, lines: Sequence[str], **kw) -> Tuple[str, Tuple[float, ...]]:
    """The stock config ``name`` with its travel set to the program's extent (the endstops
    kept inside it, and Z at least 10 mm above its switch for the homing retract): (config
    text, limits x0, x1, y0, y1, z0, z1 mm)."""
    sections = dict(kw.pop("sections", None) or {})
    base = klipper.stock_config(name, sections=sections, **kw)
    v = klipper.config_values(base)
    box = extent(lines, home_after_g28(base))
    limits = []
    for k, axis in enumerate("xyz"):
        stop = float(v["stepper_" + axis]["position_endstop"])
        lo = math.floor(min(box[k][0], stop) * 1000) / 1000
        hi = math.ceil(max(box[k][1], stop) * 1000) / 1000
        if axis == "z":  # room for G28's retract off the Z switch (5 mm by default)
            hi = max(hi, stop + 10.0)
        sec = dict(sections.get("stepper_" + axis, {}))
        sec.update(position_min=lo, position_max=hi)
        sections["stepper_" + axis] = sec
        limits += [lo, hi]
    return klipper.stock_config(name, sections=sections, **kw), tuple(limits)


def compensate(
    lines: Sequence[str], params: Params, options: Options
) -> Tuple[List[str], List[int], dict]:
    """``lines`` compensated line by line: (output lines, for each output line its input
    line (1-based), the report)."""
    comp = make_compensator(params, options)
    out, src = [], []
    for i, line in enumerate(lines, 1):
        got = comp.process(line)
        got = [got] if isinstance(got, str) else got
        out += got
        src += [i] * len(got)
    return out, src, comp.report.to_dict()


@dataclass
class Outcome:
    """Both runs of one program: errors as (input line, message)."""

    plain: List[Tuple[int, str]]
    compensated: List[Tuple[int, str]]
    report: dict
    crashed: bool = False
    new: List[Tuple[int, str]] = field(default_factory=list)  # KinComp's


def compare(
    klippy,
    workdir,
    config: str,
    lines: Sequence[str],
    params: Params = REALISTIC,
    policy: str = "clamp",
    limits: Optional[Tuple[float, ...]] = None,
    home: Optional[Tuple[float, float, float]] = None,
) -> Outcome:
    """Runs ``lines`` as written and compensated (``limits``: the config's travel unless
    given, ``home``: where its G28 leaves the head unless given) on ``config``."""
    if limits is None:
        box = klipper.travel_limits(config)
        limits = tuple(v for a in "xyz" for v in box[a])
    options = Options(
        limits=limits, policy=policy, home_mm=home if home is not None else home_after_g28(config)
    )
    out, src, report = compensate(lines, params, options)
    a = klipper.run(klippy, config, lines, workdir / "plain", positions=False, keep_going=True)
    b = klipper.run(klippy, config, out, workdir / "comp", positions=False, keep_going=True)
    n = len(lines)
    plain = [(e.line_no, e.message) for e in a.errors if 0 < e.line_no <= n]
    comp = [(src[e.line_no - 1], e.message) for e in b.errors if 0 < e.line_no <= len(out)]
    seen = {ln for ln, _ in plain}
    new = [e for e in comp if e[0] not in seen]
    return Outcome(plain, comp, report, a.crashed or b.crashed, new)
