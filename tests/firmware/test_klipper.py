"""KinComp against real Klipper (issue 36): its test programs run through klippy's batch mode
(``tests/support/klipper.py``, the session fixture ``klippy``).

* **Timing**: KinComp's plan of each program (the planner settings it reads from the stock
  config's [printer] section) against the moves Klipper itself planned: the time from the end
  of each run's radial feed-in to the start of its feed-out (what the analysis' motion check
  compares) within half of that check's tolerance, on a handful of stock configs that span
  the 108 (``max_z_accel`` 100 as in 75 of them, 30 on a CoreXY, ``minimum_cruise_ratio`` 0,
  a square-corner velocity of 15 mm/s with 450 mm/s^2).
* **Skew**: a program compensated by KinComp (squareness only) on plain Klipper against the
  same program uncompensated with Klipper's own ``SET_SKEW``: every move's end within one
  step on every axis, and the same step counts at the end.
* **The mount pause**: printed from Klipper's SD card (``virtual_sdcard``, as Mainsail and
  Fluidd print), a program for Klipper stops at its ``PAUSE``; Marlin's ``M0`` is unknown to
  Klipper, which runs on without the bar.

Cost (this machine, 2 cores shared): the C helper build once per session (about 10 s of one
core), then 9 klippy runs of 0.7 s start-up plus 0.15-0.3 ms per line each: about 15 s of one
core in all.
"""

import math

import pytest

from octoprint_kincomp.calibration.ballbar.checks import SYNC_TOLERANCE_MS, SYNC_TOLERANCE_SHARE
from octoprint_kincomp.calibration.ballbar.program import TestSpec, check_bounds, generate
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.export import equivalents
from octoprint_kincomp.firmware.motion_limits import circle_feed, parse_limits
from octoprint_kincomp.firmware.planner import plan_program, settings_from_limits
from tests.support import klipper
from tests.support.helpers import compensate_groups

FORCE_MOVE = "[force_move]\nenable_force_move: True"
# (stock config, planes): what each one stands for is in the module docstring
HANDFUL = [
    ("printer-creality-ender3-v2-2020.cfg", "XY"),
    ("printer-creality-ender3-v2-2020.cfg", "XZ"),
    ("printer-creality-ender3-v2-2020.cfg", "YZ"),
    ("printer-tronxy-x5sa-pro-2020.cfg", "YZ"),
    ("printer-sovol-sv05-2022.cfg", "XZ"),
    ("printer-wanhao-duplicator-9-2018.cfg", "XZ"),
]


def program_for(config: str, plane: str, **kw):
    """A KinComp test program for the stock ``config`` as the command line makes it with the
    config as ``--limits``: the feed the limits allow, the planner recorded. (program text,
    its spec, where the head starts, the planner settings)."""
    limits = parse_limits(config)
    box = klipper.travel_limits(config)
    mid = [0.5 * (lo + hi) for lo, hi in (box["x"], box["y"])]
    vertical = plane != "XY"
    radius = 50.0 if vertical else 100.0 if plane == "XY" and min(mid) > 115 else 50.0
    centre = (mid[0], mid[1], box["z"][0] + (radius + 11.0 if vertical else 10.0))
    feed = circle_feed(plane, radius, 1850.0, limits).feed_mm_min
    settings = settings_from_limits(limits, limits.firmware)
    spec = TestSpec(
        plane=plane,
        centre=centre,
        radius_mm=radius,
        feed_mm_min=feed,
        motion=settings.metadata(),
        **kw,
    )
    check_bounds(spec, [v for axis in "xyz" for v in box[axis]])
    return generate(spec, date="-"), spec, centre, settings


def _start(centre):
    x, y, z = centre
    return f"SET_KINEMATIC_POSITION X={x:.4f} Y={y:.4f} Z={z:.4f}"


def _run_spans(lines, offset):
    """(feed-in line, feed-out line) numbers of each run (1-based, plus ``offset``)."""
    fin = [i for i, ln in enumerate(lines, 1) if "; radial feed-in" in ln]
    fout = [i for i, ln in enumerate(lines, 1) if "; radial feed-out" in ln]
    return [(a + offset, b + offset) for a, b in zip(fin, fout)]


def klipper_arc_times(res, lines, offset=1):
    """Seconds from the end of each run's feed-in to the start of its feed-out, as Klipper
    planned the moves."""
    out = []
    for fin, fout in _run_spans(lines, offset):
        t_in = max(m["t0"] + m["t"] for m in res.moves_of([fin]))
        t_out = min(m["t0"] for m in res.moves_of([fout]))
        out.append(t_out - t_in)
    return out


def kincomp_arc_times(plan, lines):
    out = []
    for fin, fout in _run_spans(lines, 0):
        t_in = plan.block_span(int(plan.blocks_of_lines([fin])[-1]))[1]
        t_out = plan.block_span(int(plan.blocks_of_lines([fout])[0]))[0]
        out.append(t_out - t_in)
    return out


@pytest.mark.parametrize("name,plane", HANDFUL, ids=[f"{c[8:-4]}-{p}" for c, p in HANDFUL])
def test_kincomps_plan_is_klippers(klippy, tmp_path, name, plane):
    config = klipper.stock_config(name, extra=FORCE_MOVE)
    text, spec, centre, settings = program_for(config, plane)
    lines = text.splitlines()
    res = klipper.run(klippy, config, [_start(centre)] + lines, tmp_path, record_moves=True)
    assert res.ok, (res.errors, res.log_tail)
    plan = plan_program(lines, centre, settings)
    for ours, theirs in zip(kincomp_arc_times(plan, lines), klipper_arc_times(res, lines)):
        tol = 0.5 * max(SYNC_TOLERANCE_MS, SYNC_TOLERANCE_SHARE * ours * 1e3)
        assert abs(theirs - ours) * 1e3 <= tol, (theirs, ours)
    # and line by line: the whole program, travel and lift included
    theirs = res.line_times()
    dur = plan.ta + plan.tc + plan.td
    ours = {}
    for k in range(len(dur)):
        if plan.f[k] > 0:
            ours[int(plan.line[k]) + 1] = ours.get(int(plan.line[k]) + 1, 0.0) + float(dur[k])
    worst = max(abs(theirs.get(ln, 0.0) - t) for ln, t in ours.items())
    assert worst < 1e-6, worst  # s


