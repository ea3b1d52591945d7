"""Property tests (hypothesis) for the streaming compensator and the file loop.

Generated G-code streams mix G0/G1/G2/G3 (IJ and R forms, P turns), G90/G91, G92 (with and
without axes, G92 E0, G92.1), G20/G21, M82/M83, G28, planes, comments, blank lines, odd
spacing, lowercase, ``N<n> ... *<checksum>``, unknown commands and garbage. Properties:

* every input line maps to its own output lines, in order; non-motion lines come back
  unchanged; E, F, comment and indentation of motion lines are kept (E split over pieces
  sums up, or ends on the written value, as the compensator documents);
* all-zero parameters give every line back untouched (per line and per file);
* compensated programs replayed on a printer with the same errors land on the points the
  program asks for (1e-6 mm at 6 decimals), also with backlash;
* no input line, however broken, makes the compensator raise; malformed motion lines pass
  unchanged and are counted;
* (tests/engines/test_file_properties.py: the file engines write the same bytes and report
  as the per-line reference path.)

Every property runs on each engine (the ``engine`` fixture: the compiled kernel and the
pure-Python paths).

The oracle for "where the program asks the head to go" is the firmware-like interpreter
(:mod:`octoprint_kincomp.firmware.interpreter`); the printer replays the output with the true errors
(:class:`tests.support.helpers.Printer`). Everything is derandomised for reproducible CI runs.
"""

import copy
import io
import math
import os
import re
from functools import reduce

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from octoprint_kincomp.core import arcs
from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.kinematics import changes_nothing
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.file_loop import compensate_binary, marker_line
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter
from octoprint_kincomp.simulator.play import Play
from tests.support.helpers import Printer, dist

# Reproducible by default (derandomised, no example database, no deadline for slow CI
# runners). KINCOMP_FUZZ_SCALE=N runs N times the examples with fresh random seeds (a deeper,
# non-reproducible exploration; failures print the example to turn into an @example).
SCALE = int(os.environ.get("KINCOMP_FUZZ_SCALE", "0") or 0)
BASE = settings(
    deadline=None,
    derandomize=not SCALE,
    database=None,
    print_blob=False,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.filter_too_much,
        HealthCheck.function_scoped_fixture,
    ],
)

# every test here runs once per engine (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("engine")


def cfg(n: int) -> settings:
    return settings(BASE, max_examples=n * max(1, SCALE))


# -- an independent reading of the text (not the project's parser) ---------------------------

_MOTION = re.compile(r"\s*(?:[Nn]\s*\d+\s*)?[Gg]\s*0*[0-3](?![\d.])")
_FIRMWARE_MOTION = re.compile(_MOTION.pattern, re.ASCII)
_MODAL = re.compile(r"\s*(?:[Nn]\s*\d+\s*)?([GgMm])\s*(\d+)(?![\d.])")
_OUT_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_CLEAN = re.compile(r"[Gg]\s*\d+(?:\s*[A-Za-z]\s*[-+]?(?:\d+\.?\d*|\.\d+))*\s*")


def is_motion_text(line: str) -> bool:
    """G0..G3 (any spelling) after an optional line number: the only lines it may rewrite."""
    return _MOTION.match(line.split(";", 1)[0]) is not None


def well_formed(piece: str) -> bool:
    """A rewritten piece is clean G-code: a code, then letter+number words (no inf/nan)."""
    return _CLEAN.fullmatch(piece.split(";", 1)[0].strip()) is not None


def out_words(line: str):
    """[(LETTER, value text)] of an output line's code part (after its G code)."""
    code = line.split(";", 1)[0].strip()
    code = re.sub(r"^[Gg]\s*\d+", "", code)
    return [(a.upper(), v) for a, v in _OUT_WORD.findall(code)]


class EMode:
    """Tracks G90/G91/M82/M83 from the text (Marlin's rule, the compensator's default: G90/G91
    reset an M82/M83 override; without one, E follows G90/G91)."""

    def __init__(self):
        self.absolute = True
        self.e_override = None

    def feed(self, line: str) -> None:
        m = _MODAL.match(line.split(";", 1)[0])
        if not m:
            return
        kind, num = m.group(1).upper(), int(m.group(2))
        if kind == "G" and num in (90, 91):
            self.absolute = num == 90
            self.e_override = None
        elif kind == "M" and num in (82, 83):
            self.e_override = num == 82

    @property
    def e_relative(self) -> bool:
        return not self.e_override if self.e_override is not None else not self.absolute


# -- generators ------------------------------------------------------------------------------


def _num_text(v: float, dec: int, style: str) -> str:
    t = f"{v:.{dec}f}"
    if style == "plus" and not t.startswith("-"):
        t = "+" + t
    elif style == "dot" and dec == 0:
        t += "."
    elif style == "bare" and re.match(r"-?0\.", t):
        t = t.replace("0.", ".", 1)
    return t


