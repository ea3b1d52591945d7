"""The printed artifact's analysis (issue 27). Every reading here is SIMULATED: the artifact's
nominal points go through KinComp's kinematic error model, shrink, get a line width, noise and
0.01 mm rounding (simulator/artifact.py)."""

import json
import math

import numpy as np
import pytest

from octoprint_kincomp.calibration.artifact.fit import (
    ArtifactFitError,
    analyse_artifact,
    parse_readings,
)
from octoprint_kincomp.calibration.artifact.program import (
    ArtifactSpec,
    generate,
    read_measurements,
    read_program_info,
)
from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.program import TestSpec
from octoprint_kincomp.calibration.ballbar.program import generate as ballbar_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.artifact import simulate_readings
from octoprint_kincomp.simulator.printer import Truth, simulate_program

PAPER = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": -3638.6, "xz": 800.0, "yz": -600.0},
        "scale_ppm": {"x": -451.7, "y": 287.0, "z": 150.0},
    }
)
PAIRS = (("x", "y"), ("x", "z"), ("y", "z"))


@pytest.fixture(scope="module")
def program():
    text = generate(ArtifactSpec(volume=(0, 220, 0, 220, 0, 250)))
    return read_measurements(text), read_program_info(text)


def truth_of(params):
    t = {("squareness_um_per_m", p): params.squareness_um_per_m[p] for p in ("xy", "xz", "yz")}
    for a, b in PAIRS:
        t[("scale_mismatch_ppm", f"{a}-{b}")] = params.scale_ppm[a] - params.scale_ppm[b]
    return t


def errors_of(result, params):
    d = result["diagnostics"]
    return {
        k: (d[k[0]][k[1]] - v, d["uncertainty"][k[0]][k[1]]) for k, v in truth_of(params).items()
    }


def test_recovers_the_paper_errors(program):
    meas, info = program
    readings = simulate_readings(
        meas, PAPER, shrinkage=0.004, line_width_mm=0.47, rng=np.random.default_rng(3)
    )
    res = analyse_artifact(meas, readings, info=info)
    for key, (err, sigma) in errors_of(res, PAPER).items():
        assert abs(err) <= 3 * sigma, key
    d = res["diagnostics"]
    assert d["uncertainty"]["squareness_um_per_m"]["xy"] <= 30.0
    assert d["line_width_mm"]["vertical_walls"] == pytest.approx(0.47, abs=0.005)
    assert d["line_width_mm"]["slanted_walls"] == pytest.approx(0.47, abs=0.015)
    # shrinkage and the mean scale are one number: -4000 ppm of shrinkage + the axes' mean
    assert d["mean_scale_with_shrinkage_ppm"] == pytest.approx(
        -4000 + (-451.7 + 287 + 150) / 3, abs=60
    )
    assert res["trusted"] is True
    codes = {f["code"] for f in res["findings"]}
    assert {"artifact.absolute_scale", "artifact.model"} <= codes
    assert all(f["severity"] == "info" for f in res["findings"])
    # the proposal: squareness as measured, the mismatch as measured, the mean scale kept
    p = res["parameters"]
    assert p["squareness_um_per_m"]["xy"] == pytest.approx(d["squareness_um_per_m"]["xy"])
    s = p["scale_ppm"]
    assert s["x"] - s["y"] == pytest.approx(d["scale_mismatch_ppm"]["x-y"], abs=0.5)
    assert s["x"] + s["y"] + s["z"] == pytest.approx(0.0, abs=1.0)
    assert p["meta"]["source"] == "printed artifact"
    json.dumps(res)  # JSON as it is


