"""Every engine gives exactly what the reference path gives (issue 5).

The engines: the compiled kernel per line (the queuing hook) and over blocks of a file (the
file loop, engines/file_loop.py), and without it the reference path over the same file loop
(the shapes below were once the retired numpy engine's hard cases). Each must produce the
same text and report as the reference compensator, line by line, on real slicer files and on
awkward generated programs. Tests that take the ``engine`` fixture run once per engine."""

import copy
import hashlib
import io
import math
import os
import random

import pytest

from octoprint_kincomp.core.compensator import Compensator, LimitError, Options
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines import file_loop as fastfile
from octoprint_kincomp.engines import select
from octoprint_kincomp.engines.file_loop import compensate_binary, marker_line
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.tools.benchmark import BENCH_PARAMS, generate
from octoprint_kincomp.tools.line_path import compensate_lines
from tests.support import DATA as SAMPLES
from tests.support.gcodegen import random_program

PARAMS = [
    Params.from_dict(BENCH_PARAMS),
    Params.from_dict(
        {
            "squareness_um_per_m": {"xy": 300, "xz": -120},
            "scale_ppm": {"x": 100, "z": -50},
            "backlash": {"y": 12.0},
        }
    ),
    Params.from_dict({"backlash": {"x": 30.0, "z": 5.0, "fraction": 0.7}}),
]
OPTIONS = [
    Options(),
    Options(limits=(0, 200, 0, 200, 0, 250), policy="clamp"),
    Options(limits=(0, 200, 0, 200, 0, 250), policy="warn", decimals=4),
]


# the reference path's (text, report) by (the text, the parameters, the options): a test
# that runs once per engine computes it once (it is a pure function of the three)
_REFERENCE = {}


def general(text: str, params, options):
    """The reference path: every line through Compensator.process, no engine."""
    key = (
        hashlib.sha256(text.encode(ENCODING, ERRORS)).hexdigest(),
        params.to_json(),
        repr(options),
    )
    if key not in _REFERENCE:
        comp = Compensator(params, options)
        out = "".join(compensate_lines(io.StringIO(text, newline=""), comp, marker_line(params)))
        _REFERENCE[key] = (out, comp.report.to_dict())
    out, report = _REFERENCE[key]
    return out, copy.deepcopy(report)


def per_line(text: str, params, options):
    """Line by line through a compensator of the engine in use (the queuing hook's way)."""
    comp = make_compensator(params, options)
    assert (comp.fast is not None) == (select.engine() == "compiled" and comp.accelerable)
    out = "".join(compensate_lines(io.StringIO(text, newline=""), comp, marker_line(params)))
    return out, comp.report.to_dict()


def whole_file(text: str, params, options, chunk=None):
    """The file engine of the engine in use (``chunk``: its block size, bytes)."""
    if chunk:
        old = fastfile.CHUNK_BYTES
        fastfile.CHUNK_BYTES = chunk
    try:
        dst = io.BytesIO()
        rep = compensate_binary(io.BytesIO(text.encode(ENCODING, ERRORS)), dst, params, options)
    finally:
        if chunk:
            fastfile.CHUNK_BYTES = old
    return dst.getvalue().decode(ENCODING, ERRORS), rep.to_dict()


def check(text, params, options, chunk=None):
    """The engine in use, per line and on the whole file, equals the reference path."""
    ref = general(text, params, options)
    assert per_line(text, params, options) == ref
    assert whole_file(text, params, options, chunk) == ref


def sample(name):
    with open(os.path.join(SAMPLES, name), encoding=ENCODING, errors=ERRORS, newline="") as f:
        return f.read()


@pytest.mark.parametrize("params", PARAMS, ids=["bench", "skew", "backlash"])
@pytest.mark.parametrize("options", OPTIONS, ids=["plain", "clamp", "warn4"])
def test_real_slicer_files(params, options, engine):
    for name in ("bambustudio-a1-hook.gcode", "bambustudio-square-ring.gcode"):
        check(sample(name), params, options)


@pytest.mark.parametrize("seed", range(12))
def test_generated_awkward_programs(seed, engine):
    lines = random_program(seed, n=400, nasty=0.25 if seed % 2 else 0.02)
    params = PARAMS[seed % len(PARAMS)]
    options = OPTIONS[seed % len(OPTIONS)]
    for ending in ("\n", "\r\n"):
        text = ending.join(lines) + (ending if seed % 3 else "")
        # small chunks force chunk boundaries, segments and the short-run path
        check(text, params, options, chunk=997 if seed % 4 == 0 else None)


