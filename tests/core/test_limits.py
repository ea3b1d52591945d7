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
    assert comp.report.limit_hits == 1
    assert comp.report.limit_examples[0][:2] == (3, "X")
    x = float(outs[2][0].split()[1][1:])
    if policy == "clamp":
        assert x == 0.0
    else:
        assert x == pytest.approx(-0.2, abs=0.001)
    # a point the program itself puts outside is never altered by the policy
    assert comp.report.source_outside == 1
    assert float(outs[3][0].split()[1][1:]) == pytest.approx((-5 - 0.2) / 1.0003, abs=0.001)


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
