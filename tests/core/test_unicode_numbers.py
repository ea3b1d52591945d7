"""Issue 26, case 7: a number a firmware cannot read is no number. Python's float() and the
regex ``\\d`` take Unicode digits (``X١٢٣`` is 123 to them), a firmware reading bytes sees
no number there: the line is malformed and passes as written, in the reference parser and
in the file loop (compiled kernel, reference path), which must agree byte for byte."""

import pytest

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.gcode import parse_command, parse_words
from octoprint_kincomp.core.params import Params
from tests.engines.test_file_properties import _file, _per_line

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 3000.0}, "scale_ppm": {"x": 500.0}})

UNREADABLE = [
    "G1 X\u0661\u0662\u0663 Y10",  # Arabic-Indic digits
    "G1 X12\u0663 Y10",  # one of them at the end
    "G1 X\uff11\uff12 Y10",  # fullwidth digits
    "G1 X10 Y\u0969\u0966",  # Devanagari
    "G1 X10.\u0665 Y10",  # in the decimals
    "G\u0661 X10 Y10",  # in the code
    "N\u0661\u0660 G1 X10 Y10*7",  # in the line number
    "G1 X10\u00a0Y10",  # a no-break space between words
    "G1 X10\u2003Y10",  # an em space
]


@pytest.mark.parametrize("line", UNREADABLE)
def test_unicode_digits_and_spaces_make_a_line_malformed(line):
    cmd = parse_command(line)
    assert cmd is None or parse_words(cmd.body) is None


@pytest.mark.parametrize("line", UNREADABLE)
def test_such_a_line_goes_out_as_written(line):
    comp = Compensator(SKEW, Options())
    comp.process("G28")
    comp.process("G1 X5 Y5")
    assert comp.process(line) == line
    assert comp.process("G1 X123 Y10") != "G1 X123 Y10"  # a plain line is compensated


FILE = (
    "G28\nG1 X5 Y5 Z1 F3000\n"
    + "".join(f"G1 X{10 + i} Y{10 + i % 7}\n" for i in range(40))
    + "".join(line + "\n" + f"G1 X{i} Y{2 * i}\n" for i, line in enumerate(UNREADABLE))
    + "".join(f"G1 X{50 + i} Y{20 + i % 5} E0.1\n" for i in range(40))
)


@pytest.mark.parametrize("chunk", [None, 97])
def test_the_file_engines_agree_with_the_reference(engine, chunk):
    opts = Options()
    ref = _per_line(FILE, SKEW, opts, Compensator(SKEW, opts))
    got = _file(FILE, SKEW, opts, chunk)
    assert got == ref
    out = ref[0].decode("utf-8")
    for line in UNREADABLE:
        assert "\n" + line.split("*")[0] in out  # passed as written
    assert "G1 X123 Y10" not in out