def test_benchmark_style_file(tmp_path, engine):
    path = tmp_path / "b.gcode"
    generate(str(path), 30000)
    text = path.read_text()
    for params in PARAMS:
        assert whole_file(text, params, Options()) == general(text, params, Options())


def test_benchmark_style_file_with_arcs(tmp_path, engine):
    path = tmp_path / "a.gcode"
    generate(str(path), 20000, arc_fraction=0.2)
    text = path.read_text()
    assert text.count("\nG2 ") + text.count("\nG3 ") > 2000
    # each arc starts where the head is: its end lies on its circle (no spirals)
    x = y = worst = 0.0
    for line in text.splitlines():
        w = {t[0]: float(t[1:]) for t in line.split()[1:] if t[0] in "XYIJ"}
        if line.startswith(("G2 ", "G3 ")):
            cx, cy = x + w["I"], y + w["J"]
            worst = max(
                worst, abs(math.hypot(w["I"], w["J"]) - math.hypot(w["X"] - cx, w["Y"] - cy))
            )
        if line.startswith("G"):
            x, y = w.get("X", x), w.get("Y", y)
    assert worst < 0.005
    for params in PARAMS:
        assert whole_file(text, params, Options()) == general(text, params, Options())


def test_trailing_space_on_the_last_line_of_a_block(engine):
    # review finding: the tokeniser's word sums indexed past the block's end
    for text in (
        "G28\nG1 X1 Y1 \n",
        "G28\nG2 X10 Y10 I5 J0\nG1 X1 Y1 \n",
        "G28\n" + "G1 X5 Y5\n" * 40 + "G1 X1 Y1 \n",
        "G28\nG1 X1 Y1 \r\n",
    ):
        check(text, PARAMS[0], Options())


def test_lone_cr_and_missing_newline(engine):
    text = "G28\rG1 X10 Y10 Z1\rG1 X20 Y5\r; c\rG1 X30 Y30"
    check(text, PARAMS[0], Options())
    check("G28\nG1 X10 Y10 Z1\nG1 X20 Y5", PARAMS[0], Options())


def test_limit_error_raised_at_the_same_line(engine):
    lines = ["G28", "G1 X10 Y100 Z1"] + [f"G1 X{50 + i % 7} Y{100 + i % 5}" for i in range(60)]
    lines += ["G1 X0 Y200", "G1 X10 Y10"]
    text = "\n".join(lines) + "\n"
    params = Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}})
    opts = Options(limits=(0, 200, 0, 200, 0, 250), policy="error")
    with pytest.raises(LimitError) as a:
        general(text, params, opts)
    with pytest.raises(LimitError) as b:
        whole_file(text, params, opts)
    assert str(a.value) == str(b.value)


def test_a_malformed_number_is_reported_on_every_engine(engine):
    comp = make_compensator(PARAMS[1])
    comp.process("G28")
    comp.process("G1 X1 Y1 Z1")
    assert comp.process("G1 X1.2.3 Y2") == "G1 X1.2.3 Y2"
    assert comp.report.malformed == 1


TRICKY_FAST_LINES = [
    "G1 X Y2",
    "G1 X+ Y2",
    "G1 X- Y2",
    "G1 X. Y2",
    "G1 X1-2 Y2",
    "G1 X1+ Y2",
    "G1 X--1 Y2",
    "G1 X1.2.3",
    "G1 X1 Y2 E",
    "G1 X1 Y2 F",
    "G1 F1 X1 F2",
    "G1 X1  Y2",
    "G1 X1 Y2 ",
    "G1 Y2 X1",
    "G1 X1 X2",
    "G1 X1e3 Y2",
    "G1 X12345678901234567890e5 Y2",  # (past the fast parser's 2**53: its slow path)
    "G1 X1_0 Y2",
    "G1 Xinf",
    "G1 Xnan Y1",
    "G1 X1 Y2\u2003",
    "G1 X1\u00a0Y2",
    "G1 X\u0661 Y2",
    "G1 X1 Y2 E0.5 F1200",
    "G0 F9000 X12.5 Y-3",
    "G1 X" + "9" * 95,
    "G1 X" + "9" * 99 + " Y1",
    "G1 E-0.8 F2400",
    "G1 F600",
    "G1 Z.4",
    "G1 X+.5 Y-.5 Z+0",
    "G1 X5. Y6.",
    "G1 X1 Y2 Z3 E4 F5",
    "G1 X1 Y2 *12",
    "G1 X1 Y2;c",
    "G1 X1 Y2 \udcff",
    "G1 x1 y2",
    "G1 X1 Y2 A3",
]


