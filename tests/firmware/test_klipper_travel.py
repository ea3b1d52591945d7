"""Compensated output that real Klipper accepts (issue 36, items 1, 2 and 4): corpus files and
KinComp's own programs, compensated with the issue's realistic parameters (xy 1500, xz -800,
yz 600 um/m; scale +300/-200/+150 ppm; backlash x 60, y 40 um) under the default limits
policy, run through klippy's batch mode (``tests/support/klipper_travel.py``) on stock
configs: no Klipper error that the file as written does not get.

The corpus files run on stock configs whose travel is set tight to each file's own extent
(start and end code at the printer's edges, as real profiles put them: Prusa's purge line at
Y-3, a K1's or Bambu's wiper at the far edge); there the compensation had pushed 5-7 points
per file out of range (``Move out of range``) and the first Z lift after homing left the box
at the homed corner. The programs (single tests, a campaign, the artifact) run on the stock
configs' own travel, homed with ``G28`` first as a user would.

Cost: quick part 3 corpus files x 2 runs of 20,000 lines and 5 programs, about 80 s on
2 shared cores (the slowest, the arc benchy, 16 s); the slow part the other 20 corpus and
sample files (about 60 s).
"""

import os
from pathlib import Path

import pytest

from octoprint_kincomp.calibration.artifact.program import ArtifactSpec
from octoprint_kincomp.calibration.artifact.program import generate as artifact_program
from octoprint_kincomp.calibration.ballbar.campaign import plan_campaign
from octoprint_kincomp.calibration.ballbar.program import generate
from tests.support import ROOT, klipper
from tests.support import klipper_travel as kt

CORPUS = Path(os.environ.get("KINCOMP_CORPUS", os.path.join(ROOT, "..", "shared", "gcode-corpus")))
SAMPLES = CORPUS.parent / "gcode-samples"
LINES = 20000
# file: the stock config whose other limits (extrusion, speeds, steps) it runs with
QUICK = {
    "gp_benchy_slic3rpe133_arcwelder.gcode": "printer-creality-ender3-v2-2020.cfg",  # arcs
    "mk_ideamaker514.gcode": "printer-creality-ender3-s1-2021.cfg",  # G1 Z5 E15 F200
    "nom_mini_cube_ps260.gcode": "printer-prusa-mini-plus-2020.cfg",  # purge at Y-3
}
SLOW = {
    "mk_cura591.gcode": "printer-creality-ender3-v2-2020.cfg",
    "gp_puzzle_cura231_reprap.gcode": "printer-twotrees-sapphire-plus-sp-5-v1.1-2021.cfg",
    "nom_benchy_slic3r129.gcode": "printer-creality-ender3-v2-2020.cfg",
    "gp_screw_ps274_arcs.gcode": "printer-creality-ender3-v2-2020.cfg",
    "gp_duplo_slic3rpe136.gcode": "printer-creality-ender3-v2-2020.cfg",
    "mk_orca230b2_arcs.gcode": "printer-creality-ender3-s1plus-2022.cfg",
    "mk_crealityprint514.gcode": "printer-creality-ender3-s1plus-2022.cfg",
    "mk_bambu11002_k1max_arcs.gcode": "printer-creality-ender3-s1plus-2022.cfg",
    "dm_motor_mount_kisslicer11.gcode": "printer-creality-ender3-v2-2020.cfg",
    "dm_motor_mount_oldcura.gcode": "printer-creality-ender3-v2-2020.cfg",
    "dm_towel_hook_slic3r098.gcode": "printer-creality-ender3-v2-2020.cfg",
    "gp_plant_sign_ps274_arcs.gcode": "printer-creality-ender3-v2-2020.cfg",
    "gp_ripple_vase_fullcontrol.gcode": "printer-creality-ender3-v2-2020.cfg",
    "lh_kreistest_cura410.gcode": "printer-creality-ender3-v2-2020.cfg",
    # (klippy's own step compression aborts on this file as written on the Ender-3 V2 config)
    "pr_testgeometry_ps291_arcs.gcode": "printer-prusa-mini-plus-2020.cfg",
    "mg_plate_bambu231.gcode": "printer-creality-ender3-v2-2020.cfg",
    "ud_xmaspud_bambu176_ams.gcode": "printer-creality-ender3-v2-2020.cfg",
    "am_dice_ps271_toolchange.gcode": "printer-creality-ender3-v2-2020.cfg",
    "bambustudio-a1-hook.gcode": "printer-creality-ender3-v2-2020.cfg",
    "bambustudio-square-ring.gcode": "printer-creality-ender3-v2-2020.cfg",
}


