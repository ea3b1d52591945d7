"""The printer's motion limits (M503, printer.cfg, profile) and the feasible test feed
(issue 23)."""

import math

import pytest

from octoprint_kincomp.calibration.ballbar.campaign import plan_campaign
from octoprint_kincomp.calibration.ballbar.program import ProgramError, TestSpec, generate
from octoprint_kincomp.cli import main
from octoprint_kincomp.firmware.motion_limits import (
    MIN_TEST_FEED,
    LimitsError,
    MotionLimits,
    circle_feed,
    parse_limits,
    require_known,
    steps_per_mm,
)

# Marlin 2 (Ender-3 defaults) as OctoPrint's terminal shows M503's answer
MARLIN = """Send: M503
Recv: echo:; Linear Units:
Recv: echo:  G21 ; (mm)
Recv: echo:; Steps per unit:
Recv: echo: M92 X80.00 Y80.00 Z400.00 E93.00
Recv: echo:; Maximum feedrates (units/s):
Recv: echo:  M203 X500.00 Y500.00 Z5.00 E25.00
Recv: echo:; Maximum Acceleration (units/s2):
Recv: echo:  M201 X500.00 Y500.00 Z100.00 E5000.00
Recv: echo:; Acceleration (units/s2): P<print_accel> R<retract_accel> T<travel_accel>
Recv: echo:  M204 P500.00 R500.00 T1000.00
Recv: echo:; Advanced: B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>
Recv: echo:  M205 B20000.00 S0.00 T0.00 J0.08
Recv: ok
"""
# RepRapFirmware: M503 lists config.g, M203 in mm/min
RRF = """; Drives
M92 X80.00 Y80.00 Z400.00 E420.00        ; set steps per mm
M566 X900.00 Y900.00 Z60.00 E120.00      ; set maximum instantaneous speed changes (mm/min)
M203 X6000.00 Y6000.00 Z180.00 E1200.00:1200.00 ; set maximum speeds (mm/min)
M201 X500.00 Y500.00 Z20.00 E250.00      ; set accelerations (mm/s^2)
M204 P600 T2000
"""
KLIPPER = """[stepper_z]
max_velocity: 999
[printer]
kinematics: cartesian
max_velocity: 300   # mm/s
max_accel = 3000
max_z_velocity: 10
max_z_accel: 100
square_corner_velocity: 5.0
[extruder]
max_accel: 1
"""


def test_marlin_m503_in_its_units():
    lim = parse_limits(MARLIN)
    assert lim.max_feed_mm_min == {"x": 30000.0, "y": 30000.0, "z": 300.0}  # 5 mm/s
    assert lim.max_accel_mm_s2 == {"x": 500.0, "y": 500.0, "z": 100.0}
    assert (lim.print_accel_mm_s2, lim.travel_accel_mm_s2) == (500.0, 1000.0)
    assert lim.junction_deviation_mm == 0.08 and lim.notes == []
    assert lim.sources["max_feed_mm_min.z"] == "M203 (mm/s)"


def test_reprapfirmware_m203_is_mm_per_min():
    lim = parse_limits(RRF)
    assert lim.max_feed_mm_min == {"x": 6000.0, "y": 6000.0, "z": 180.0}
    assert lim.max_accel_mm_s2["z"] == 20.0
    assert (lim.print_accel_mm_s2, lim.travel_accel_mm_s2) == (600.0, 2000.0)
    # without a unit in the text, the firmware's name decides; else mm/s is assumed and said
    assert (
        parse_limits("M203 X100 Y100 Z3", "RepRapFirmware for Duet 3").max_feed_mm_min["z"] == 3.0
    )
    bare = parse_limits("M203 X100 Y100 Z3")
    assert bare.max_feed_mm_min["z"] == 180.0 and "mm/s" in str(bare.notes[0])
    assert parse_limits("M203 X100 Y100 Z3", "Marlin 2.1.2").notes == []