def number(lo, hi, max_dec=4):
    return st.builds(
        _num_text,
        st.floats(lo, hi, allow_nan=False, allow_infinity=False),
        st.integers(0, max_dec),
        st.sampled_from(["", "", "", "plus", "dot", "bare"]),
    )


# Indentation: ASCII blanks (a command), and other Unicode whitespace: the firmware reads
# such a line as no command (core/gcode.py, firmware/interpreter.py), so it passes as written.
INDENTS = ["", "", "", "", " ", "  ", "\t", "\x0b", "\xa0", "\u2003", "\x1c", "\x85"]
COMMENT_TEXT = st.text(
    st.characters(
        blacklist_categories=("Cs",), blacklist_characters="\r\n\x1c\x1d\x1e\x85\u2028\u2029"
    ),
    max_size=12,
)


def _checksum(text: str) -> int:
    return reduce(lambda a, b: a ^ b, text.encode("utf-8", "surrogateescape"), 0)


@st.composite
def decorate(draw, code: str, words, plain=False):
    """Render a command with the spellings firmware accepts: case, spacing, packed words,
    ``N<n> ... *<checksum>``, indentation and a trailing comment. Returns (line, info)."""
    if plain:
        return code + "".join(" " + a + v for a, v in words), {
            "indent": "",
            "comment": "",
            "numbered": False,
        }
    case = draw(st.sampled_from(["upper"] * 5 + ["lower", "mixed"]))
    parts = [code.lower() if case == "lower" else code]
    for a, v in words:
        sep = draw(st.sampled_from([" "] * 6 + ["  ", "\t", ""]))
        if case == "lower" or (case == "mixed" and draw(st.booleans())):
            a = a.lower()
        gap = " " if v and draw(st.integers(0, 19)) == 0 else ""
        parts.append(sep + a + gap + v)
    body = "".join(parts)
    numbered = draw(st.integers(0, 5)) == 0
    if numbered:
        n = draw(st.integers(0, 99999))
        body = f"N{n} {body}"
        cs = _checksum(body)
        if draw(st.integers(0, 4)) == 0:
            cs = (cs + 1) % 256  # a wrong checksum: not ours to judge
        body += f"*{cs}"
    comment = ""
    if draw(st.integers(0, 3)) == 0:
        comment = draw(st.sampled_from([";", "; ", " ;", " ; "])).lstrip() + draw(COMMENT_TEXT)
        body += draw(st.sampled_from([" ", "", "  "])) + comment
    indent = draw(st.sampled_from(INDENTS))
    return indent + body, {"indent": indent, "comment": comment, "numbered": numbered}


COORD = number(-50, 300)
EVAL = number(-5, 60, 5)
FVAL = number(60, 20000, 1)


@st.composite
def motion(draw, plain=False):
    """A valid G0/G1 or G2/G3 line; info records its E/F words."""
    arc = draw(st.integers(0, 3)) == 0
    if arc:
        code = draw(st.sampled_from(["G2", "G3", "G02", "G03"]))
    else:
        code = draw(st.sampled_from(["G1", "G1", "G1", "G0", "G01", "G00"]))
    words = []
    for a in "XYZ":
        if draw(st.booleans()):
            words.append((a, draw(COORD)))
    if arc:
        if draw(st.booleans()):
            for a in draw(st.sampled_from(["IJ", "I", "J", "JK", "KI"])):
                words.append((a, draw(number(-60, 60, 3).filter(lambda t: float(t) != 0))))
        else:
            words.append(("R", draw(number(-150, 150, 3).filter(lambda t: float(t) != 0))))
        if draw(st.integers(0, 5)) == 0:
            words.append(("P", str(draw(st.integers(0, 2)))))
    e = draw(EVAL) if draw(st.booleans()) else None
    f = draw(FVAL) if draw(st.integers(0, 2)) == 0 else None
    tail = [("E", e)] if e is not None else []
    if f is not None:
        tail.append(("F", f))
    if not arc and f is not None and draw(st.integers(0, 3)) == 0:
        tail = tail[-1:] + tail[:-1]  # F before E
        if draw(st.booleans()):
            words, tail = tail[:1] + words, tail[1:]  # slicers' "G1 F1800 X.. Y.."
    if not plain and draw(st.integers(0, 6)) == 0:
        words = draw(st.permutations(words))  # any word order is G-code too
    line, info = draw(decorate(code, words + tail, plain))
    info.update(kind="arc" if arc else "move", e=e, f=f)
    return line, info


