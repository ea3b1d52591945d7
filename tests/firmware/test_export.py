"""Firmware export (issue 14): the ready-to-paste blocks for Klipper, Marlin and
RepRapFirmware. The numbers are checked by running each firmware's documented correction on
them against KinComp's error model (README sign table): the firmware, fed the exported
values, must cancel the error KinComp describes."""

import json
import math
import re

import pytest

from octoprint_kincomp import __plugin_url__, __version__
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.export import (
    KLIPPER_PROFILE,
    equivalents,
    export,
    export_json,
    format_equivalents,
    format_export,
    klipper_skew_factor,
)

PAPER = {
    "squareness_um_per_m": {"xy": -3638.6, "xz": 250.0, "yz": -120.0},
    "scale_ppm": {"x": -451.7, "y": 287.0, "z": 35.0},
    "backlash": {
        "x": [{"at_mm": 10.0, "um": 37.4}, {"at_mm": 210.0, "um": 4.4}],
        "y": 8.0,
        "z": 0.0,
        "fraction": 0.8,
        "smoothing_mm": 2.0,
    },
}


def _words(line):
    """{letter: float} of a G-code line's words (comment dropped)."""
    return {w[0]: float(w[1:]) for w in line.split(";")[0].split()[1:]}


def _line(text, command):
    lines = [l for l in text.splitlines() if l.split(" ")[0] == command]
    assert len(lines) == 1, (command, text)
    return lines[0]


def _section(ex, key):
    found = [s for s in ex.sections if s.key == key]
    assert len(found) == 1, [s.key for s in ex.sections]
    return found[0].text


def _actual(params, x, y, z):
    """KinComp's error model (README): where the machine really goes for a command."""
    sq = params.squareness_um_per_m
    return (x + sq["xy"] * 1e-6 * y + sq["xz"] * 1e-6 * z, y + sq["yz"] * 1e-6 * z, z)


def test_marlin_m852_cancels_kincomps_skew_and_has_its_sign():
    p = Params.from_dict(PAPER)
    w = _words(_line(_section(export(p)["marlin"], "terminal"), "M852"))
    # the paper's squareness gives the known Marlin factor: same sign as KinComp
    assert w == {"I": -0.0036386, "J": 0.00025, "K": -0.00012}
    for x, y, z in ((10, 200, 0), (150, 20, 180), (0, 0, 250)):
        # Marlin's planner: sx = x - y*I - z*(J - I*K), sy = y - z*K (skew())
        sx = x - y * w["I"] - z * (w["J"] - w["I"] * w["K"])
        sy = y - z * w["K"]
        ax, ay, _ = _actual(p, sx, sy, z)
        assert ax == pytest.approx(x, abs=1e-9) and ay == pytest.approx(y, abs=1e-9)


def test_reprapfirmware_m556_has_the_opposite_sign_and_cancels_the_skew():
    p = Params.from_dict(PAPER)
    line = _line(_section(export(p)["reprapfirmware"], "config_g"), "M556")
    w = _words(line)
    assert w["S"] == 100.0 and w["X"] == 0.36386  # -(-3638.6 um/m) over 100 mm
    assert w["Y"] == pytest.approx(0.012) and w["Z"] == pytest.approx(-0.025)  # Y: YZ, Z: ZX
    tan_xy, tan_yz, tan_xz = w["X"] / w["S"], w["Y"] / w["S"], w["Z"] / w["S"]
    for x, y, z in ((10, 200, 0), (150, 20, 180)):
        # RepRapFirmware's axis transform: x += tanXY*y + tanXZ*z, y += tanYZ*z
        mx, my = x + tan_xy * y + tan_xz * z, y + tan_yz * z
        ax, ay, _ = _actual(p, mx, my, z)
        # only the products of two skew terms (1e-7 of a move) are left over
        assert ax == pytest.approx(x, abs=2e-6 * z + 1e-9) and ay == pytest.approx(y, abs=1e-9)


def test_klipper_set_skew_lengths_give_kincomps_factors_back():
    p = Params.from_dict(PAPER)
    console = _section(export(p)["klipper"], "console")
    assert console.splitlines()[1:] == [f"SKEW_PROFILE SAVE={KLIPPER_PROFILE}", "SAVE_CONFIG"]
    planes = dict(m.groups() for m in re.finditer(r"(XY|XZ|YZ)=(\S+)", console))
    assert sorted(planes) == ["XY", "XZ", "YZ"]
    for pair, text in planes.items():
        ac, bd, ad = (float(v) for v in text.split(","))
        # Klipper's (and Marlin's) formula from the measured lengths: same sign as KinComp
        want = p.squareness_um_per_m[pair.lower()] * 1e-6
        assert klipper_skew_factor(ac, bd, ad) == pytest.approx(want, abs=1e-7)


