"""The printed artifact's program (issue 27): contract header, G-code through KinComp's own
interpreter, inside the volume."""

import math

import pytest

from octoprint_kincomp.calibration.artifact.program import (
    ArtifactProgramError,
    ArtifactSpec,
    generate,
    layout,
    read_measurements,
    read_program_info,
)
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Home, Move

VOLUME = (0.0, 220.0, 0.0, 220.0, 0.0, 250.0)


def run(text):
    fw = FirmwareInterpreter(home_mm=(0.0, 0.0, 0.0), start=(0.0, 0.0, 0.0))
    events = list(fw.run(text.splitlines()))
    return fw, events


def test_program_parses_and_stays_in_volume():
    spec = ArtifactSpec(volume=VOLUME)
    text = generate(spec)
    fw, events = run(text)
    assert fw.malformed == 0
    moves = [e for e in events if isinstance(e, Move)]
    assert any(isinstance(e, Home) for e in events)
    for m in moves:
        for k, (lo, hi) in enumerate(((0, 220), (0, 220), (0, 250))):
            assert lo <= m.end[k] <= hi
    printing = [m for m in moves if m.e > 0]
    assert printing and sum(m.e for m in printing) > 100  # mm of filament
    # heats, homes before printing, ends with heaters off
    cmds = [ln.split()[0] for ln in text.splitlines() if ln and not ln.startswith(";")]
    assert cmds.index("M190") < cmds.index("G28") < cmds.index("M109")
    assert cmds[-5:] == ["M104", "M140", "M107", "G0", "M84"]
    assert "M104 S0" in text and "M140 S0" in text
    assert "M83" in cmds


def test_walls_are_printed_where_the_contract_says():
    """Each measurement's from/to points lie on a printed line of their layer (the walls'
    centre planes), so the header describes the part the program prints."""
    spec = ArtifactSpec(volume=VOLUME)
    text = generate(spec)
    _, events = run(text)
    lines = [m for m in events if isinstance(m, Move) and m.e > 0]
    for meas in read_measurements(text):
        for p in (meas.start, meas.end):
            near = [m for m in lines if abs(m.end[2] - spec.layer / 2 - p[2]) <= spec.layer]
            best = min(_dist_point_segment(p[:2], m.start[:2], m.end[:2]) for m in near)
            assert best < 0.1, (meas.id, p, best)


def _dist_point_segment(c, a, b):
    dx, dy = b[0] - a[0], b[1] - a[1]
    L2 = dx * dx + dy * dy
    t = max(0.0, min(1.0, ((c[0] - a[0]) * dx + (c[1] - a[1]) * dy) / L2)) if L2 else 0.0
    return math.hypot(c[0] - a[0] - t * dx, c[1] - a[1] - t * dy)


def test_contract_header():
    text = generate(
        ArtifactSpec(volume=VOLUME, nozzle_mm=0.6, hotend_c=240, bed_c=80, first_layer_mm=0.3)
    )
    meas = read_measurements(text)
    ids = [m.id for m in meas]
    assert len(ids) == len(set(ids)) == 36
    assert {m.kind for m in meas} == {"outside", "inside"}
    assert {m.plane for m in meas} == {"X", "Y", "XY", "XZ", "YZ"}
    for m in meas:
        assert m.length + 0.7 <= 150.0  # an outside reading fits a 150 mm caliper
        assert m.hint
    info = read_program_info(text)
    assert info["nozzle_mm"] == "0.6" and info["temperatures_c"] == "240,80"
    assert info["first_layer_mm"] == "0.3" and info["line_width_mm"] == "0.675"
    assert "M109 S240" in text and "M190 S80" in text
    # the first layer is printed at its own height
    _, events = run(text)
    first = [m for m in events if isinstance(m, Move) and m.e > 0][0]
    assert first.end[2] == pytest.approx(0.3)


def test_planes_subset_and_features():
    feats = layout(ArtifactSpec(volume=VOLUME, planes=("XY",)))
    assert {f.plane for f in feats} == {"XY"}
    # diagonals at 45 deg in both senses, spans along X and Y
    dirs = {tuple(round(c, 3) for c in f.n) for f in feats}
    assert {(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.707, 0.707, 0.0), (0.707, -0.707, 0.0)} == dirs
    towers = layout(ArtifactSpec(volume=VOLUME, planes=("XZ", "YZ")))
    assert {f.plane for f in towers} == {"XZ", "YZ"}
    assert all(abs(abs(f.n[2]) - math.sqrt(0.5)) < 1e-12 for f in towers)