MODAL_LINES = [
    "G90",
    "G91",
    "G20",
    "G21",
    "M82",
    "M83",
    "G92 E0",
    "G92",
    "G92 X10 Y10",
    "G92 Z0.3",
    "G92.1",
    "G28",
    "G28 X",
    "G28 X Y",
    "G28 Z",
    "G17",
    "G18",
    "G19",
    "G90.1",
    "G91.1",
]
OTHER_LINES = [
    "M104 S200",
    "M106 S255",
    "G4 P100",
    "T0",
    "T1",
    "G29",
    "G29.2 S0",
    "M48",
    "M620.1 E F523 T240",
    "M117 Hello; world",
    "G2814 Z0.32",
    "M1002 judge_flag x",
    "G38.2 Z-5",
    "SET_SKEW CLEAR=1",
    "%",
    "M400",
    "G1.5 X3",
    "; comment",
    "",
    "   ",
    ";",
    "(paren comment)",
    "M83.1",
]
# Motion lines that are not G-code whatever the state: passed unchanged, counted malformed.
MALFORMED = [
    "G1 X1..2",
    "G1 Xabc",
    "G1 X1 X2",
    "G1 X",
    "G1 X10 #",
    "G0 X1.2.3 Y2",
    "G1 X10 Y10 (c)",
    "G2 X1 Y1 I1 I2",
    "G3 X5 J",
    "G1 E1.2.3",
    "g1 x1 x2",
    "G1 X--1",
    "G1 X1 Y2 Z",
    "N7 G1 X1 X2*12",
    "G1 X1 X2 ; c ; G1 X3",
    "G92 X1..2",
    "G1 X" + "9" * 400,
    "G2 X10 Y10 I" + "9" * 400 + " J0",
]
GARBAGE = st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=30)
UNICODE_LINE = st.text(
    st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n"), max_size=30
)


@st.composite
def malformed(draw):
    """A motion line made malformed on purpose (repeated letter, junk token, bare letter)."""
    line, info = draw(motion(plain=True))
    how = draw(st.sampled_from(["dup", "junk", "bare", "hash"]))
    cut = line
    if how == "dup":
        letter = draw(st.sampled_from("XYZEF"))
        cut += f" {letter}1 {letter}2"
    elif how == "junk":
        cut += " " + draw(st.sampled_from(["X1..2", "Yabc", "Z1.2.3", "Q", "E-", "F+."]))
    elif how == "bare":
        cut += " " + draw(st.sampled_from(["S", "A", "X"]))
    else:
        cut += " #" + draw(GARBAGE)
    return cut, {"kind": "malformed"}


@st.composite
def any_line(draw, text_ok=True):
    pick = draw(st.integers(0, 19))
    if pick < 9:
        return draw(motion())
    if pick < 13:
        return draw(st.sampled_from(MODAL_LINES)), {"kind": "modal"}
    if pick < 15:
        return draw(st.sampled_from(OTHER_LINES)), {"kind": "other"}
    if pick < 17:
        if draw(st.booleans()):
            return draw(st.sampled_from(MALFORMED)), {"kind": "malformed"}
        return draw(malformed())
    if pick < 19 or not text_ok:
        return draw(GARBAGE.filter(lambda s: "\r" not in s)), {"kind": "garbage"}
    return draw(UNICODE_LINE), {"kind": "garbage"}


@st.composite
def stream(draw, min_size=1, max_size=40):
    lines = [("G28", {"kind": "modal"})] if draw(st.integers(0, 4)) else []
    # E modes: relative extrusion, or absolute from a defined E (else arcs with E pass)
    lines += [
        (m, {"kind": "modal"})
        for m in draw(st.sampled_from([(), ("M83",), ("G92 E0",), ("M82", "G92 E0")]))
    ]
    lines += draw(st.lists(any_line(), min_size=min_size, max_size=max_size))
    return lines


def um(max_abs):
    return st.one_of(st.just(0.0), st.floats(-max_abs, max_abs, allow_nan=False))


@st.composite
def geometry(draw, max_sq=5000.0, max_scale=5000.0):
    return {
        "squareness_um_per_m": {k: draw(um(max_sq)) for k in ("xy", "xz", "yz")},
        "scale_ppm": {k: draw(um(max_scale)) for k in "xyz"},
    }


@st.composite
def backlash(draw, tables=True, fraction=True, smoothing=True):
    d = {}
    for a in "xyz":
        kind = draw(
            st.sampled_from(
                ["none", "const", "const", "table"] if tables else ["none", "const", "const"]
            )
        )
        if kind == "const":
            d[a] = draw(st.floats(0.5, 120.0))
        elif kind == "table":
            d[a] = [
                {"at_mm": 10.0, "um": draw(st.floats(0.0, 80.0))},
                {"at_mm": 210.0, "um": draw(st.floats(0.0, 80.0))},
            ]
    if fraction and draw(st.booleans()):
        d["fraction"] = draw(st.floats(0.0, 1.0))
    if smoothing and draw(st.integers(0, 3)) == 0:
        d["smoothing_mm"] = draw(st.floats(0.1, 5.0))
    return d