def test_klipper_printer_cfg_only_the_printer_section():
    lim = parse_limits(KLIPPER)
    assert lim.max_feed_mm_min == {"x": 18000.0, "y": 18000.0, "z": 600.0}
    assert lim.max_accel_mm_s2 == {"x": 3000.0, "y": 3000.0, "z": 100.0}
    assert lim.print_accel_mm_s2 == 3000.0 and lim.square_corner_velocity_mm_s == 5.0
    # a pasted fragment without a section, and Klipper's runtime command
    assert parse_limits("max_velocity: 200\nmax_accel: 2000").max_feed_mm_min["z"] == 12000.0
    svl = parse_limits("SET_VELOCITY_LIMIT VELOCITY=250 ACCEL=4000")
    assert svl.max_feed_mm_min["x"] == 15000.0 and svl.print_accel_mm_s2 == 4000.0


def test_steps_per_mm_from_m92_and_klipper_steppers():
    """The drives' resolution (the reversal dead band follows it): Marlin's and
    RepRapFirmware's M92 (E left out), Klipper's [stepper_x/y/z] (200 full steps a turn unless
    said); nothing stated: nothing, never an error."""
    assert steps_per_mm(MARLIN) == {"x": 80.0, "y": 80.0, "z": 400.0}
    assert steps_per_mm(RRF) == {"x": 80.0, "y": 80.0, "z": 400.0}
    cfg = (
        "[stepper_x]\nrotation_distance: 40\nmicrosteps: 16\n"
        "[stepper_y]\nrotation_distance: 40 # GT2 20T\nmicrosteps: 32\n"
        "full_steps_per_rotation: 400\n[extruder]\nrotation_distance: 7\nmicrosteps: 16\n"
    )
    assert steps_per_mm(cfg) == {"x": 80.0, "y": 320.0}
    for text in (KLIPPER, "", "M92 X0 Yabc", None):
        assert steps_per_mm(text) == {}


@pytest.mark.parametrize("text", ["", "hello\nok", "M203", "M203 X-5 Y0", "[printer]\nfoo: 1"])
def test_nothing_usable_is_refused(text):
    with pytest.raises(LimitsError, match="no motion limits found"):
        parse_limits(text)


def test_a_number_with_an_exponent_is_read_whole():
    """``M203 X1e307`` was read as X 1 mm/s with Y and Z dropped (issue 37, row 3's probe):
    the number is read whole and refused as out of range; a plain exponent is a number."""
    with pytest.raises(LimitsError, match=r"max_feed_mm_min\.x .* out of range"):
        parse_limits("M203 X1e307 Y500 Z12 ; mm/s")
    lim = parse_limits("M201 X1.5e3 Y1500 Z100\nM203 X3e2 Y300 Z12 ; mm/s")
    assert lim.max_accel_mm_s2 == {"x": 1500.0, "y": 1500.0, "z": 100.0}
    assert lim.max_feed_mm_min == {"x": 18000.0, "y": 18000.0, "z": 720.0}


def test_later_lines_win_and_sources_combine_to_the_lower():
    lim = parse_limits("M203 X200 Y200 Z10 ; mm/s\nM203 Z8 ; mm/s")
    assert lim.max_feed_mm_min["z"] == 480.0
    profile = MotionLimits.from_feeds({"x": 6000, "y": 6000, "z": 200}, "printer profile")
    both = lim.combined(profile)
    assert both.max_feed_mm_min == {"x": 6000.0, "y": 6000.0, "z": 200.0}
    assert both.sources["max_feed_mm_min.z"] == "printer profile"
    assert both.sources["max_feed_mm_min.x"] == "printer profile"
    assert lim.combined(MotionLimits.from_feeds({"z": 9000}, "p")).max_feed_mm_min["z"] == 480


def test_vertical_circle_feed_is_capped_by_z_and_says_why():
    """The issue's case: an XZ test at F1850 on a printer whose Z reaches 10 mm/s."""
    choice = circle_feed("XZ", 50, 1850, parse_limits("M203 X300 Y300 Z10 ; mm/s"))
    assert choice.feed_mm_min == 600.0 and choice.lowered
    assert "Z axis' max feed is 600 mm/min" in str(choice.reasons[0])
    # XY is not bound by Z
    assert circle_feed("XY", 50, 1850, parse_limits(MARLIN)).feed_mm_min == 1850.0