@pytest.mark.parametrize("size", ["paper", "small"])
def test_done_when_coverage(program, size):
    """Issue 27's done-when: random errors (the paper's size, or 100 um/m and 50 ppm), 220 mm
    bed, 0.01 mm readings with 10 um noise, three repeats, line width 0.40-0.50 mm and up to
    0.5 % shrinkage unknown to the fit: every value within its reported 2 sigma in >= 90 % of
    the trials; XY squareness sigma <= 30 um/m (docs/artifact.md states the others)."""
    meas, info = program
    rng = np.random.default_rng(2027 if size == "paper" else 4054)
    hits, sig = {}, {}
    for _ in range(100):
        if size == "paper":
            sq = {
                "xy": -3638.6 * rng.uniform(0.5, 1.2) * float(rng.choice([-1, 1])),
                "xz": rng.uniform(-1500, 1500),
                "yz": rng.uniform(-1500, 1500),
            }
            sc = {a: rng.uniform(-500, 500) for a in "xyz"}
        else:
            sq = {p: 100.0 * float(rng.choice([-1, 1])) for p in ("xy", "xz", "yz")}
            sc = {
                "x": 50.0 * float(rng.choice([-1, 1])),
                "y": 0.0,
                "z": -50.0 * float(rng.choice([-1, 1])),
            }
        truth = Params.from_dict({"squareness_um_per_m": sq, "scale_ppm": sc})
        readings = simulate_readings(
            meas,
            truth,
            shrinkage=rng.uniform(0, 0.005),
            line_width_mm=rng.uniform(0.40, 0.50),
            rng=rng,
        )
        res = analyse_artifact(meas, readings, info=info)
        assert res["trusted"]
        assert not [f for f in res["findings"] if f["severity"] != "info"]
        for key, (err, sigma) in errors_of(res, truth).items():
            hits.setdefault(key, []).append(abs(err) <= 2 * sigma)
            sig.setdefault(key, []).append(sigma)
    for key in hits:
        assert np.mean(hits[key]) >= 0.90, (key, np.mean(hits[key]))
    assert max(sig[("squareness_um_per_m", "xy")]) <= 30.0
    assert max(sig[("squareness_um_per_m", "xz")]) <= 100.0
    assert max(sig[("squareness_um_per_m", "yz")]) <= 100.0
    assert max(sig[("scale_mismatch_ppm", "x-y")]) <= 50.0
    assert max(sig[("scale_mismatch_ppm", "x-z")]) <= 80.0


def test_sign_matches_the_ballbar_route(program):
    """The same simulated machine gives the same squareness sign by both routes (XY and
    XZ): positive = actual X grows with Y (Z), the +X+Y diagonal long."""
    meas, info = program
    for plane, centre, key in (("XY", (110, 110, 10), "xy"), ("XZ", (110, 110, 100), "xz")):
        for value in (400.0, -400.0):
            errors = Params.from_dict({"squareness_um_per_m": {key: value}})
            trace = simulate_program(
                ballbar_program(TestSpec(plane=plane, centre=centre)),
                Truth(errors=errors, noise_um=0.5),
            )
            ballbar = analyse(trace)["diagnostics"]["squareness_um_per_m"]
            readings = simulate_readings(meas, errors, noise_um=2.0, rng=np.random.default_rng(5))
            art = analyse_artifact(meas, readings, info=info)["diagnostics"]
            assert ballbar == pytest.approx(value, abs=10)
            assert art["squareness_um_per_m"][key] == pytest.approx(value, abs=40)
            assert np.sign(ballbar) == np.sign(art["squareness_um_per_m"][key])


def test_a_one_mm_typo_is_named(program):
    meas, info = program
    readings = simulate_readings(meas, PAPER, shrinkage=0.003, rng=np.random.default_rng(8))
    clean = analyse_artifact(meas, readings, info=info)["diagnostics"]
    typo = {k: list(v) for k, v in readings.items()}
    typo["A3-out"][1] += 1.0
    res = analyse_artifact(meas, typo, info=info)
    bad = [f for f in res["findings"] if f["severity"] != "info"]
    assert [(f["code"], f["evidence"]["id"], f["evidence"]["reading"]) for f in bad] == [
        ("artifact.reading_disagrees", "A3-out", 2)
    ]
    assert "A3-out" in bad[0]["message"]
    d = res["diagnostics"]
    assert d["measurements"]["A3-out"]["readings_left_out"] == [2]
    # left out, the result is the clean one within a fraction of its sigma
    assert abs(d["squareness_um_per_m"]["xy"] - clean["squareness_um_per_m"]["xy"]) < 10