@st.composite
def params(draw, with_backlash=True):
    d = draw(geometry())
    if with_backlash and draw(st.booleans()):
        d["backlash"] = draw(backlash())
    return Params.from_dict(d)


@st.composite
def options(draw):
    kw = {
        "decimals": draw(st.integers(3, 8)),
        "chord_tol_mm": draw(st.sampled_from([0.01, 0.05, 0.5])),
    }
    if draw(st.integers(0, 3)) == 0:
        kw["limits"] = (0, 200, 0, 200, 0, 250)
        kw["policy"] = draw(st.sampled_from(["warn", "clamp"]))
    return Options(**kw)


# -- 1. every line accounted for -------------------------------------------------------------


def _outputs(out, line):
    assert isinstance(out, (str, list)), type(out)
    if isinstance(out, str):
        assert out is line, "a changed line must come as a list"
        return [line]
    assert out and all(isinstance(o, str) for o in out)
    return out


def check_motion_group(line, info, outs, mode: EMode):
    """E, F, comment, indentation and line numbers of one rewritten motion line."""
    indent = info["indent"]
    for o in outs:
        assert o.startswith(indent)
        body = o[len(indent) :]
        assert re.match(r"[Gg]0*[0-3](?![\d.])", body), (line, o)  # moves stay moves
        assert well_formed(body), (line, o)
        assert "*" not in body.split(";")[0] and not body.startswith(("N", "n")), (line, o)
    comment = info["comment"]
    if comment:
        assert sum(o.endswith(comment) for o in outs) == 1, (line, outs)
    else:
        assert all(";" not in o for o in outs), (line, outs)
    words = [out_words(o) for o in outs]
    fs = [v for ws in words for a, v in ws if a == "F"]
    if info["f"] is None:
        assert fs == [], (line, outs)
    else:
        assert len(fs) == 1 and float(fs[0]) == float(info["f"]), (line, outs)
    es = [v for ws in words for a, v in ws if a == "E"]
    e = info["e"]
    if e is None:
        assert es == [], (line, outs)
        return
    assert es, (line, outs)
    if len(es) == 1:
        assert float(es[0]) == float(e), (line, outs)
        return
    # split over pieces (linearised arc, or a smoothed take-up cut): the compensator works in
    # integer units of max(5, written decimals) decimals
    dec = max(5, len(e.split(".")[1]) if "." in e else 0)
    unit = 10.0**-dec
    vals = [float(v) for v in es]
    if mode.e_relative:
        assert abs(sum(vals) - float(e)) <= 0.5 * unit + 1e-9, (line, vals)
        assert all(abs(v * 10**dec - round(v * 10**dec)) < 1e-6 for v in vals)
    else:
        assert float(es[-1]) == float(e), (line, outs)  # ends on the written position
        steps = [b - a for a, b in zip(vals, vals[1:])]
        sign = math.copysign(1.0, vals[-1] - vals[0])
        assert all(s * sign >= -unit for s in steps), (line, vals)  # monotone to the target


@cfg(120)
@given(stream(), params(), options())
@example(
    [
        ("G28", {}),
        ("G1 X10 Y10 Z1", {}),
        ("M83", {}),
        (
            "G2 X30 Y10 I10 J0 E1.23457 F1200 ; arc",
            {"kind": "arc", "e": "1.23457", "f": "1200", "indent": "", "comment": "; arc"},
        ),
    ],
    Params.from_dict({"squareness_um_per_m": {"xy": 3000}}),
    Options(),
)
def test_every_line_maps_to_its_own_outputs_in_order(lines, p, opts):
    comp = make_compensator(p, opts)
    mode = EMode()
    total = 0
    for line, info in lines:
        malformed_before = comp.report.malformed
        outs = _outputs(comp.process(line), line)
        total += len(outs)
        if not is_motion_text(line):
            # non-motion lines (G92/G28/M-codes/comments/garbage) are never rewritten
            assert outs == [line] and outs[0] is line, (line, outs)
        elif info.get("kind") in ("move", "arc") and outs[0] is not line:
            check_motion_group(line, info, outs, mode)
        if info.get("kind") == "malformed":
            assert outs[0] is line and comp.report.malformed == malformed_before + 1, line
        mode.feed(line)
    assert comp.report.lines == len(lines)
    assert comp.report.lines_out == total


# -- 2. all-zero parameters ------------------------------------------------------------------