@pytest.mark.parametrize(
    "volume, planes",
    [((0, 180, 0, 180, 0, 180), ("XY", "XZ", "YZ")), ((0, 150, 0, 150, 0, 150), ("XY",))],
)
def test_small_beds_get_shorter_diagonals(volume, planes):
    """A 180 mm bed (all parts) or 150 mm (XY alone): the diagonals are shortened until every
    wall keeps its clearance; the program still parses and stays in the volume."""
    feats = layout(ArtifactSpec(volume=volume, planes=planes))
    diag = [f for f in feats if f.name.startswith("A")]
    assert len(diag) == 5 and 60.0 <= diag[0].length < 147.0
    text = generate(ArtifactSpec(volume=volume, planes=planes))
    fw, events = run(text)
    assert fw.malformed == 0
    for m in (e for e in events if isinstance(e, Move)):
        assert all(volume[2 * k] <= m.end[k] <= volume[2 * k + 1] for k in range(3))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(volume=(0, 60, 0, 60, 0, 100)), "too small"),
        (dict(volume=(0, 220, 0, 220, 0, 30), planes=("XZ",)), "no room"),
        (dict(planes=("XW",)), "planes"),
        (dict(nozzle_mm=5.0), "nozzle"),
        (dict(volume=(10, 0, 0, 220, 0, 250)), "volume"),
    ],
)
def test_bad_specs_are_refused(kwargs, word):
    with pytest.raises(ArtifactProgramError) as exc:
        generate(ArtifactSpec(**kwargs))
    assert word in str(exc.value)


@pytest.mark.parametrize(
    "line, word",
    [
        ("; kincomp measure: id=a kind=sideways from=0,0,0 to=10,0,0 hint=x", "kind"),
        ("; kincomp measure: id=a kind=outside from=0,0 to=10,0,0 hint=x", "three numbers"),
        ("; kincomp measure: id=a kind=outside from=0,0,0 to=0.5,0,0 hint=x", "1 mm"),
        ("; kincomp measure: kind=outside", "malformed"),
    ],
)
def test_bad_contract_lines(line, word):
    with pytest.raises(ArtifactProgramError) as exc:
        read_measurements(line + "\n")
    assert word in str(exc.value)
    with pytest.raises(ArtifactProgramError, match="not a KinComp artifact"):
        read_measurements("G28\n")
    dup = "; kincomp measure: id=a kind=outside from=0,0,0 to=10,0,0 hint=x\n"
    with pytest.raises(ArtifactProgramError, match="twice"):
        read_measurements(dup + dup)


def test_drawing_numbers_every_measurement():
    from octoprint_kincomp.calibration.artifact.drawing import legend, svg

    text = generate(ArtifactSpec(volume=VOLUME))
    meas = read_measurements(text)
    drawing = svg(meas, VOLUME)
    assert drawing.startswith("<svg") and drawing.rstrip().endswith("</svg>")
    labels = [f">{2 * k + 1}/{2 * k + 2}</text>" for k in range(len(meas) // 2)]
    assert all(lab in drawing for lab in labels)  # outside/inside of each pair of walls
    assert drawing.count("<text") == len(meas) // 2 + 1  # + the bed's caption
    rows = legend(meas)
    assert [r["n"] for r in rows] == list(range(1, len(meas) + 1))
    assert rows[0]["id"] == meas[0].id and rows[0]["nominal_mm"] == pytest.approx(
        meas[0].length, abs=1e-3
    )


@pytest.mark.parametrize("mode", ["full", "quick"])
def test_every_hint_reaches_the_web_ui_as_a_message(mode):
    """Issue 35: the measuring form showed the header's English hints ("45 deg tower in XZ
    leaning towards -X: caliper along the 45 deg line ...") in the German UI too. Each hint
    KinComp writes is a message of the catalog; a hand-edited one stays as it is."""
    from octoprint_kincomp.calibration.artifact.drawing import legend
    from octoprint_kincomp.calibration.artifact.program import hint_words
    from octoprint_kincomp.core.messages import Msg

    meas = read_measurements(generate(ArtifactSpec(volume=VOLUME, mode=mode)))
    for m, row in zip(meas, legend(meas)):
        words = hint_words(m.hint)
        assert isinstance(words, Msg), m.hint
        assert row["hint_i18n"]["template"] == words.template
        assert " deg " not in str(words) and str(words).count(": ") == 1, str(words)
    assert any("45°" in str(hint_words(m.hint)) for m in meas)
    assert hint_words("my own note") == "my own note"