@pytest.mark.parametrize("params", PARAMS[:2], ids=["bench", "skew"])
def test_odd_line_shapes_agree_with_the_reference_path(params, engine):
    """The engines read lines by their shape and their own number parsers; on every odd
    spelling they either give the reference path's text and report, or leave the line to
    it."""
    for line in TRICKY_FAST_LINES:
        text = "G28\nG1 X10 Y10 Z1 E0\n" + line + "\nG1 X20 Y20\n"
        ref = general(text, params, Options())
        assert per_line(text, params, Options()) == ref, line
        assert whole_file(text, params, Options()) == ref, line


@pytest.mark.parametrize("params", PARAMS[:2], ids=["bench", "skew"])
def test_odd_lines_inside_long_runs_of_moves(params, engine):
    """The retired numpy engine classified a whole block at once: each odd spelling, in the
    middle of runs of plain moves long enough to be vectorised, is read as the reference
    path reads it."""
    lines = ["G28", "G1 X10 Y10 Z1 E0"]
    for i, odd in enumerate(TRICKY_FAST_LINES):
        lines += [
            f"G1 X{10 + (i + j) % 13}.{j * 37 % 1000:03d} Y{20 + j % 7}.5 E{i}.{j}"
            for j in range(30)
        ]
        lines.append(odd)
    for ending in ("\n", "\r\n"):
        check(ending.join(lines) + ending, params, Options())


def test_m_codes_with_leading_zeros_inside_long_runs(engine):
    # review finding: the retired numpy engine read M codes by their first three bytes, so
    # M048 (positions unknown) and M082/M083 (extruder mode), as int() reads them, passed
    # as inert lines
    def run(i):
        return [
            f"G1 X{10 + j % 13}.{j * 37 % 1000:03d} Y{20 + j % 7}.5 E{i + j * 0.01:.2f}"
            for j in range(30)
        ]

    for code in ("M048", "M082", "M083", "M0083", "M083 ; relative", "M00", "M0106 S1"):
        lines = ["G28", "G1 X10 Y10 Z1 E0"] + run(0) + [code] + run(1)
        lines += ["G2 X30 Y25 I5 J0 E3.5", "G1 X5 Y20", "G28"] + run(2)
        for options in (Options(), Options(linearise_arcs=True)):
            check("\n".join(lines) + "\n", PARAMS[0], options)


@pytest.mark.parametrize("policy", ["warn", "clamp"])
def test_limits_counted_once_when_a_run_leaves_the_number_tables(policy, engine):
    # review finding: a run with a coordinate beyond the number tables goes to the line
    # path, which counted its limit hits and points outside a second time
    lines = ["G28", "G1 X10 Y10 Z1"]
    lines += [f"G1 X{20 + j % 9} Y{30 + j % 5}" for j in range(30)]
    lines += ["G1 X12000 Y10", "G1 X0 Y190", "G1 X199.99 Y0"]
    lines += [f"G1 X{20 + j % 9} Y{30 + j % 5}" for j in range(30)]
    text = "\n".join(lines) + "\n"
    options = Options(limits=(0, 200, 0, 200, 0, 250), policy=policy)
    for params in (PARAMS[0], Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}})):
        check(text, params, options)
    rep = general(text, PARAMS[0], options)[1]
    assert rep["source_outside_limits"] == 1 and rep["limit_hits"] >= 1


def rows_program(seed: int) -> list:
    """Runs of plain moves in the shapes the retired numpy engine's rows took: input of every
    length before a move (comment lines up to 300 bytes: copied into its row, a row of its
    own, spliced in), leading F words, reversals (take-up moves), coordinates from negative
    to beyond its number tables (10,000 mm), and a part in inches."""
    rng = random.Random(seed)
    lines = ["G28", "G1 X10 Y10 Z1 F3000"]
    x, y = 10.0, 10.0
    for i in range(2500):
        if i == 2000:
            lines += ["G20", "G1 X1 Y1 Z0.1"]
            x, y = 1.0, 1.0
        r = rng.random()
        if r < 0.12:
            lines.append(";" + "c" * rng.choice([0, 3, 20, 40, 60, 100, 200, 300]))
        if r < 0.02:
            lines.append("M106 S255")  # (inert)
        x += rng.choice([-1, 1]) * rng.uniform(0, 40 if i < 2000 else 1.5)
        y += rng.uniform(-3, 3) * (1 if i < 2000 else 0.05)
        if 1500 < i < 1510:
            x = 12000.0 + i  # (beyond the number tables)
        dec = rng.choice([3, 3, 2, 5, 0])
        f = f"F{rng.choice([600, 1200, 9000])} " if rng.random() < 0.15 else ""
        tail = rng.choice(["", f" E{i * 0.0123:.5f}", f" E{i}.5 F4800", " ; note"])
        lines.append(f"G1 {f}X{x:.{dec}f} Y{y:.{dec}f}{tail}")
    return lines