ZEROS = [
    {},
    {"squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0}, "scale_ppm": {"x": 0.0}},
    {"backlash": {"x": 0.0, "y": 0.0, "z": 0.0}},
    {"backlash": {"x": 40.0, "y": 12.0, "fraction": 0.0}},  # backlash switched off
    {"kinematics": "corexy", "axis_errors": {"x": {"tx_um": 0.0, "rz_urad": [0.0, 0.0]}}},
    {"servo_lag_ms": {"x": 0.6}},  # servo lead only when servo_precomp is on
]


@cfg(60)
@given(
    stream(max_size=60),
    st.sampled_from(ZEROS),
    options(),
    st.sampled_from(["\n", "\r\n"]),
    st.booleans(),
)
def test_zero_parameters_give_the_input_back(lines, zero, opts, ending, final_newline):
    p = Params.from_dict(zero)
    comp = make_compensator(p, opts)
    for line, _ in lines:
        assert comp.process(line) is line
    assert comp.report.lines == len(lines) and comp.report.moves_compensated == 0
    # the file engine: the marker line, then the very same bytes
    text = ending.join(line for line, _ in lines) + (ending if final_newline else "")
    data = text.encode(ENCODING, ERRORS)
    dst = io.BytesIO()
    compensate_binary(io.BytesIO(data), dst, p, opts)
    first_end = re.search(r"\r\n|\r|\n", text)
    head = (marker_line(p) + (first_end.group(0) if first_end else "\n")).encode()
    assert dst.getvalue() == (head + data if data else b"")


# -- 3. the compensated program lands where the program asks ---------------------------------


class _Program:
    """A program being drawn: its lines, and what the firmware model and the E mode know
    after them (where the head is, whether the E position is defined)."""

    def __init__(self, draw):
        self.draw = draw
        self.oracle = FirmwareInterpreter()
        self.mode = EMode()
        self.e_known = False
        self.lines = []

    def add(self, line):
        self.oracle.execute(line)
        self.mode.feed(line)
        code = line.split(";", 1)[0].upper()
        # (what the firmware takes as a command: ASCII blanks before it, no other whitespace)
        if re.match(r"\s*(N\d+\s*)?G92(?![\d.])", code, re.ASCII):
            self.e_known = self.e_known or "E" in code or not re.search("[XYZ]", code[4:])
        elif "E" in code and _FIRMWARE_MOTION.match(code):
            self.e_known = not self.mode.e_relative
        self.lines.append(line)

    def value(self, lo, hi, rel=False):
        """A coordinate's text in the program's units (relative: a step of up to 40 mm)."""
        draw, inches = self.draw, self.oracle.inches
        v = draw(st.floats(-40, 40) if rel else st.floats(lo, hi))
        dec = draw(st.integers(0, 4))
        return _num_text(
            v / 25.4 if inches else v,
            dec + (2 if inches else 0),
            draw(st.sampled_from(["", "", "plus", "bare"])),
        )

    def arc_words(self):
        """The centre offsets (in the plane's letters) or the radius of an arc."""
        draw, inches = self.draw, self.oracle.inches
        inch = 25.4 if inches else 1.0
        letters = {17: "IJ", 18: "KI", 19: "JK"}[self.oracle.plane]
        if draw(st.integers(0, 2)):
            offs = [
                (a, _num_text(draw(st.floats(-60, 60)) / inch, 3 + (2 if inches else 0), ""))
                for a in letters
                if draw(st.integers(0, 3))
            ]
            words = offs or [(letters[0], "10")]
        else:
            r = draw(st.floats(5, 160)) * draw(st.sampled_from([1, -1]))
            words = [("R", _num_text(r / inch, 4, ""))]
        if draw(st.integers(0, 5)) == 0:
            words.append(("P", str(draw(st.integers(1, 2)))))
        return words

    def motion(self, op):
        """A move or (``op`` "arc") an arc, kept only if the firmware model takes it."""
        draw = self.draw
        rel = not self.oracle.absolute
        words = [
            (a, self.value(lo, hi, rel))
            for a, (lo, hi) in zip("XYZ", ((-20, 220), (-20, 220), (0, 60)))
            if draw(st.booleans())
        ]
        code = draw(st.sampled_from(["G1", "G0", "G01"]))
        if op == "arc":
            code = draw(st.sampled_from(["G2", "G3"]))
            words += self.arc_words()
        if draw(st.booleans()) and (op == "move" or self.mode.e_relative or self.e_known):
            words.append(("E", _num_text(draw(st.floats(-2, 30)), 5, "")))
        if draw(st.integers(0, 3)) == 0:
            words.append(("F", str(draw(st.integers(300, 9000)))))
        line, _ = draw(decorate(code, words))
        if op == "arc":
            probe = copy.deepcopy(self.oracle)
            probe.execute(line)
            if probe.malformed > self.oracle.malformed:
                return  # not an arc (radius too small, centre on the start ...)
        self.add(line)

    def g92(self):
        draw = self.draw
        if draw(st.booleans()):
            self.add(draw(st.sampled_from(["G92 E0", "G92", "G92.1"])))
            return
        axes = draw(st.sampled_from(["X", "Y", "Z", "XY", "XYZ", "E"]))
        self.add("G92 " + " ".join(f"{a}{self.value(-50, 150)}" for a in axes))

    def home(self, partial_home):
        choices = (
            [
                ("G28",),
                ("G28 X",),
                ("G28 Y Z",),
                ("G28 X Y Z",),
                ("G28 X", "G28 Y"),
                ("G28 Y", "G28 X", "G28 Z"),
                ("G28 Z", "G28 X"),
            ]
            if partial_home
            else [("G28",), ("G28 X Y Z",)]
        )
        for h in self.draw(st.sampled_from(choices)):  # (axes homed one G28 at a time, too)
            self.add(h)


_MODES = ["G90", "G91", "G20", "G21", "M82", "M83", "G17", "G18", "G19"]
_OTHER = ["M104 S200", "G4 P10", "; layer", "", "M106 S128", "M117 hi"]


@st.composite
def program(draw, max_ops=30, partial_home=True):
    """A program that always knows where the head is: homed first, no probing or tool
    changes, every arc a valid arc (the firmware model is asked before an arc is kept) and
    absolute-E arcs only when the E position is defined (the compensator cannot split an
    absolute E from an unknown one and passes such arcs untouched, as documented)."""
    prog = _Program(draw)
    prog.add("G28")
    for m in draw(st.sampled_from([(), ("G92 E0",), ("M83",), ("G92 E0", "M83")])):
        prog.add(m)
    x, y, z = draw(st.floats(0, 200)), draw(st.floats(0, 200)), draw(st.floats(0.2, 40))
    prog.add(f"G1 X{x:.3f} Y{y:.3f} Z{z:.3f} F3000")
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(["move"] * 6 + ["arc"] * 3 + ["mode", "g92", "home", "other"]))
        if op in ("move", "arc"):
            prog.motion(op)
        elif op == "mode":
            prog.add(draw(st.sampled_from(_MODES)))
        elif op == "g92":
            prog.g92()
        elif op == "home":
            prog.home(partial_home)
        else:
            prog.add(draw(st.sampled_from(_OTHER)))
    return prog.lines


