"""Every verb of the command line answers a bad file or path with one line on stderr and exit
status 1, never a traceback (review findings)."""

import json

import pytest

from octoprint_kincomp.cli import main


@pytest.fixture
def program(tmp_path):
    path = tmp_path / "xy.gcode"
    assert (
        main(
            [
                "program",
                "--plane",
                "XY",
                "--centre",
                "100,100,10",
                "--radius",
                "50",
                "-o",
                str(path),
            ]
        )
        == 0
    )
    return path


def _fails(args, capsys, *needles):
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("kincomp: error: ") and "Traceback" not in err
    for n in needles:
        assert n in err, err
    return err


def test_an_output_path_that_cannot_be_written(tmp_path, program, capsys):
    bad = str(tmp_path / "no-such-dir" / "out.gcode")
    _fails(["program", "--plane", "XY", "--centre", "100,100,10", "-o", bad], capsys, bad)
    truth = tmp_path / "t.json"
    truth.write_text(json.dumps({"errors": {}}))
    _fails(["simulate", str(program), "--truth", str(truth), "-o", bad], capsys, bad)


def test_a_binary_program_or_raw_stream(tmp_path, program, capsys):
    binary = tmp_path / "raw.bin"
    binary.write_bytes(bytes(range(128, 256)) * 10)
    truth = tmp_path / "t.json"
    truth.write_text(json.dumps({"errors": {}}))
    _fails(["simulate", str(binary), "--truth", str(truth)], capsys, str(binary), "UTF-8")
    _fails(["sensor-trace", str(binary), str(program)], capsys, str(binary), "UTF-8")


def test_a_missing_campaign_manifest_or_trace(tmp_path, program, capsys):
    truth = tmp_path / "t.json"
    truth.write_text(json.dumps({"errors": {}}))
    trace = str(tmp_path / "a.csv")
    assert main(["simulate", str(program), "--truth", str(truth), "-o", trace]) == 0
    missing = str(tmp_path / "nope.json")
    _fails(["analyze", "--manifest", missing, trace, trace], capsys, "nope.json")
    _fails(["analyze", trace, str(tmp_path / "b.csv")], capsys, "b.csv")