# backlash that changes along the axis in three pieces (a table of four points)
TABLE_PARAMS = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": -900.0},
        "scale_ppm": {"x": 200.0},
        "backlash": {
            "x": [
                {"at_mm": 10, "um": 30},
                {"at_mm": 60, "um": 12},
                {"at_mm": 110, "um": 25},
                {"at_mm": 200, "um": 5},
            ],
            "y": 8.0,
        },
    }
)


@pytest.mark.parametrize("seed", range(3))
def test_rows_of_every_shape(seed, engine):
    lines = rows_program(seed)
    options = [Options(), Options(decimals=4), Options(decimals=8)][seed]
    for ending in ("\n", "\r\n"):
        check(ending.join(lines) + ending, PARAMS[0], options)
    check("\n".join(lines) + "\n", TABLE_PARAMS, options)
    # a NUL byte (the row assembly's filler) in a comment: that block goes line by line
    lines[1000] = "; a \x00 in a comment"
    check("\n".join(lines) + "\n", PARAMS[0], Options())


def arc_program(seed: int, n: int = 500, e_mode: str = "absolute", crlf=False) -> str:
    """Slicer-style perimeters with arcs (G2/G3 X Y I J E [F]) between G1 moves, in the
    shapes the file engine vectorises, and some it must leave to the compensator."""
    import math
    import random

    rng = random.Random(seed)
    head = ["G28", "G90", "M83" if e_mode == "relative" else "M82", "G1 Z0.3 F1200"]
    if e_mode == "absolute":
        head.insert(3, "G92 E0")
    lines = list(head)
    e = 0.0
    cx, cy, r = 100.0, 100.0, 20.0
    ang = 0.0
    x, y = cx + r, cy
    lines.append(f"G1 X{x:.3f} Y{y:.3f}")
    for _ in range(n):
        kind = rng.random()
        step = rng.uniform(0.02, 0.6) * rng.choice([1, 1, 1, -1])
        na = ang + step
        nx, ny = round(cx + r * math.cos(na), 3), round(cy + r * math.sin(na), 3)
        de = abs(step) * r * 0.033
        e_text = f"E{de:.5f}" if e_mode == "relative" else f"E{e + de:.5f}"
        e += de
        if kind < 0.45:
            code = "G3" if step > 0 else "G2"
            words = [f"X{nx:.3f}", f"Y{ny:.3f}", f"I{cx - x:.3f}", f"J{cy - y:.3f}"]
            if rng.random() < 0.9:
                words.append(e_text)
            if rng.random() < 0.15:
                words.append(f"F{rng.choice([1200, 3000])}")
            if rng.random() < 0.03:
                words = words[2:4] + words[4:]  # a full circle: I/J only
                nx, ny = x, y
            line = code + " " + " ".join(words)
            if rng.random() < 0.03:
                line += " ; not simple"  # commented arcs take the line path
        elif kind < 0.9:
            line = f"G1 X{nx:.3f} Y{ny:.3f} {e_text}"
        elif kind < 0.95:
            line = "G1 E-0.8 F2400" if e_mode == "relative" else f"G1 E{e - 0.8:.5f} F2400"
            e -= 0.8 if e_mode == "absolute" else 0
            nx, ny = x, y
        else:
            r = rng.uniform(5, 60)
            nx, ny, na = round(cx + r * math.cos(ang), 3), round(cy + r * math.sin(ang), 3), ang
            line = f"G0 X{nx:.3f} Y{ny:.3f} F9000"
        lines.append(line)
        x, y, ang = nx, ny, na
    end = "\r\n" if crlf else "\n"
    return end.join(lines) + end


ARC_PARAMS = PARAMS + [
    Params.from_dict({"squareness_um_per_m": {"xy": 800.0}}),  # no backlash
    Params.from_dict({"backlash": {"x": 25.0, "y": 25.0}}),  # backlash only
]


