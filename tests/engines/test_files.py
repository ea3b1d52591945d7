"""Whole-file processing: zero parameters, line endings, idempotence, nothing written on
error (issue 2)."""

import os

import pytest

from octoprint_kincomp.core.compensator import LimitError, Options
from octoprint_kincomp.core.marker import file_marker
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.file_loop import AlreadyCompensated, compensate_file
from tests.core.test_limits import LIMITS, SKEW, edge_program
from tests.support import DATA as SAMPLES


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, newline="")
    return str(p)


def test_zero_params_file_identical_apart_from_header(tmp_path):
    src = os.path.join(SAMPLES, "bambustudio-a1-hook.gcode")
    out = str(tmp_path / "out.gcode")
    compensate_file(src, out, Params())
    with open(src, newline="") as a, open(out, newline="") as b:
        orig, new = a.read().splitlines(True), b.read().splitlines(True)
    assert new[0].startswith("; kincomp: compensated params=")
    assert new[1:] == orig


def test_crlf_and_missing_final_newline_preserved(tmp_path):
    p = write(tmp_path, "in.gcode", "G28\r\nG1 X10 Y10 Z1\r\n; c\r\nG1 X20 Y20")
    compensate_file(p, None, Params.from_dict(SKEW))
    data = open(p, newline="").read()
    lines = data.split("\r\n")
    assert lines[0].startswith("; kincomp:") and lines[2].startswith("G1 X") and lines[3] == "; c"
    assert not data.endswith("\n") and lines[-1].startswith("G1 X")


def test_idempotence_refused(tmp_path):
    p = write(tmp_path, "in.gcode", "G28\nG1 X10 Y10 Z1\n")
    params = Params.from_dict(SKEW)
    compensate_file(p, None, params)
    assert file_marker(p) == params.hash()
    before = open(p).read()
    with pytest.raises(AlreadyCompensated, match=params.hash()):
        compensate_file(p, None, params)
    assert open(p).read() == before


def test_limit_error_writes_nothing(tmp_path):
    p = write(tmp_path, "in.gcode", "\n".join(edge_program()) + "\n")
    before = open(p).read()
    with pytest.raises(LimitError):
        compensate_file(p, None, Params.from_dict(SKEW), Options(limits=LIMITS, policy="error"))
    assert open(p).read() == before
    assert [f for f in os.listdir(tmp_path) if f.startswith(".kincomp")] == []
