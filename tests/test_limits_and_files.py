"""Limits policies, dry-run report, file processing, idempotence and the CLI (issue 2)."""

import json
import os
import subprocess
import sys

import pytest

from octoprint_kincomp.cli import main
from octoprint_kincomp.compensator import Compensator, LimitError, Options
from octoprint_kincomp.fileproc import (
    AlreadyCompensated, compensate_file, file_marker, marker_line)
from octoprint_kincomp.params import Params

SAMPLES = os.path.join(os.path.dirname(__file__), "data")
SKEW = {"squareness_um_per_m": {"xy": 2000.0}, "scale_ppm": {"x": 300.0}}
LIMITS = (0, 200, 0, 200, 0, 180)


def edge_program():
    # desired X=0 at Y=100: the skew correction pushes the command to X=-0.2 (outside)
    return ["G28", "G1 X10 Y100 Z1", "G1 X0 Y100", "G1 X-5 Y100", "G1 X100 Y100"]


@pytest.mark.parametrize("policy", ["warn", "clamp"])
def test_limit_policies_warn_and_clamp(policy):
    comp = Compensator(Params.from_dict(SKEW), Options(limits=LIMITS, policy=policy))
    outs = [comp.process(l) for l in edge_program()]
    assert comp.report.limit_hits == 1
    assert comp.report.limit_examples[0][:2] == (3, "X")
    x = float(outs[2][0].split()[1][1:])
    if policy == "clamp":
        assert x == 0.0
    else:
        assert x == pytest.approx(-0.2, abs=0.001)
    # a point the program itself puts outside is never altered by the policy
    assert comp.report.source_outside == 1
    assert float(outs[3][0].split()[1][1:]) == pytest.approx((-5 - 0.2) / 1.0003, abs=0.001)


def test_limit_policy_error_names_the_line():
    comp = Compensator(Params.from_dict(SKEW), Options(limits=LIMITS, policy="error"))
    with pytest.raises(LimitError, match=r"line 3: compensated X=-0\.1999 mm is outside"):
        for l in edge_program():
            comp.process(l)


def test_options_validation():
    with pytest.raises(ValueError, match="policy"):
        Options(policy="ignore")
    with pytest.raises(ValueError, match="min < max"):
        Options(limits=(10, 0, 0, 1, 0, 1))


def test_report_counts_and_max_correction():
    comp = Compensator(Params.from_dict(SKEW))
    for l in edge_program() + ["G2 X120 Y100 I10 J0", "G1 X1 X2"]:
        comp.process(l)
    r = comp.report.to_dict()
    assert r["moves"] == 6 and r["moves_compensated"] == 5 and r["malformed"] == 1
    assert r["arcs_linearised"] == 1 and r["arc_segments"] > 2
    top = comp.model.inverse((110.0, 110.0, 1.0))[0]  # the arc's top is the worst point
    assert r["max_correction_um"]["x"] == pytest.approx(abs(top - 110.0) * 1000, abs=0.5)
    assert r["lines_out"] > r["lines"]


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


def test_cli_compensate_report_and_in_place(tmp_path, capsys):
    p = write(tmp_path, "in.gcode", "\n".join(edge_program()) + "\n")
    params = write(tmp_path, "p.json", json.dumps(SKEW))
    rc = main(["compensate", p, "--params", params, "--limits", "0,200,0,200,0,180",
               "--report"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["limit_hits"] == 1 and rep["params_hash"] == Params.from_dict(SKEW).hash()
    assert open(p).read().startswith(marker_line(Params.from_dict(SKEW)))
    # second run: refused with a clear message and exit status 1
    rc = main(["compensate", p, "--params", params])
    err = capsys.readouterr().err
    assert rc == 1 and "already compensated" in err


@pytest.mark.parametrize("args, msg", [
    (["--params", "{P}", "--limits", "1,2,3"], "--limits: expected 6"),
    (["--params", "{BAD}"], "invalid params file"),
    (["--params", "{P}", "--policy", "error", "--limits", "0,200,0,200,0,180"],
     "outside the limits"),
    ([], "--params is required"),
])
def test_cli_errors(tmp_path, capsys, args, msg):
    p = write(tmp_path, "in.gcode", "\n".join(edge_program()) + "\n")
    good = write(tmp_path, "p.json", json.dumps(SKEW))
    bad = write(tmp_path, "bad.json", json.dumps({"squareness_um_per_m": {"xy": "x"}}))
    args = [a.format(P=good, BAD=bad) for a in args]
    rc = main(["compensate", p] + args)
    assert rc == 1
    assert msg in capsys.readouterr().err


def test_cli_missing_file(tmp_path, capsys):
    good = write(tmp_path, "p.json", json.dumps(SKEW))
    assert main(["compensate", str(tmp_path / "nope.gcode"), "--params", good]) == 1
    assert "No such file" in capsys.readouterr().err


def test_cli_params_init_and_module_entry(tmp_path):
    out = subprocess.run([sys.executable, "-m", "octoprint_kincomp", "params", "--init"],
                         capture_output=True, text=True, check=True).stdout
    assert Params.from_json(out).is_zero
    p = write(tmp_path, "p.json", json.dumps(SKEW))
    chk = subprocess.run([sys.executable, "-m", "octoprint_kincomp", "params", "--check", p],
                         capture_output=True, text=True)
    assert chk.returncode == 0 and "valid" in chk.stdout


def test_cli_firmware_equivalents(tmp_path, capsys):
    p = write(tmp_path, "p.json", json.dumps({"squareness_um_per_m": {"xy": -3638.6},
                                             "backlash": {"x": 20}}))
    assert main(["firmware", "--params", p]) == 0
    out = capsys.readouterr().out
    assert "M852 I-0.003639" in out and "M556 S100 X0.36386" in out and "M425 X0.0200" in out
