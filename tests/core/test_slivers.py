"""No output move of no length carries extrusion where the input move had length (issue 28):
a piece of an arc or a chord whose rounded coordinates do not move passes its E (and the
first piece's other words) on to the next piece, and a last piece folds its E back into the
piece before it."""

import pytest

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from tests.support.helpers import compensate_groups, zero_length_extrusions

pytestmark = pytest.mark.usefixtures("engine")

ALL = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": -3638.6, "xz": 500.0, "yz": 500.0},
        "scale_ppm": {"x": -451.7, "y": 287.0},
        "backlash": {"x": 50.0, "y": 30.0},
    }
)
START = ["G28", "G90", "G1 X100 Y100 Z0.3 F1200"]
TINY_ARCS = [
    "G2 X100.001 Y100.002 I0.0014 J0.0007 E0.0005",
    "G3 X100.002 Y100 I0.0007 J-0.0014 E0.0005",
    "G2 I0.0014 J0.0002 E0.001",
]


def extrusion(groups, relative):
    """Total E of the output lines of ``groups`` that carry one (relative), or the last."""
    es = [float(w[1:]) for _, outs in groups for o in outs for w in o.split()[1:] if w[0] == "E"]
    return sum(es) if relative else es[-1]


@pytest.mark.parametrize("mode", ["M83", "M82"])
def test_tiny_arcs_leave_no_e_only_slivers(mode):
    """Arcs of radius ~1.4 um cut at the backlash breaks: pieces that round to no motion."""
    lines = START + [mode, "G92 E10"] + TINY_ARCS
    if mode == "M82":
        lines = START + [
            mode,
            "G92 E10",
            "G2 X100.001 Y100.002 I0.0014 J0.0007 E10.0005",
            "G3 X100.002 Y100 I0.0007 J-0.0014 E10.001",
            "G2 I0.0014 J0.0002 E10.002",
        ]
    _, groups = compensate_groups(ALL, lines, Options())
    assert zero_length_extrusions(groups) == []
    for _, outs in groups:
        for o in outs:
            assert not o.startswith("G1 E"), outs
    want = 0.002 if mode == "M83" else 10.002
    assert extrusion(groups[5:], mode == "M83") == pytest.approx(want, abs=1e-12)


def test_an_arc_ending_next_to_a_reversal_has_no_empty_last_piece():
    """The ArcWelder benchy line (issue 28): the last piece after the X reversal rounded to
    the arc piece's own end and carried E 0.00005 on a move of no length; its E now ends the
    arc piece before it."""
    lines = [
        "G28",
        "G90",
        "M82",
        "G92 E126.22596",
        "G1 X108.993 Y109.182 Z37.4",
        "G1 X91.643 Y108.184",
        "G3 X90.771 Y107.272 I0.037 J-0.908 E126.33664",
    ]
    _, groups = compensate_groups(ALL, lines, Options())
    assert zero_length_extrusions(groups) == [], groups[-1]
    assert groups[-1][1] == ["G3 X91.159 Y107.208 I0.037 J-0.911 E126.33664"]