@pytest.mark.parametrize("repeats", [3, 1])
def test_a_measurement_off_in_every_repeat_is_named(program, repeats):
    """All repeats of one id 1 mm off (typed consistently wrong, jaws on a blob), or its only
    reading: the fit names the measurement and leaves it out."""
    meas, info = program
    readings = simulate_readings(
        meas, PAPER, shrinkage=0.003, repeats=repeats, rng=np.random.default_rng(9)
    )
    readings["X2-in"] = [v - 1.0 for v in readings["X2-in"]]
    res = analyse_artifact(meas, readings, info=info)
    bad = [f for f in res["findings"] if f["severity"] != "info"]
    assert [(f["code"], f["evidence"]["id"]) for f in bad if "id" in f["evidence"]] == [
        ("artifact.measurement_outlier", "X2-in")
    ]
    # one reading per span: the towers' squareness is said to be poorly determined
    assert {f["code"] for f in bad} - {"artifact.measurement_outlier"} == (
        set() if repeats == 3 else {"artifact.poorly_determined"}
    )
    assert res["diagnostics"]["measurements"]["X2-in"]["left_out"] is True
    for key, (err, sigma) in errors_of(res, PAPER).items():
        assert abs(err) <= 3.5 * sigma, key


def test_strong_shrinkage_is_no_typo(program):
    """ABS shrinks up to about 1.6 %: 2 % still fits, nothing is left out."""
    meas, info = program
    readings = simulate_readings(meas, PAPER, shrinkage=0.02, rng=np.random.default_rng(16))
    res = analyse_artifact(meas, readings, info=info)
    assert not [f for f in res["findings"] if f["severity"] != "info"]
    for key, (err, sigma) in errors_of(res, PAPER).items():
        assert abs(err) <= 3 * sigma, key


def test_gross_typo_and_two_disagreeing_repeats(program):
    meas, info = program
    readings = simulate_readings(meas, PAPER, rng=np.random.default_rng(10))
    readings["Y1-out"][0] = readings["Y1-out"][0] + 10.0  # a digit wrong
    readings["B2-in"] = readings["B2-in"][:2]
    readings["B2-in"][1] += 0.3
    res = analyse_artifact(meas, readings, info=info)
    codes = {(f["code"], f["evidence"].get("id")) for f in res["findings"]}
    assert ("artifact.reading_far_from_nominal", "Y1-out") in codes
    assert ("artifact.repeats_disagree", "B2-in") in codes


def test_what_cannot_be_separated_is_said(program):
    meas, info = program
    readings = simulate_readings(meas, PAPER, rng=np.random.default_rng(11))
    xy_only = {k: v for k, v in readings.items() if not k.startswith(("XZ", "YZ"))}
    res = analyse_artifact(meas, xy_only, info=info)
    d = res["diagnostics"]
    assert (
        d["squareness_um_per_m"]["xz"] is None
        and d["uncertainty"]["squareness_um_per_m"]["xz"] is None
    )
    assert d["scale_mismatch_ppm"]["x-z"] is None
    assert d["squareness_um_per_m"]["xy"] is not None
    sep = [f for f in res["findings"] if f["code"] == "artifact.not_separable"]
    assert {f["evidence"]["quantity"] for f in sep} == {
        "squareness.xz",
        "squareness.yz",
        "scale_mismatch.x-z",
        "scale_mismatch.y-z",
    }
    assert res["parameters"]["squareness_um_per_m"]["xz"] == 0.0  # kept as it was
    # spans along the axes only: squareness XY cannot be separated from them
    spans = {k: v for k, v in readings.items() if k[0] in "XY" and k[1].isdigit()}
    res = analyse_artifact(meas, spans, info=info)
    assert res["diagnostics"]["squareness_um_per_m"]["xy"] is None
    assert res["diagnostics"]["scale_mismatch_ppm"]["x-y"] is not None
    assert any(f["evidence"].get("quantity") == "squareness.xy" for f in res["findings"])
    # one diagonal pair, one reading each, mostly outside: 5 readings for 4 unknowns
    few = {k: readings[k][:1] for k in ("X1-out", "X1-in", "Y1-out", "A1-out", "B1-out")}
    res = analyse_artifact(meas, few, info=info)
    codes = {f["code"] for f in res["findings"]}
    assert "artifact.little_redundancy" in codes and "artifact.unchecked" in codes