def test_klipper_blocks_config_section_profile_and_start_end_gcode():
    ex = export(Params.from_dict(PAPER))["klipper"]
    assert [s.key for s in ex.sections] == [
        "printer_cfg",
        "console",
        "start_gcode",
        "end_gcode",
        "scale",
    ]
    cfg = _section(ex, "printer_cfg").splitlines()
    assert cfg[0].startswith("# KinComp ") and cfg[1:] == ["[skew_correction]"]
    assert _section(ex, "start_gcode") == f"SKEW_PROFILE LOAD={KLIPPER_PROFILE}"
    assert _section(ex, "end_gcode") == "SET_SKEW CLEAR=1"
    notes = " ".join(ex.notes)
    assert "no per-axis scale" in notes and "no backlash compensation" in notes


@pytest.mark.parametrize("axis, old", [("x", 40.0), ("y", 32.0), ("z", 8.0)])
def test_klipper_rotation_distance_cancels_the_scale(axis, old):
    p = Params.from_dict(PAPER)
    rd = {"x": 40.0, "y": 32.0, "z": 8.0}
    text = _section(export(p, rotation_distance=(rd["x"], rd["y"], rd["z"]))["klipper"], "scale")
    lines = text.splitlines()
    i = lines.index(f"[stepper_{axis}]")
    new = float(re.match(r"rotation_distance: (\S+)  # was ", lines[i + 1]).group(1))
    # Klipper moves commanded * rd_true / rd_configured; the axis' true rd is old * (1 + s)
    s = p.scale_ppm[axis] * 1e-6
    assert old * (1 + s) / new == pytest.approx(1.0, abs=2e-7)
    # without the current values: the factor to multiply by
    text = _section(export(p)["klipper"], "scale")
    assert f"# [stepper_{axis}] rotation_distance * {1 + s:.7f}" in text


def test_marlin_steps_per_mm_cancel_the_scale():
    p = Params.from_dict(PAPER)
    old = (80.0, 80.0, 400.0)
    text = _section(export(p, steps_per_mm=old)["marlin"], "terminal")
    w = _words(_line(text, "M92"))
    for i, axis in enumerate("xyz"):
        # Marlin moves commanded * spm_configured / spm_true; the true spm is old / (1 + s)
        s = p.scale_ppm[axis] * 1e-6
        assert w[axis.upper()] * (1 + s) / old[i] == pytest.approx(1.0, abs=2e-7)
    assert "was X80 Y80 Z400" in _line(text, "M92")
    hint = _section(export(p)["marlin"], "terminal")
    assert "; M92: multiply the current steps/mm by X1.0004519 Y0.9997131 Z0.9999650" in hint


def test_reprapfirmware_m579_cancels_the_scale():
    p = Params.from_dict(PAPER)
    w = _words(_line(_section(export(p)["reprapfirmware"], "config_g"), "M579"))
    for axis in "xyz":  # machine = user * factor, actual = machine * (1 + s)
        assert w[axis.upper()] * (1 + p.scale_ppm[axis] * 1e-6) == pytest.approx(1.0, abs=1e-7)


def test_marlin_m425_and_the_options_it_needs():
    p = Params.from_dict(PAPER)
    ex = export(p)["marlin"]
    text = _section(ex, "terminal")
    w = _words(_line(text, "M425"))
    # Marlin: the full distance (the mean of the per-side values) and the fraction F
    assert w == {
        "F": 0.8,
        "S": 2.0,
        "X": pytest.approx((37.4 + 4.4) / 2e3, abs=1e-4),
        "Y": 0.008,
        "Z": 0.0,
    }
    assert text.splitlines()[-1].startswith("M500")
    options = re.search(r"built with (.*) \(", ex.notes[0]).group(1).split(", ")
    assert options == [
        "SKEW_CORRECTION",
        "SKEW_CORRECTION_GCODE",
        "SKEW_CORRECTION_FOR_Z",
        "BACKLASH_COMPENSATION",
        "BACKLASH_GCODE",
        "BACKLASH_SMOOTHING_MM",
        "EEPROM_SETTINGS",
    ]
    assert any("Backlash differs along X" in n for n in ex.notes)


