"""``artifact program`` and ``artifact analyze`` (issue 27); the older ``artifact
--diagonals/--length`` form stays (tests/calibration/test_analysis.py::test_artifact_route)."""

import json

import numpy as np
import pytest

from octoprint_kincomp.calibration.artifact.program import read_measurements
from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.artifact import simulate_readings

TRUTH = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": 600.0, "xz": -900.0, "yz": 400.0},
        "scale_ppm": {"x": 300.0, "y": -200.0, "z": 0.0},
    }
)


@pytest.fixture
def artifact(tmp_path):
    prog = tmp_path / "A.gcode"
    assert (
        main(
            [
                "artifact",
                "program",
                "--volume",
                "0,235,0,235,0,250",
                "--nozzle",
                "0.4",
                "--temps",
                "215,65",
                "--first-layer",
                "0.25",
                "-o",
                str(prog),
            ]
        )
        == 0
    )
    meas = read_measurements(prog.read_text())
    readings = simulate_readings(
        meas, TRUTH, shrinkage=0.004, line_width_mm=0.44, rng=np.random.default_rng(1)
    )
    m = tmp_path / "M.json"
    m.write_text(json.dumps(readings))
    return tmp_path, prog, m


def test_program_then_analyze_json(artifact, capsys):
    tmp, prog, m = artifact
    text = prog.read_text()
    assert "M109 S215" in text and "M190 S65" in text and "G1 Z0.25" in text
    capsys.readouterr()
    out_params = tmp / "P.json"
    assert (
        main(
            [
                "artifact",
                "analyze",
                str(m),
                "--program",
                str(prog),
                "--json",
                "--params-out",
                str(out_params),
            ]
        )
        == 0
    )
    res = json.loads(capsys.readouterr().out)
    assert set(res) >= {"diagnostics", "parameters", "firmware", "findings", "trusted"}
    d = res["diagnostics"]
    assert set(d["squareness_um_per_m"]) == {"xy", "xz", "yz"}
    assert set(d["scale_mismatch_ppm"]) == {"x-y", "x-z", "y-z"}
    for key in ("squareness_um_per_m", "scale_mismatch_ppm"):
        assert set(d["uncertainty"][key]) == set(d[key])
    u = d["uncertainty"]
    assert d["squareness_um_per_m"]["xy"] == pytest.approx(
        600, abs=3 * u["squareness_um_per_m"]["xy"]
    )
    assert d["scale_mismatch_ppm"]["x-y"] == pytest.approx(
        500, abs=3 * u["scale_mismatch_ppm"]["x-y"]
    )
    assert res["trusted"] is True
    p = Params.load(str(out_params))  # the proposal is a valid params file
    assert p.squareness_um_per_m["xy"] == pytest.approx(d["squareness_um_per_m"]["xy"])
    assert "M852" in " ".join(res["firmware"]["marlin"])


def test_analyze_text_and_current(artifact, capsys):
    tmp, prog, m = artifact
    cur = tmp / "cur.json"
    cur.write_text(json.dumps({"squareness_um_per_m": {"xy": 100.0}}))
    assert main(["artifact", "analyze", str(m), "--program", str(prog), "--current", str(cur)]) == 0
    out = capsys.readouterr().out
    assert "squareness_um_per_m" in out and "+-" in out and "trusted" in out
    assert "current + residual" in out


def test_analyze_errors(artifact, capsys):
    tmp, prog, m = artifact
    bad = tmp / "bad.json"
    bad.write_text('{"Q1-out": [1.0]}')
    assert main(["artifact", "analyze", str(bad), "--program", str(prog)]) == 1
    assert "Q1-out" in capsys.readouterr().err
    bad.write_text('{"X1-out": [-146]}')
    assert main(["artifact", "analyze", str(bad), "--program", str(prog)]) == 1
    assert "positive" in capsys.readouterr().err
    notprog = tmp / "x.gcode"
    notprog.write_text("G28\n")
    assert main(["artifact", "analyze", str(m), "--program", str(notprog)]) == 1
    assert "not a KinComp artifact" in capsys.readouterr().err
    assert main(["artifact", "analyze", str(m), "--program", str(tmp / "missing")]) == 1
    assert "missing" in capsys.readouterr().err


def test_program_errors_and_old_form(tmp_path, capsys):
    assert main(["artifact", "program", "--volume", "0,50,0,50,0,50"]) == 1
    assert "too small" in capsys.readouterr().err
    assert main(["artifact", "program", "--planes", "XY,QQ"]) == 1
    assert "planes" in capsys.readouterr().err
    assert main(["artifact"]) == 1
    assert "--diagonals" in capsys.readouterr().err
    assert main(["artifact", "--plane", "XZ", "--diagonals", "141.6,141.2,100"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["parameters"]["squareness_um_per_m"]["xz"] > 0


def test_quick_program_with_its_stl(tmp_path, capsys):
    """Issue 35: ``artifact program --quick --stl``: the quick artifact's G-code (its
    measuring sheet) and its walls as STL; its 12 readings analysed, the verdict first."""
    prog, stl = tmp_path / "Q.gcode", tmp_path / "Q.stl"
    assert main(["artifact", "program", "--quick", "--stl", str(stl), "-o", str(prog)]) == 0
    meas = read_measurements(prog.read_text())
    assert len(meas) == 12
    data = stl.read_bytes()
    assert len(data) == 84 + 50 * int.from_bytes(data[80:84], "little")
    readings = simulate_readings(meas, TRUTH, repeats=1, rng=np.random.default_rng(2))
    m = tmp_path / "M.json"
    m.write_text(json.dumps(readings))
    capsys.readouterr()
    assert main(["artifact", "analyze", str(m), "--program", str(prog)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "verdict: apply"