def motion_info(line: str) -> dict:
    """E/F words, comment and indentation of a valid motion line, read from its text."""
    code, semi, rest = line.partition(";")
    words = dict(reversed(out_words(code.replace("*", " * "))))  # first E/F of the line
    return {
        "indent": line[: len(line) - len(line.lstrip())],
        "comment": semi + rest,
        "e": words.get("E"),
        "f": words.get("F"),
    }


def replay(p, lines, opts, play=True):
    """Compensate ``lines`` and replay the output on a printer with the errors of ``p``
    (with its play, or the kinematic errors only); yields (line, actual, wanted) at the end
    of every move the compensator rewrote. Homing is not compensated (the endstops decide)
    and other lines do not move the head, so those are not compared."""
    comp = make_compensator(p, opts)
    oracle = FirmwareInterpreter()
    printer = Printer(p)
    if not play:
        printer.play = Play(Params())
    mode = EMode()
    for line in lines:
        out = comp.process(line)
        oracle.execute(line)
        outs = _outputs(out, line)
        for o in outs:
            printer.run_line(o)
        if out is not line:
            # the E/F/comment checks of property 1, on programs where every arc is compensated
            check_motion_group(line, motion_info(line), outs, mode)
            yield line, printer.actual(), tuple(oracle.machine)
        mode.feed(line)
    # every move of these programs can be compensated: none may pass untouched
    assert comp.report.untouched_unknown == 0 and comp.report.malformed == 0


@cfg(50)
@given(program(), geometry(), st.sampled_from([0.01, 0.05]))
@example(
    ["G28", "G1 X10 Y10 Z1", "G92 X0 Y0", "G92.1", "G1 X5", "G1 Y20"],
    {"squareness_um_per_m": {"xy": 5000.0}},
    0.01,
)  # G92.1 must not move the frame
def test_compensated_program_lands_on_the_desired_points(lines, geo, tol):
    p = Params.from_dict(geo)
    checked = 0
    for line, got, want in replay(p, lines, Options(decimals=6, chord_tol_mm=tol)):
        assert dist(got, want) <= 1e-6, (line, got, want)
        checked += 1
    assert checked > 0 or changes_nothing(p)  # the first G1 always moves