def test_marlin_xy_only_needs_no_z_skew_option():
    ex = export(Params.from_dict({"squareness_um_per_m": {"xy": 500.0}}))["marlin"]
    text = _section(ex, "terminal")
    assert _words(_line(text, "M852")) == {"I": 0.0005}
    assert "M425" not in text and "M92" not in text
    assert "SKEW_CORRECTION_FOR_Z" not in ex.notes[0] and "BACKLASH" not in ex.notes[0]


def test_reprapfirmware_m425_applies_the_fraction_and_spreads_like_kincomp():
    p = Params.from_dict(PAPER)
    ex = export(p)["reprapfirmware"]
    w = _words(_line(_section(ex, "config_g"), "M425"))
    x = 0.8 * (37.4 + 4.4) / 2e3  # no fraction in RepRapFirmware: applied to the value
    assert w["X"] == pytest.approx(x, abs=1e-4) and w["Y"] == pytest.approx(0.8 * 0.008)
    # spread over S times the backlash: 2 mm / 0.0167 mm is over the limit of 100
    assert w["S"] == 100
    p2 = Params.from_dict(dict(PAPER, backlash={"x": 50.0, "smoothing_mm": 1.0}))
    w2 = _words(_line(_section(export(p2)["reprapfirmware"], "config_g"), "M425"))
    assert w2["S"] == 20 and w2["X"] == 0.05  # 20 * 0.05 mm = KinComp's 1 mm
    notes = " ".join(ex.notes)
    assert "3.5 or later" in notes and "already is 0.8 of the measured one" in notes


def test_nothing_to_export_says_so():
    for ex in export(Params()).values():
        assert ex.sections == []
        assert ex.notes == ["Nothing to export: squareness, scale and backlash are all zero."]
    text = format_export(Params())
    assert text.count("Nothing to export") == 3
    # backlash only: Klipper cannot take it, says so and what to do instead
    ex = export(Params.from_dict({"backlash": {"x": 30.0}}))
    assert ex["klipper"].sections == []
    assert ex["klipper"].notes[0] == (
        "Nothing to export to Klipper: it cannot take any of these corrections."
    )
    assert "no backlash compensation" in ex["klipper"].notes[1]
    assert [s.key for s in ex["marlin"].sections] == ["terminal"]


def test_terms_only_kincomp_applies_and_corexy_scale_are_noted():
    p = Params.from_dict(
        {"kinematics": "corexy", "scale_ppm": {"x": 100.0}, "axis_errors": {"x": {"rz_urad": 20.0}}}
    )
    ex = export(p)
    for fw in ("klipper", "marlin"):
        notes = " ".join(ex[fw].notes)
        assert "CoreXY" in notes and "full axis error terms" in notes
    assert "CoreXY" not in " ".join(ex["reprapfirmware"].notes)  # M579 acts on X and Y


def test_export_is_deterministic_json_and_translatable():
    p = Params.from_dict(PAPER)
    assert format_export(p) == format_export(Params.from_dict(PAPER))
    eq = equivalents(p)
    assert json.loads(json.dumps(eq))["export"] == export_json(p)
    assert eq["about"] == {
        "version": __version__,
        "homepage": __plugin_url__,
        "firmware_help": __plugin_url__ + "/blob/main/docs/firmware-export.md",
    }
    fw = eq["export"]["marlin"]
    assert fw["name"] == "Marlin" and fw["comment"] == ";"
    assert fw["sections"][0]["title"]["template"].startswith("Send to the printer")
    built = fw["notes"][0]
    assert built["template"].startswith("Marlin must be built with %(options)s")
    assert "SKEW_CORRECTION" in built["params"]["options"]
    header = fw["sections"][0]["text"].splitlines()[0]
    assert header == f"; KinComp {__version__} firmware export"  # (no hash: issue 35)


def test_default_output_is_the_one_line_equivalents():
    p = Params.from_dict({"squareness_um_per_m": {"xy": -3638.6}, "backlash": {"x": 20}})
    text = format_equivalents(p)
    assert text.splitlines()[:2] == [
        "# Marlin",
        "M852 I-0.003639 J0.000000 K0.000000 ; skew factors (SKEW_CORRECTION_GCODE)",
    ]
    assert "M556 S100 X0.36386 Y0.00000 Z0.00000" in text


def test_current_values_must_be_three_positive_numbers():
    for bad in ((80.0, 80.0), (80.0, 0.0, 400.0), (80.0, math.nan, 400.0)):
        with pytest.raises(ValueError, match="steps_per_mm"):
            export(Params(), steps_per_mm=bad)
    with pytest.raises(ValueError, match="rotation_distance"):
        export(Params(), rotation_distance=(40.0, -1.0, 8.0))
