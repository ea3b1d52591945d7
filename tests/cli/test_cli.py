"""The command line's file verbs: compensate (in place, report, errors), params, firmware
(issue 2)."""

import json
import subprocess
import sys

import pytest

from octoprint_kincomp.cli import main
from octoprint_kincomp.core.kinematics import changes_nothing
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.file_loop import marker_line
from tests.core.test_limits import SKEW, edge_program
from tests.engines.test_files import write


def test_cli_compensate_report_and_in_place(tmp_path, capsys):
    p = write(tmp_path, "in.gcode", "\n".join(edge_program()) + "\n")
    params = write(tmp_path, "p.json", json.dumps(SKEW))
    rc = main(["compensate", p, "--params", params, "--limits", "0,200,0,200,0,180", "--report"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    # (X0 and the program's own X-5, both kept where the travel ends; see test_limits)
    assert rep["limit_hits"] == 2 and rep["params_hash"] == Params.from_dict(SKEW).hash()
    assert rep["limit_worst_axis"] == "X" and rep["limit_worst_um"] == pytest.approx(199.94)
    assert "X-5 Y100" in open(p).read()
    assert open(p).read().startswith(marker_line(Params.from_dict(SKEW)))
    # second run: refused with a clear message and exit status 1
    rc = main(["compensate", p, "--params", params])
    err = capsys.readouterr().err
    assert rc == 1 and "already compensated" in err


def test_cli_steps_per_mm_sets_the_reversal_deadband(tmp_path, capsys):
    """A retreat of 0.4 um is below the deadband at 80 steps/mm (0.625 um, the default) and
    gets no take-up; at 400 steps/mm (0.125 um) it does. X,Y,Z: the finer of X and Y."""
    params = write(tmp_path, "p.json", json.dumps({"backlash": {"x": 40.0}}))
    program = "G28\nG1 X50 Y0 Z1\nG1 X49.9996\n"
    lines = {}
    for steps in (None, "80", "400", "80,400,4000"):
        p = write(tmp_path, "in.gcode", program)
        args = ["compensate", p, "--params", params, "--decimals", "6"]
        args += ["--steps-per-mm", steps] if steps else []
        assert main(args) == 0
        lines[steps] = [ln for ln in open(p).read().splitlines() if not ln.startswith(";")]
    assert len(lines[None]) == len(lines["80"]) == 3
    assert len(lines["400"]) == len(lines["80,400,4000"]) == 4  # the take-up
    assert main(["compensate", p, "--params", params, "--steps-per-mm", "0"]) == 1
    assert "--steps-per-mm" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, msg",
    [
        (["--params", "{P}", "--limits", "1,2,3"], "--limits: expected 6"),
        (["--params", "{BAD}"], "invalid params file"),
        (
            ["--params", "{P}", "--policy", "error", "--limits", "0,200,0,200,0,180"],
            "outside the limits",
        ),
        ([], "--params is required"),
    ],
)
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
    out = subprocess.run(
        [sys.executable, "-m", "octoprint_kincomp", "params", "--init"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert changes_nothing(Params.from_json(out))
    p = write(tmp_path, "p.json", json.dumps(SKEW))
    chk = subprocess.run(
        [sys.executable, "-m", "octoprint_kincomp", "params", "--check", p],
        capture_output=True,
        text=True,
    )
    assert chk.returncode == 0 and "valid" in chk.stdout


def test_cli_firmware_equivalents(tmp_path, capsys):
    p = write(
        tmp_path,
        "p.json",
        json.dumps({"squareness_um_per_m": {"xy": -3638.6}, "backlash": {"x": 20}}),
    )
    assert main(["firmware", "--params", p]) == 0
    out = capsys.readouterr().out
    assert "M852 I-0.003639" in out and "M556 S100 X0.36386" in out and "M425 X0.0200" in out


def test_cli_compensate_to_a_new_output_keeps_the_inputs_mode_and_says_what_it_wrote(
    tmp_path, capsys
):
    # issue 25: the output was left 0600 (its temporary file's mode) and nothing was said
    import os
    import stat

    p = write(tmp_path, "in.gcode", "\n".join(edge_program()) + "\n")
    os.chmod(p, 0o644)
    params = write(tmp_path, "p.json", json.dumps(SKEW))
    out = str(tmp_path / "out.gcode")
    assert main(["compensate", p, "-o", out, "--params", params]) == 0
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o644
    said = capsys.readouterr().out.strip().splitlines()
    assert len(said) == 1, said
    h = Params.from_dict(SKEW).hash()
    assert said[0].startswith(f"kincomp: wrote {out}: ") and h in said[0]
    assert " moves compensated" in said[0] and " lines" in said[0]
    # another mode: followed too; an existing output keeps its own mode
    os.chmod(p, 0o640)
    out2 = str(tmp_path / "out2.gcode")
    assert main(["compensate", p, "-o", out2, "--params", params]) == 0
    assert stat.S_IMODE(os.stat(out2).st_mode) == 0o640
    os.chmod(out, 0o664)
    assert main(["compensate", p, "-o", out, "--params", params]) == 0
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o664