PARAMS = Params.from_dict({"squareness_um_per_m": {"xy": 1500.0, "xz": -800.0, "yz": 600.0}})


def _steps_per_mm(config):
    v = klipper.config_values(config)
    out = {}
    for axis in "xyz":
        s = v["stepper_" + axis]
        full = float(s.get("full_steps_per_rotation", 200))
        out[axis] = full * float(s["microsteps"]) / float(s["rotation_distance"])
    return out


def _compensated(lines):
    """The program compensated by KinComp (the reference path, squareness only, 3 decimals),
    and for each input line the number of the output line that ends it (1-based)."""
    _, groups = compensate_groups(PARAMS, lines)
    out, last = [], {}
    for i, (_, produced) in enumerate(groups, 1):
        out.extend(produced)
        last[i] = len(out)
    return out, last


def test_compensation_equals_klippers_own_skew_correction(klippy, tmp_path):
    """A vertical test (X, Y and Z all move) and the XY test: KinComp's compensated program
    on plain Klipper, and the program as written on Klipper with ``SET_SKEW`` of the same
    squareness (KinComp's own export of it), end every move within one step of each other."""
    name = "printer-creality-ender3-v2-2020.cfg"
    plain = klipper.stock_config(name)
    skewed = klipper.stock_config(name, add=("skew_correction",))
    spm = _steps_per_mm(plain)
    lines = []
    for plane in ("YZ", "XY"):
        lines += program_for(plain, plane)[0].splitlines()
    # both: homed, then a known point inside the box; there Klipper's skew is switched on
    # (SET_SKEW does not move the head: the next move takes up the difference)
    head = ["G28", "G1 X117.5 Y117.5 Z30 F3000"]
    written = head + [equivalents(PARAMS)["klipper"][0], head[1]] + lines
    comp, last = _compensated(head + [head[1]] + lines)
    a = klipper.run(klippy, skewed, written, tmp_path / "klipper_skew")
    b = klipper.run(klippy, plain, comp, tmp_path / "kincomp")
    assert a.ok and b.ok, (a.errors, b.errors)
    pa = {ln: tool for ln, tool, _ in a.positions}
    pb = {ln: tool for ln, tool, _ in b.positions}
    compared = 0
    for i in range(len(head) + 2, len(written) + 1):  # the program's lines
        if i not in pa:
            continue
        src = i - 1  # (the SET_SKEW line has no counterpart in the compensated input)
        out_line = last[src]
        assert out_line in pb, (i, written[i - 1])
        for k, axis in enumerate("xyz"):
            assert abs(pa[i][k] - pb[out_line][k]) <= 1.0 / spm[axis], (i, axis)
        compared += 1
    assert compared > 1500
    for stepper in ("stepper_x", "stepper_y", "stepper_z"):
        assert abs(a.final["mcu"][stepper] - b.final["mcu"][stepper]) <= 1, stepper


def _sd_print(klippy, tmp_path, config_name, text, cut_after):
    """Prints the first lines of ``text`` (up to ``cut_after`` lines past its mount pause)
    from Klipper's SD card; the head's last planned position."""
    sd = tmp_path / "sd"
    sd.mkdir(parents=True)
    lines = text.splitlines()
    pause = next(i for i, ln in enumerate(lines) if ln.startswith(("PAUSE", "M0")))
    (sd / "test.gcode").write_text("\n".join(lines[: pause + 1 + cut_after]) + "\n")
    extra = f"{FORCE_MOVE}\n[pause_resume]\n[virtual_sdcard]\npath: {sd}"
    config = klipper.stock_config(config_name, extra=extra)
    res = klipper.run(
        klippy,
        config,
        ["SDCARD_PRINT_FILE FILENAME=test.gcode"],
        tmp_path / "run",
        record_moves=True,
        positions=False,
        final_position=False,
    )
    assert res.ok, (res.errors, res.log_tail)
    return [m["p1"][:3] for m in res.moves if m["kin"]][-1], res.responses


def test_the_mount_pause_holds_a_print_from_klippers_sd_card(klippy, tmp_path):
    """The program for Klipper waits at its PAUSE with the head at the test height; the same
    program with Marlin's M0 goes on to the first run without the bar (issue 36's case)."""
    name = "printer-creality-ender3-v2-2020.cfg"
    config = klipper.stock_config(name)
    for pause in ("PAUSE", "M0"):
        text, spec, centre, _ = program_for(config, "XY", mount_pause=True, pause_command=pause)
        sd_text = _start(centre) + "\n" + text
        end, responses = _sd_print(klippy, tmp_path / pause, name, sd_text, cut_after=6)
        start = spec.point(-spec.overshoot_deg, spec.radius_mm + spec.feed_in_mm)
        at_pause = math.dist(end, start)
        if pause == "PAUSE":
            assert at_pause < 1e-3  # waiting where the bar is mounted (4-decimal program)
        else:
            assert at_pause > 0.5  # went on: the radial feed-in ran without the bar
            assert any('Unknown command:"M0"' in t for _, t in responses)