@cfg(40)
@given(program(), geometry(), backlash(tables=True, fraction=False, smoothing=False))
@example(  # a full-circle helix under XZ/YZ skew: the last piece's circle once carried X
    # 21 um past its end (where X reverses) and back, leaving the play on the wrong side
    ["G28", "G1 X0 Y0 Z26 F3000", "G2 X-0Y-0 Z+57 I-15.840f788"],
    {
        "squareness_um_per_m": {"xy": 0.0, "xz": 2974.797, "yz": 4272.194},
        "scale_ppm": {"x": 0.0, "y": 2377.635, "z": -242.385},
    },
    {"x": 39.733, "z": 90.9998},
)
@example(  # a spiral (radius 8 -> 6 mm over a turn): Y turns round 0.1 deg before its end,
    # between the check points of the piece; the chords then carried Y back without take-up
    ["G28", "G1 X0 Y0 Z1 F3000", "G2 Y2 J8 F300"],
    {},
    {"y": 1.0},
)
@example(  # a half circle from a skewed X extreme: X retreats ~25 nm next to its start, below
    # the step-derived deadband (the default since issue 28); the arc must not be cut there
    ["G28", "G1 X33.255 Y0 Z0.5 F3000", "G2 X0 I-16.6275 J0", "G3 X33.255 I16.6275 J0"],
    {"squareness_um_per_m": {"xy": -1766.0}},
    {"x": 24.6},
)
def test_with_backlash_the_printer_with_play_lands_too(lines, geo, bl):
    """The take-up moves are what make a printer with play land: replayed through the play,
    every compensated move ends on its point (the 1e-6 output resolution plus the
    compensator's reversal deadband, a hysteresis, so sub-deadband steps cannot add up, and
    a retreat below it, not taken up, leaves the carriage at most that far off (0.625 um by
    default, a twentieth of a step at 80 steps/mm, through a model of norm < 1.02); after an
    arc 1.5e-6 more: its written centre is rounded, so the firmware's circle may turn an
    axis up to that much before the piece's end where the axis reverses, and the play then
    stays on the other side). Partial homing included: the first move after it is judged
    from the home command."""
    p = Params.from_dict(dict(geo, backlash=bl))
    opts = Options(decimals=6, chord_tol_mm=0.05)
    lines_bound = 1e-6 + 1.02 * opts.deadband_mm
    for line, got, want in replay(p, lines, opts, play=True):
        bound = lines_bound + (1.5e-6 if re.search(r"G0*[23]\b", line, re.I) else 0.0)
        assert dist(got, want) <= bound, (line, got, want)


@cfg(40)
@given(program(), geometry(), backlash())
def test_with_backlash_endpoints_stay_within_the_takeup(lines, geo, bl):
    """Ignoring the play, each move ends within the backlash offset (+-fraction*b/2 per axis,
    at most) of its point: take-up moves come before the move, never instead of it."""
    p = Params.from_dict(dict(geo, backlash=bl))
    half = [
        p.backlash_fraction * max(um_ for _, um_ in p.backlash[a].points) * 1e-3 / 2 for a in "xyz"
    ]
    # |A o| <= ||A|| ||o||; ||A|| < 1.02 for squareness and scale up to 5000 um/m and ppm
    bound = 1.02 * math.sqrt(sum(h * h for h in half)) + 1e-6
    opts = Options(decimals=6, chord_tol_mm=0.05)
    for line, got, want in replay(p, lines, opts, play=False):
        assert dist(got, want) <= bound, (line, got, want, bound)


def test_landing_checks_can_fail():
    """The replay detects a wrong program (guards the properties above against vacuity)."""
    p = Params.from_dict({"squareness_um_per_m": {"xy": 3000.0}})
    lines = ["G28", "G1 X10 Y100 Z1"]
    comp = make_compensator(p, Options(decimals=6))
    printer = Printer(p)
    for line in lines:
        printer.run_line(line)  # uncompensated
    assert comp.process(lines[1]) != lines[1]
    assert dist(printer.actual(), (10, 100, 1)) > 0.2


# -- 4. nothing raises; malformed lines pass and are counted ---------------------------------


