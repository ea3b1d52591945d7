"""ISO 230-4 test programs (issue 7)."""

import math

import pytest

from octoprint_kincomp.calibration.ballbar.program import (
    ProgramError,
    TestSpec,
    arc_angles,
    cap_feed,
    generate,
    run_angles,
    spec_from_program,
)
from octoprint_kincomp.cli import main
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Move


def moves(text, start):
    fw = FirmwareInterpreter(start=start)
    return [ev for ev in fw.run(text.splitlines()) if isinstance(ev, Move)]


@pytest.mark.parametrize(
    "plane, centre", [("XY", (110, 110, 10)), ("XZ", (110, 110, 100)), ("YZ", (110, 110, 100))]
)
def test_program_geometry(plane, centre):
    spec = TestSpec(plane=plane, centre=centre)
    text = generate(spec, date="test")
    cmds = [l.split()[0] for l in text.splitlines() if l and not l.startswith(";")]
    assert not {"G2", "G3", "G02", "G03", "G18", "G19"} & set(cmds)  # G1 polylines only
    a, b = spec.axes
    pts = [m.end for m in moves(text, centre) if m.feed == spec.feed_mm_min]
    radii = [math.hypot(p[a] - centre[a], p[b] - centre[b]) for p in pts]
    # feed-in/out points at R + 1, everything else on the circle (4 decimals)
    on = [r for r in radii if abs(r - 100.0) < 0.5]
    assert all(abs(r - 100.0) < 2e-4 for r in on)
    assert sum(1 for r in radii if abs(r - 101.0) < 2e-4) >= 4
    # chord error <= 0.5 um: consecutive points on the circle
    circ = [p for p, r in zip(pts, radii) if abs(r - 100) < 0.5]
    for p, q in zip(circ, circ[1:]):
        chord = math.hypot(p[a] - q[a], p[b] - q[b])
        sagitta = 100.0 - math.sqrt(max(0.0, 100.0**2 - (chord / 2) ** 2))
        assert sagitta <= 0.5e-3 + 1e-6
    # the coordinate that is not in the plane never changes during the test
    other = 3 - a - b
    assert len({round(p[other], 6) for p in pts}) == 1


def test_capture_and_directions_xy():
    spec = TestSpec()
    assert spec.capture_deg == 360 and spec.start_deg == 0
    assert run_angles(spec, "ccw") == (-20.0, 400.0)
    assert run_angles(spec, "cw") == (380.0, -400.0)
    text = generate(spec)
    assert text.count("; sync marker") == 2 and text.count("; end marker") == 2
    assert "; --- run ccw" in text and "; --- run cw" in text
    assert "radial feed-in" in text and "radial feed-out" in text


def test_vertical_planes_default_to_220_deg_from_minus_20():
    spec = TestSpec(plane="XZ", centre=(110, 110, 100))
    assert (spec.capture_deg, spec.start_deg) == (220.0, -20.0)
    assert run_angles(spec, "ccw") == (-40.0, 260.0)


def test_quadrant_points_present():
    spec = TestSpec()
    angs = arc_angles(spec, -20.0, 400.0)
    for q in (0, 90, 180, 270, 360):
        assert any(abs(x - q) < 1e-9 for x in angs)


def test_header_comments_and_round_trip():
    spec = TestSpec(plane="XY", centre=(100, 100, 5), radius_mm=50, feed_mm_min=1200)
    text = generate(spec, params_hash="abc123", date="2026-01-02 03:04")
    head = text.splitlines()[:20]
    assert head[0].startswith("; KinComp ballbar test") and "2026-01-02 03:04" in head[0]
    assert any("radius 50 mm, feed 1200 mm/min" in h for h in head)
    assert any("params hash abc123" in h for h in head)
    back, h = spec_from_program(text)
    assert back.radius_mm == 50 and back.centre == (100, 100, 5) and back.feed_mm_min == 1200
    assert len(h) == 12


def test_z_lift_before_travel():
    text = generate(TestSpec())
    lines = [l for l in text.splitlines() if not l.startswith(";")]
    i_lift = next(i for i, l in enumerate(lines) if l.startswith("G1 Z10 F600"))
    i_travel = next(i for i, l in enumerate(lines) if "travel to above the start" in l)
    assert lines[i_lift - 1] == "G91" and i_lift < i_travel


def test_bounds_check_names_the_problem():
    with pytest.raises(ProgramError, match=r"X reaches -51.00 mm, below the limit 0 mm"):
        generate(TestSpec(centre=(50, 110, 10)), volume=(0, 220, 0, 220, 0, 250))
    with pytest.raises(ProgramError, match="Z reaches"):
        generate(TestSpec(plane="XZ", centre=(110, 110, 20)), volume=(0, 220, 0, 220, 0, 250))
    generate(TestSpec(radius_mm=50, centre=(110, 110, 10)), volume=(0, 220, 0, 220, 0, 250))


def test_small_radius_and_feed_cap():
    assert cap_feed(1850, "XZ", {"x": 12000, "y": 12000, "z": 300}) == 300
    assert cap_feed(1850, "XY", {"x": 12000, "y": 12000, "z": 300}) == 1850
    text = generate(
        TestSpec(radius_mm=25, centre=(50, 50, 5), feed_mm_min=300, requested_feed_mm_min=1850)
    )
    assert "feed capped from 1850 mm/min" in text


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"plane": "XX"}, "plane"),
        ({"radius_mm": 0}, "radius"),
        ({"feed_mm_min": -5}, "feed"),
        ({"centre": (1, 2)}, "centre"),
    ],
)
def test_bad_specs(kw, msg):
    with pytest.raises(ProgramError, match=msg):
        TestSpec(**kw)


def test_cli_program(tmp_path, capsys):
    out = tmp_path / "ballbar_xy.gcode"
    rc = main(
        [
            "program",
            "--plane",
            "XY",
            "--centre",
            "110,110,10",
            "--radius",
            "100",
            "--feed",
            "1850",
            "-o",
            str(out),
        ]
    )
    assert rc == 0 and out.read_text().startswith("; KinComp ballbar test")
    rc = main(
        ["program", "--plane", "XZ", "--centre", "110,110,10", "--volume", "0,220,0,220,0,250"]
    )
    assert rc == 1 and "does not fit" in capsys.readouterr().err