@pytest.mark.parametrize("seed", range(8))
def test_arc_files_give_the_same_output(seed, engine):
    params = ARC_PARAMS[seed % len(ARC_PARAMS)]
    options = OPTIONS[seed % len(OPTIONS)]
    text = arc_program(seed, e_mode=("absolute", "relative")[seed % 2], crlf=seed % 3 == 0)
    ref = general(text, params, options)
    assert per_line(text, params, options) == ref
    assert whole_file(text, params, options, 4093 if seed % 2 else None) == ref
    rep = ref[1]
    assert rep["arcs_kept"] + rep["arcs_split"] + rep["arcs_linearised"] > 100
    if options.limits is None:
        assert rep["arcs_kept"] > 100  # kept as arcs


def test_arc_files_with_linearised_arcs_give_the_same_output(engine):
    text = arc_program(3)
    options = Options(linearise_arcs=True)
    ref = general(text, ARC_PARAMS[0], options)
    assert per_line(text, ARC_PARAMS[0], options) == ref
    assert whole_file(text, ARC_PARAMS[0], options) == ref
    assert ref[1]["arcs_linearised"] > 100 and ref[1]["arcs_kept"] == 0


def test_arcs_with_absolute_e_from_an_unknown_position_take_the_line_path(engine):
    # no G92 E0 and no E before the arcs: the line path passes such arcs as written
    lines = ["G28", "G1 X120 Y100 Z0.3"] + [
        f"G3 X{100 + 20 * __import__('math').cos(a / 10):.3f} "
        f"Y{100 + 20 * __import__('math').sin(a / 10):.3f} I-20 J0 E{a:.5f}"
        for a in range(1, 40)
    ]
    text = "\n".join(lines) + "\n"
    for params in ARC_PARAMS:
        assert whole_file(text, params, Options()) == general(text, params, Options())


def test_reversal_at_the_deadband_edge_is_decided_like_the_tracker(engine):
    """A retreat of the deadband plus an ulp (review finding): the numpy engine's shortcut used
    step < -db where the tracker compares q < anchor - db; they round differently there."""
    p = Params.from_dict({"backlash": {"x": 30.0}})
    for lines, opts in (
        (["G28", "G1 X0.0001 Y10 Z1", "G1 X0.0004", "G1 X0.000399"], Options()),
        (["G28", "G1 X1 Y10 Z1", "G1 X2", "G1 X1.998"], Options(deadband_mm=0.002)),
    ):
        text = "\n".join(lines + [f"G1 X{3 + i}" for i in range(30)]) + "\n"
        check(text, p, opts)


def test_limit_examples_of_arc_chords_come_in_emission_order(engine):
    import math

    p = Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}})
    t = math.pi - 0.04
    sx, sy = 1000 + 1000 * math.cos(t), 100 + 1000 * math.sin(t)
    lines = [
        "G28",
        f"G1 X{sx:.3f} Y{sy:.3f} Z1",
        f"G3 X0 Y100 I{1000 - sx:.3f} J{100 - sy:.3f}",
    ] + [f"G1 X{3 + i} Y100" for i in range(30)]
    text = "\n".join(lines) + "\n"
    for policy in ("warn", "clamp"):
        opts = Options(limits=(0, 300, 0, 300, 0, 300), policy=policy)
        ref = general(text, p, opts)
        assert len(ref[1]["limit_examples"]) >= 3
        assert whole_file(text, p, opts) == ref


def test_relative_e_adds_up_in_long_runs_like_the_reference(engine):
    """Issue 28: relative E is summed into the E position (Marlin); the file engine sums a
    run of moves as the reference path does line by line, and the absolute-E arc after
    M83, G91 and G90 is split from that sum on every engine."""
    moves = [
        f"G1 X{50 + (i % 7) * 3.1:.3f} Y{60 + (i % 5) * 2.3:.3f} E0.0{i % 9 + 1}" for i in range(60)
    ]
    text = "\n".join(
        ["G28", "G90", "G92 E0", "M83", "G1 X50 Y50 Z1 F3000"]
        + moves
        + ["G91", "G1 Z0.2 E-0.5", "G90", "G2 X70 Y50 I10 J0 E9.5"]
        + moves[:30]
        + ["G90", "G3 X50 Y50 I-10 J0 E12.25", ""]
    )
    for params in PARAMS:
        check(text, params, Options())
    ref, rep = general(text, PARAMS[1], Options())
    assert rep["untouched_unknown_position"] == 0