def test_acceleration_bounds_the_feed():
    """v^2 <= a * R and reached within the overshoot: v^2 <= 2 a R * overshoot (rad)."""
    lim = parse_limits("M201 X50 Y500 Z100\nM203 X500 Y500 Z50 ; mm/s")
    choice = circle_feed("XY", 20, 6000, lim, overshoot_deg=20)
    expect = math.sqrt(50 * 20 * min(1.0, 2 * math.radians(20))) * 60
    assert choice.feed_mm_min == math.floor(expect)
    assert "X axis' max acceleration" in str(choice.reasons[0])
    # a longer overshoot lets the circle's own limit v^2 = a R bind
    long = circle_feed("XY", 20, 6000, lim, overshoot_deg=90)
    assert long.feed_mm_min == math.floor(math.sqrt(50 * 20) * 60)
    # the print acceleration bounds too
    m204 = circle_feed("XY", 20, 6000, parse_limits("M204 P10"))
    assert "print acceleration" in str(m204.reasons[0])


def test_an_unreachable_feed_is_refused_naming_the_limit():
    with pytest.raises(LimitsError, match="Z axis' max feed is 30 mm/min"):
        circle_feed("YZ", 50, 1850, parse_limits("M203 X200 Y200 Z0.5 ; mm/s"))
    assert MIN_TEST_FEED == 60.0


def test_unknown_z_refused_for_vertical_planes_only():
    choice = circle_feed("XZ", 50, 1850, None)
    assert choice.unknown == ["x", "z"]
    with pytest.raises(LimitsError, match="Z axis' max feed is not known"):
        require_known(choice, "XZ")
    require_known(circle_feed("XY", 50, 1850, None), "XY")  # no refusal


def test_program_pins_the_speed_factor():
    text = generate(TestSpec(plane="XY"), date="-")
    body = [l for l in text.splitlines() if not l.startswith(";")]
    m220 = [i for i, l in enumerate(body) if l.startswith("M220")]
    first_move = next(i for i, l in enumerate(body) if l.startswith("G1"))
    assert m220 and body[m220[0]].startswith("M220 S100") and m220[0] < first_move


def test_campaign_feeds_within_the_limits():
    lim = parse_limits(MARLIN)  # Z 5 mm/s
    steps = plan_campaign((0, 220, 0, 220, 0, 250), limits=lim, require_limits=True)
    feeds = {s.name: s.spec.feed_mm_min for s in steps}
    assert feeds == {"xy": 1850.0, "xz": 300.0, "yz": 300.0}
    assert steps[1].spec.requested_feed_mm_min == 1850.0
    assert "Z axis' max feed is 300 mm/min" in steps[1].feed_notes[0]
    with pytest.raises(ProgramError, match="campaign test XZ: the Z axis' max feed is not"):
        plan_campaign((0, 220, 0, 220, 0, 250), require_limits=True)


def test_cli_program_reads_limits_and_refuses_without_them(tmp_path, capsys):
    m503 = tmp_path / "m503.txt"
    m503.write_text(MARLIN)
    out = tmp_path / "xz.gcode"
    assert (
        main(
            [
                "program",
                "--plane",
                "XZ",
                "--centre",
                "110,110,60",
                "--radius",
                "50",
                "--limits",
                str(m503),
                "-o",
                str(out),
            ]
        )
        == 0
    )
    text = out.read_text()
    assert "; ballbar feed_mm_min: 300" in text and "F300" in text and "F1850" not in text
    assert "; feed lowered from 1850 to 300 mm/min" in text
    assert "feed lowered" in capsys.readouterr().err
    # no limits: an XZ test is refused, saying what to give
    assert (
        main(
            [
                "program",
                "--plane",
                "XZ",
                "--centre",
                "110,110,60",
                "--radius",
                "50",
                "-o",
                str(tmp_path / "no.gcode"),
            ]
        )
        == 1
    )
    err = capsys.readouterr().err
    assert "Z axis' max feed is not known" in err and not (tmp_path / "no.gcode").exists()
    # --max-feed and --max-accel count too (the lower of each)
    assert (
        main(
            [
                "program",
                "--plane",
                "XZ",
                "--centre",
                "110,110,60",
                "--radius",
                "50",
                "--max-feed",
                "6000,6000,900",
                "--max-accel",
                "1000,1000,2",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    assert "Z axis' max acceleration" in out.read_text()
    bad = tmp_path / "bad.txt"
    bad.write_text("nothing here")
    assert (
        main(
            [
                "program",
                "--plane",
                "XY",
                "--centre",
                "110,110,10",
                "--limits",
                str(bad),
                "-o",
                str(out),
            ]
        )
        == 1
    )
    assert "no motion limits found" in capsys.readouterr().err
