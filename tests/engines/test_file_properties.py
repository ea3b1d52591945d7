"""Property tests (hypothesis) for the file engines: over generated G-code files (runs of
plain slicer moves, arcs, modal changes, odd line endings, chunk boundaries), the file engine
of each engine (the compiled kernel over blocks, the reference path over blocks) writes the
same bytes and report as the per-line reference path (``Compensator.process`` alone)."""

import io
import re

from hypothesis import example, given
from hypothesis import strategies as st

from octoprint_kincomp.core.compensator import Compensator, LimitError, Options
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines import file_loop as fastfile
from octoprint_kincomp.engines.file_loop import compensate_binary, marker_line
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.tools.line_path import compensate_lines
from tests.core.test_properties import any_line, cfg, params

# -- the file engines are the per-line reference path ------------------------------------


@st.composite
def plain_run(draw):
    """A run of plain slicer-style moves (what the kernel takes)."""
    n = draw(st.integers(1, 60))
    x, y, z, e = (draw(st.floats(0, 200)), draw(st.floats(0, 200)), draw(st.floats(0.2, 5)), 0.0)
    dec = draw(st.sampled_from([3, 3, 2, 4, 0, 1]))
    out = []
    for _ in range(n):
        kind = draw(st.integers(0, 9))
        x = min(230, max(-20, x + draw(st.floats(-30, 30))))
        y = min(230, max(-20, y + draw(st.floats(-30, 30))))
        e += draw(st.floats(0, 2))
        if kind < 6:
            line = f"G1 X{x:.{dec}f} Y{y:.{dec}f} E{e:.5f}"
        elif kind == 6:
            line = f"G0 F9000 X{x:.{dec}f} Y{y:.{dec}f}"
        elif kind == 7:
            z += 0.2
            line = f"G1 Z{z:.2f} F600"
        elif kind == 8:
            line = f"G1 X{x:.{dec}f}"
        else:
            line = f"G1 Y{y:.{dec}f} F{draw(st.sampled_from([1200, 1800, 3000]))}"
        if draw(st.integers(0, 9)) == 0:
            line += " ; note"
        out.append(line)
    return out


@st.composite
def gcode_file(draw):
    lines = ["G28", "G1 X100 Y100 Z0.3 F3000"] if draw(st.integers(0, 5)) else []
    for _ in range(draw(st.integers(1, 8))):
        if draw(st.booleans()):
            lines += draw(plain_run())
        else:
            lines += [line for line, _ in draw(st.lists(any_line(text_ok=False), max_size=4))]
    if lines and draw(st.integers(0, 5)) == 0:  # bytes that are not UTF-8
        i = draw(st.integers(0, len(lines) - 1))
        lines[i] += "\udcff\udcc3"
    endings = draw(st.sampled_from(["\n", "\n", "\r\n", "\r\n", "mixed", "\r"]))
    if endings == "mixed":
        ends = [draw(st.sampled_from(["\n", "\r\n", "\n", "\r"])) for _ in lines]
    else:
        ends = [endings] * len(lines)
    if ends and not draw(st.booleans()):
        ends[-1] = ""  # no final newline
    return "".join(a + b for a, b in zip(lines, ends))


def _per_line(text, p, opts, comp):
    try:
        out = "".join(compensate_lines(io.StringIO(text, newline=""), comp, marker_line(p)))
    except LimitError as exc:
        return "error", str(exc)
    return out.encode(ENCODING, ERRORS), comp.report.to_dict()


def _file(text, p, opts, chunk):
    old = fastfile.CHUNK_BYTES
    fastfile.CHUNK_BYTES = chunk or old
    try:
        dst = io.BytesIO()
        rep = compensate_binary(io.BytesIO(text.encode(ENCODING, ERRORS)), dst, p, opts)
    except LimitError as exc:
        return "error", str(exc)
    finally:
        fastfile.CHUNK_BYTES = old
    return dst.getvalue(), rep.to_dict()


@st.composite
def engine_options(draw):
    kw = {"decimals": draw(st.integers(3, 6))}
    if draw(st.booleans()):
        kw["limits"] = (0, 200, 0, 200, 0, 250)
        kw["policy"] = draw(st.sampled_from(["warn", "clamp", "error"]))
    return Options(**kw)


UNICODE_INDENT_FILE = (
    "G28\nG1 X10 Y10 Z1\n"
    + "".join(f"G1 X{i} Y{i}\n" for i in range(10, 40))
    + "\xa0G1 X50 Y50\n"
    + "".join(f"G1 X{i} Y1\n" for i in range(30))
)


@cfg(80)
@given(gcode_file(), params(), engine_options(), st.sampled_from([None, None, 97, 1000]))
@example(
    UNICODE_INDENT_FILE, Params.from_dict({"squareness_um_per_m": {"xy": 3000}}), Options(), None
)
@example(
    UNICODE_INDENT_FILE.replace("\xa0", "\x1c").replace("\n", "\r\n"),
    Params.from_dict({"squareness_um_per_m": {"xy": 3000}}),
    Options(),
    None,
)
# a last line ending in a lone CR that expands into a take-up and a move (and a CR-only file
# of one line): the pieces are joined with that CR, not CRLF
@example(
    "G28\nG1 X1 Y1\r",
    Params.from_dict({"backlash": {"y": 0.5, "smoothing_mm": 0.1}}),
    Options(),
    None,
)
@example("G28\rG1 X1 Y1\r", Params.from_dict({"backlash": {"y": 20.0}}), Options(), 3)
@example("\r", Params.from_dict({"backlash": {"y": 20.0}}), Options(), None)
def test_file_engine_matches_the_per_line_reference(engine, text, p, opts, chunk):
    ref = _per_line(text, p, opts, Compensator(p, opts))  # the reference path alone
    assert _per_line(text, p, opts, make_compensator(p, opts)) == ref  # the hook's way
    got = _file(text, p, opts, chunk)
    if ref[0] != "error" and got[0] != "error" and got[0] != ref[0]:
        a, b = ref[0], got[0]
        i = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
        assert a == b, (
            "first difference at byte",
            i,
            a[max(0, i - 60) : i + 60],
            b[max(0, i - 60) : i + 60],
        )
    assert got == ref
    if ref[0] != "error":
        # line structure: the marker line, then one or more lines per input line, each with
        # its input line's ending (an unterminated last line stays unterminated)
        unterminated = bool(text) and not re.search(r"[\r\n]\Z", text)
        assert ref[1]["lines"] == len(re.findall(r"\r\n|\r|\n", text)) + unterminated
        out_endings = len(re.findall(rb"\r\n|\r|\n", ref[0]))
        assert out_endings == (1 + ref[1]["lines_out"] - unterminated if text else 0)