def corpus_lines(name):
    """The file's first 20,000 lines (from the corpus or the samples), as a Klipper user runs
    them (``klipper_travel.for_klipper``: other firmware's motor-off and homing words), with
    a ``G28`` first where its homing is in a start macro (``START_PRINT``: not in the batch
    config) before its first move."""
    path = CORPUS / name
    if not path.exists():
        path = SAMPLES / name
    if not path.exists():
        pytest.skip(f"no corpus file {name} in {CORPUS} or {SAMPLES}")
    lines = kt.for_klipper(path.read_text(errors="replace").splitlines()[:LINES])
    for line in lines:
        code = line.split(";")[0].split()[:1]
        if code and code[0].upper() in ("G0", "G1", "G2", "G3", "G28"):
            return lines if code[0].upper() == "G28" else ["G28"] + lines
    return lines


def check_file(klippy, tmp_path, name, config_name):
    lines = corpus_lines(name)
    config, limits = kt.tight_config(config_name, lines)
    out = kt.compare(klippy, tmp_path, config, lines, limits=limits)
    assert not out.crashed
    assert len(out.plain) < 100, out.plain[
        :3
    ]  # (the file as written runs: the check means something)
    assert out.new == [], (name, out.new[:5], out.report["limit_examples"][:5])
    return out


@pytest.mark.parametrize("name", sorted(QUICK))
def test_corpus_files_at_their_own_edges(klippy, tmp_path, name):
    out = check_file(klippy, tmp_path, name, QUICK[name])
    # the edges were met (the test can fail) and said: count, shortfall, axis
    assert out.report["limit_hits"] >= 5 and out.report["limit_worst_axis"] in "XYZ"
    assert 10.0 < out.report["limit_worst_um"] < 100.0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SLOW))
def test_more_corpus_files_at_their_own_edges(klippy, tmp_path, name):
    check_file(klippy, tmp_path, name, SLOW[name])


def _volume(config):
    box = klipper.travel_limits(config)
    return tuple(v for a in "xyz" for v in box[a])


PROGRAMS = [
    ("printer-creality-ender3-v2-2020.cfg", "xy"),
    ("printer-creality-ender3-v2-2020.cfg", "xz"),
    ("printer-tronxy-x5sa-pro-2020.cfg", "yz"),
]


@pytest.mark.parametrize("name,step", PROGRAMS, ids=[f"{c[8:-4]}-{s}" for c, s in PROGRAMS])
def test_campaign_programs(klippy, tmp_path, name, step):
    """The campaign's tests (each also a single test) on the stock config's own travel, homed
    first: the first Z lift at the homed corner left the box (``Move out of range: 0.030
    -0.020 0.000``)."""
    config = klipper.stock_config(name)
    spec = {s.name: s.spec for s in plan_campaign(_volume(config))}[step]
    lines = ["G28"] + generate(spec, date="-").splitlines()
    out = kt.compare(klippy, tmp_path, config, lines)
    assert not out.crashed and out.plain == []
    assert out.new == [], out.new[:5]


@pytest.mark.parametrize("mode", ["quick", "full"])
def test_the_artifact_program(klippy, tmp_path, mode):
    """The printed artifact (both modes) on a CoreXY whose Y homes at its maximum (the
    Sapphire Plus)."""
    name = "printer-twotrees-sapphire-plus-sp-5-v1.1-2021.cfg"
    config = klipper.stock_config(name)
    lines = artifact_program(ArtifactSpec(volume=_volume(config), mode=mode), date="-")
    out = kt.compare(klippy, tmp_path, config, lines.splitlines())
    assert not out.crashed and out.plain == []
    assert out.new == [], out.new[:5]


def test_warn_sends_points_past_the_edge_that_klipper_refuses(klippy, tmp_path):
    """The contrast (and proof the check can fail): the same homing and first lift under the
    policy ``warn`` end the print at line 2, as the issue found."""
    config = klipper.stock_config("printer-creality-ender3-v2-2020.cfg")
    lines = ["G28", "G1 Z5 F5000", "G1 X100 Y100", "G1 Z0.3", "G1 Z5 E15 F200"]
    warned = kt.compare(klippy, tmp_path / "warn", config, lines, policy="warn")
    assert [ln for ln, _ in warned.new] == [2]
    assert warned.new[0][1].startswith("Move out of range")
    clamped = kt.compare(klippy, tmp_path / "clamp", config, lines)
    assert clamped.new == [] and clamped.plain == []
