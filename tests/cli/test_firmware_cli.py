"""``firmware``: the one-line equivalents (default) and the ready-to-paste blocks
(``--format``, with the current steps/mm or rotation_distance), and its errors (issue 14)."""

import json
import subprocess
import sys

import pytest

from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.export import format_equivalents, format_export
from tests.engines.test_files import write

PARAMS = {
    "squareness_um_per_m": {"xy": -3638.6},
    "scale_ppm": {"x": 500.0, "y": -250.0},
    "backlash": {"x": 20.0},
}


@pytest.fixture
def pfile(tmp_path):
    return write(tmp_path, "p.json", json.dumps(PARAMS))


def test_default_is_todays_output(pfile, capsys):
    assert main(["firmware", "--params", pfile]) == 0
    assert capsys.readouterr().out == format_equivalents(Params.from_dict(PARAMS))


@pytest.mark.parametrize(
    "fmt, firmwares, first",
    [
        ("klipper", ("klipper",), "# ==== Klipper"),
        ("marlin", ("marlin",), "; ==== Marlin"),
        ("rrf", ("reprapfirmware",), "; ==== RepRapFirmware"),
        ("all", ("klipper", "marlin", "reprapfirmware"), "# ==== Klipper"),
    ],
)
def test_format_prints_the_blocks(pfile, capsys, fmt, firmwares, first):
    assert main(["firmware", "--params", pfile, "--format", fmt]) == 0
    out = capsys.readouterr().out
    assert out == format_export(Params.from_dict(PARAMS), firmwares)
    assert out.startswith(first)
    assert out.count("====") == 2 * len(firmwares)


def test_current_values_give_the_new_ones(pfile, capsys):
    assert (
        main(
            [
                "firmware",
                "--params",
                pfile,
                "--format",
                "all",
                "--steps-per-mm",
                "80,80,400",
                "--rotation-distance",
                "40,40,8",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "M92 X79.96002 Y80.02001 ; steps/mm for the scale, was X80 Y80" in out
    assert "rotation_distance: 40.02  # was 40; X +500.0 ppm" in out
    assert "rotation_distance: 39.99  # was 40; Y -250.0 ppm" in out


@pytest.mark.parametrize(
    "args, msg",
    [
        (["--steps-per-mm", "80,80,400"], "--steps-per-mm needs --format marlin or all"),
        (["--format", "klipper", "--steps-per-mm", "80,80,400"], "needs --format marlin or all"),
        (
            ["--format", "marlin", "--rotation-distance", "40,40,8"],
            "--rotation-distance needs --format klipper or all",
        ),
        (["--format", "marlin", "--steps-per-mm", "80,80"], "--steps-per-mm: expected 3"),
        (["--format", "marlin", "--steps-per-mm", "80,-80,400"], "3 positive numbers"),
        (["--format", "all", "--rotation-distance", "40,abc,8"], "--rotation-distance: expected 3"),
    ],
)
def test_errors_name_the_flag(pfile, capsys, args, msg):
    assert main(["firmware", "--params", pfile] + args) == 1
    err = capsys.readouterr().err
    assert err.startswith("kincomp: error: ") and msg in err


def test_bad_params_file_and_format(tmp_path, capsys):
    bad = write(tmp_path, "bad.json", json.dumps({"scale_ppm": {"x": "lots"}}))
    assert main(["firmware", "--params", bad, "--format", "marlin"]) == 1
    assert "invalid params file" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["firmware", "--params", bad, "--format", "grbl"])
    assert exc.value.code == 2


def test_module_entry_all_zero_says_nothing_to_export(tmp_path):
    p = write(tmp_path, "zero.json", Params().to_json())
    run = subprocess.run(
        [sys.executable, "-m", "octoprint_kincomp", "firmware", "--params", p, "--format", "rrf"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0 and run.stderr == ""
    assert "; note: Nothing to export: squareness, scale and backlash are all zero." in run.stdout
    assert "M556" not in run.stdout