@cfg(80)
@given(
    st.lists(any_line(), max_size=20),
    params(),
    options(),
    st.lists(st.text(max_size=40), min_size=1, max_size=10),
)
@example(
    [("G28", {}), ("G1 X1 Y1 Z1", {})],
    Params.from_dict({"squareness_um_per_m": {"xy": 100}}),
    Options(),
    [
        "G2 X10 Y10 I5 J0 P" + "9" * 400,
        "G2 X10 Y10 I1" + "0" * 200 + " J0",
        "G2 X10 Y10 I5 J0 P1" + "0" * 18,
        "G3 X10 Y10 R1" + "0" * 20,
        "G1 X\u0661\u0660",
        "G2 X10 Y10 I5 J0 P100",
        "G1 X1\nM83",
        "\x00G1 X5",
        "G1 X" + "9" * 400,
    ],
)
@example(
    [("G28", {}), ("G1 X1 Y1 Z1", {}), ("G91", {})],
    Params.from_dict({"squareness_um_per_m": {"xy": 100}}),
    Options(),
    ["G1 X1" + "0" * 200, "G20", "G1 X1" + "0" * 307 + " Y5"],
)
@example(
    [("G28", {}), ("G1 X1 Y1 Z1", {})],
    Params.from_dict({"backlash": {"x": 10, "smoothing_mm": 1}}),
    Options(),
    ["G1 X1" + "0" * 200],
)
def test_no_line_makes_it_raise(prefix, p, opts, texts):
    comp = make_compensator(p, opts)
    for line, _ in prefix:
        comp.process(line)
    for text in texts:
        outs = _outputs(comp.process(text), text)
        if not is_motion_text(text):
            assert outs == [text], (text, outs)
        else:
            assert all(is_motion_text(o) for o in outs), (text, outs)
            if outs[0] is not text:
                assert all(well_formed(o) for o in outs), (text, outs)
            assert len(outs) <= 3 * arcs.MAX_SEGMENTS  # a bounded expansion


SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 100.0}})


def test_arc_from_an_unknown_linear_axis_passes_untouched():
    """Found by the stream property: XY known, Z never set (no homing), then an XY arc. The
    chords interpolate Z, so the arc waits for Z like any move waits for its axes (it raised
    TypeError in linearise)."""
    for p in (Params.from_dict({"scale_ppm": {"z": 1.0}}), SKEW):
        for arc in ("G2 Y0 I1 J1", "G3 X5 Y5 R5 Z2", "G2 X2 Y0 I1 J0 P1"):
            comp = make_compensator(p)
            comp.process("G1 X0 Y0 F60")
            assert comp.known == (True, True, False)
            assert comp.process(arc) is arc
            assert comp.report.untouched_unknown == 1


def test_arc_with_a_huge_turn_count_passes_untouched():
    """P100000: the forced chord ends alone would exceed arcs.MAX_SEGMENTS (P1e18 used to
    run out of memory building them): not an arc we can linearise, so malformed."""
    for line in ["G2 X10 Y10 I5 J0 P100000", "G2 X10 Y10 I5 J0 P1" + "0" * 18]:
        comp = make_compensator(SKEW)
        comp.process("G28")
        comp.process("G1 X1 Y1 Z1")
        assert comp.process(line) is line
        assert comp.report.malformed == 1 and comp.report.untouched_unknown == 1


def test_arc_with_a_huge_radius_passes_untouched():
    """R1e20: the chord angle rounds to 0 (it divided by zero); beyond 1e100 the number is
    no coordinate at all (its square overflowed)."""
    for line in [
        "G3 X10 Y10 R1" + "0" * 20,
        "G2 X10 Y10 I1" + "0" * 20 + " J0",
        "G2 X10 Y10 I1" + "0" * 200 + " J0",
    ]:
        comp = make_compensator(SKEW)
        comp.process("G28")
        comp.process("G1 X1 Y1 Z1")
        assert comp.process(line) is line
        assert comp.report.malformed == 1


def test_many_turn_arc_is_linearised_with_its_forced_points():
    """P1000 with skew: thousands of forced chord ends (the command extremes of every turn);
    filtering the uniform chords against them used to be quadratic (minutes)."""
    comp = make_compensator(SKEW, Options(decimals=6, linearise_arcs=True))
    comp.process("G28")
    comp.process("G1 X1 Y1 Z1")
    out = comp.process("G2 X1 Y1 I5 J0 P1000")
    assert comp.report.arcs_linearised == 1 and comp.report.malformed == 0
    assert 4 * 1001 <= len(out) <= arcs.MAX_SEGMENTS + 8 * 1001
    # the chords go round the circle: the last one ends on the (compensated) start point
    q = comp.model.inverse((1.0, 1.0, 1.0))
    end = {a: float(v) for a, v in out_words(out[-1])}
    assert abs(end["X"] - q[0]) < 1e-6 and abs(end["Y"] - q[1]) < 1e-6


@cfg(60)
@given(
    st.lists(st.one_of(any_line(), malformed()), max_size=30), params(), options(), st.booleans()
)
def test_malformed_motion_lines_pass_unchanged_and_are_counted(items, p, opts, homed):
    comp = make_compensator(p, opts)
    rep = comp.report
    if homed:
        comp.process("G28")
    for line, info in items:
        before = rep.malformed
        out = comp.process(line)
        if info["kind"] == "malformed":  # malformed by construction, in any state
            assert rep.malformed == before + 1, line
        if rep.malformed > before:
            assert out is line  # whatever made it malformed, it passes as written
            if rep.malformed <= 20:
                assert rep.malformed_examples[-1] == (comp.lineno, line[:80])
