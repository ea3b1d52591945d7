"""Limits policies and the dry-run report of the compensator (issue 2)."""

import pytest

from octoprint_kincomp.core.compensator import LimitError, Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator

# every test here runs once per engine (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("engine")

SKEW = {"squareness_um_per_m": {"xy": 2000.0}, "scale_ppm": {"x": 300.0}}
LIMITS = (0, 200, 0, 200, 0, 180)


def edge_program():
    # desired X=0 at Y=100: the skew correction pushes the command to X=-0.2 (outside)
    return ["G28", "G1 X10 Y100 Z1", "G1 X0 Y100", "G1 X-5 Y100", "G1 X100 Y100"]


@pytest.mark.parametrize("policy", ["warn", "clamp"])
def test_limit_policies_warn_and_clamp(policy):
    comp = make_compensator(Params.from_dict(SKEW), Options(limits=LIMITS, policy=policy))
    outs = [comp.process(l) for l in edge_program()]
    # line 3 pushed past X0; line 4 (the program's own X-5) pushed past X-5
    assert comp.report.limit_hits == 2
    assert [e[:2] for e in comp.report.limit_examples] == [(3, "X"), (4, "X")]
    assert comp.report.limit_worst_axis == "X"
    assert comp.report.limit_worst_um == pytest.approx(199.94, abs=0.01)  # line 3
    x = float(outs[2][0].split()[1][1:])
    x_own = float(outs[3][0].split()[1][1:])
    assert comp.report.source_outside == 1
    if policy == "clamp":
        assert x == 0.0
        # a point the program itself puts past the limit marks where the travel ends:
        # compensation does not push it further out (nor pull it in to X0)
        assert x_own == -5.0
    else:
        assert x == pytest.approx(-0.2, abs=0.001)
        assert x_own == pytest.approx((-5 - 0.2) / 1.0003, abs=0.001)


def test_clamp_is_the_default_policy():
    assert Options().policy == "clamp"


def test_a_point_past_the_edge_that_compensation_pulls_inward_is_kept():
    # the program's X-5 at Y100 under xy -2000: compensation moves X inward (+0.2): kept
    comp = make_compensator(
        Params.from_dict({"squareness_um_per_m": {"xy": -2000.0}}), Options(limits=LIMITS)
    )
    outs = [comp.process(l) for l in ["G28", "G1 X10 Y100 Z1", "G1 X-5 Y100"]]
    assert outs[2] == ["G1 X-4.8 Y100"]
    assert comp.report.limit_hits == 0 and comp.report.source_outside == 1


def test_the_clamp_rounds_toward_the_inside():
    """Review of issue 36: a limit with more decimals than the output (a box from a file's
    own 4-decimal extent) was clamped to 90.4598 and written 90.46, past it."""
    limits = (0, 200, 0, 90.4598, 0, 180)
    comp = make_compensator(Params.from_dict(SKEW), Options(limits=limits))
    lines = ["G28", "G1 X10 Y10 Z1", "G1 X150 Y90.4", "G1 X150 Y90.45979", "G1 X100 Y90.4598"]
    outs = [comp.process(l) for l in lines]
    ys = [float(w[1:]) for o in outs[2:] for w in o[0].split() if w[0] == "Y"]
    assert ys[1:] == [90.459, 90.459]  # (90.45979 and the limit itself: not 90.46)
    assert max(ys) <= 90.4598


def test_the_clamp_rounds_toward_the_inside_below_the_limit_too():
    limits = (0.0004, 200, 0, 200, 0, 180)
    comp = make_compensator(Params.from_dict(SKEW), Options(limits=limits))
    outs = [comp.process(l) for l in ["G28", "G1 X10 Y10 Z1", "G1 X0.0004 Y50"]]
    assert outs[2][0].split()[1] == "X0.001"  # (X0 would be past 0.0004)
    assert comp.report.limit_hits == 1


def test_limit_policy_error_names_the_line():
    comp = make_compensator(Params.from_dict(SKEW), Options(limits=LIMITS, policy="error"))
    with pytest.raises(LimitError, match=r"line 3: compensated X=-0\.1999 mm is outside"):
        for l in edge_program():
            comp.process(l)


def test_options_validation():
    with pytest.raises(ValueError, match="policy"):
        Options(policy="ignore")
    with pytest.raises(ValueError, match="min < max"):
        Options(limits=(10, 0, 0, 1, 0, 1))


def test_report_counts_and_max_correction():
    comp = make_compensator(Params.from_dict(SKEW), Options(linearise_arcs=True))
    for l in edge_program() + ["G2 X120 Y100 I10 J0", "G1 X1 X2"]:
        comp.process(l)
    r = comp.report.to_dict()
    assert r["moves"] == 6 and r["moves_compensated"] == 5 and r["malformed"] == 1
    assert r["arcs_linearised"] == 1 and r["arc_segments"] > 2
    top = comp.model.inverse((110.0, 110.0, 1.0))[0]  # the arc's top is the worst point
    assert r["max_correction_um"]["x"] == pytest.approx(abs(top - 110.0) * 1000, abs=0.5)
    assert r["lines_out"] > r["lines"]