def test_swapped_outside_inside_is_not_trusted(program):
    meas, info = program
    readings = simulate_readings(meas, PAPER, rng=np.random.default_rng(12))
    swapped = {}
    for k, v in readings.items():
        other = k.replace("-out", "-IN").replace("-in", "-out").replace("-IN", "-in")
        swapped[other] = v
    res = analyse_artifact(meas, swapped, info=info)
    assert res["trusted"] is False
    assert res["findings"][0]["code"] == "artifact.line_width_implausible"


def test_printed_with_compensation_is_a_residual(program):
    meas, info = program
    current = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -3000.0, "xz": 500.0},
            "scale_ppm": {"x": -300.0, "y": 200.0},
        }
    )
    readings = simulate_readings(
        meas, PAPER, shrinkage=0.002, compensated_with=current, rng=np.random.default_rng(13)
    )
    res = analyse_artifact(meas, readings, current=current, info=info)
    d, p = res["diagnostics"], res["parameters"]
    u = d["uncertainty"]
    # the fit sees the residual, the proposal is the whole error again
    assert d["squareness_um_per_m"]["xy"] == pytest.approx(
        -638.6, abs=3 * u["squareness_um_per_m"]["xy"]
    )
    for key in ("xy", "xz", "yz"):
        assert p["squareness_um_per_m"][key] == pytest.approx(
            PAPER.squareness_um_per_m[key], abs=3 * u["squareness_um_per_m"][key] + 5
        )
    for a, b in PAIRS:
        assert p["scale_ppm"][a] - p["scale_ppm"][b] == pytest.approx(
            PAPER.scale_ppm[a] - PAPER.scale_ppm[b], abs=3 * u["scale_mismatch_ppm"][f"{a}-{b}"] + 5
        )
    assert any(f["code"] == "artifact.residual" for f in res["findings"])


def test_bad_readings_are_refused(program):
    meas, info = program
    with pytest.raises(ArtifactFitError, match="Z9-out"):
        analyse_artifact(meas, {"Z9-out": [1.0]}, info=info)
    with pytest.raises(ArtifactFitError, match="positive"):
        parse_readings({"X1-out": [146.0, -1]})
    with pytest.raises(ArtifactFitError, match="positive"):
        parse_readings({"X1-out": ["146"]})
    with pytest.raises(ArtifactFitError, match="JSON"):
        parse_readings("{not json")
    with pytest.raises(ArtifactFitError, match="object"):
        parse_readings("[1, 2]")
    assert parse_readings('{"X1-out": 146.5}') == {"X1-out": [146.5]}
    with pytest.raises(ArtifactFitError, match="too few"):
        analyse_artifact(meas, {"X1-out": [146.6]}, info=info)


def test_nearly_parallel_spans_are_ill_conditioned():
    """Hand-made contracts. Diagonals 0.5 deg off X: XY squareness is barely measured (its
    sigma says so, poorly determined). Two spans 20 and 20.5 deg off X beside X: Y scale and XY
    squareness move together (ill-conditioned)."""
    from octoprint_kincomp.calibration.artifact.program import Measurement

    def contract(spans):
        meas = []
        for name, deg in spans:
            t = math.radians(deg)
            for kind in ("outside", "inside"):
                meas.append(
                    Measurement(
                        f"{name}-{kind}",
                        kind,
                        (40.0, 80.0, 2.5),
                        (40.0 + 140 * math.cos(t), 80.0 + 140 * math.sin(t), 2.5),
                    )
                )
        return meas

    info = {"planes": "XY", "nozzle_mm": "0.4"}
    meas = contract((("X", 0.0), ("Y", 90.0), ("P", 0.5), ("N", -0.5)))
    res = analyse_artifact(
        meas, simulate_readings(meas, PAPER, rng=np.random.default_rng(14)), info=info
    )
    assert "artifact.poorly_determined" in {f["code"] for f in res["findings"]}
    assert res["diagnostics"]["uncertainty"]["squareness_um_per_m"]["xy"] > 1000
    meas = contract((("X", 0.0), ("P", 20.0), ("Q", 20.5)))
    res = analyse_artifact(
        meas, simulate_readings(meas, PAPER, rng=np.random.default_rng(15)), info=info
    )
    cond = [f for f in res["findings"] if f["code"] == "artifact.ill_conditioned"]
    assert cond and cond[0]["evidence"]["condition"] > 100
