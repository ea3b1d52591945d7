"""Ballbar analysis: recovery of known errors from simulated traces (issue 7).

Every trace here is SIMULATED by KinComp's own printer + ballbar simulator."""

import json
import math

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.analysis import (
    Geometry,
    analyse,
    fit,
    load_runs,
    propose_params,
    reversal_mask,
)
from octoprint_kincomp.calibration.ballbar.formats import (
    AngleTrace,
    TraceError,
    parse_csv_trace,
    parse_summary,
)
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.printer import Truth, paper_truth, simulate_program

XZ_TRUTH = dict(
    errors=Params.from_dict(
        {
            "squareness_um_per_m": {"xz": 300.0},
            "scale_ppm": {"x": 120.0, "z": -80.0},
            "backlash": {
                "x": [{"at_mm": 10, "um": 30}, {"at_mm": 210, "um": 18}],
                "z": [{"at_mm": 0, "um": 20}, {"at_mm": 200, "um": 26}],
            },
        }
    ),
    servo_lag_ms={"x": 0.0, "y": 0.0, "z": 1.0},
)


def check(d, square, mismatch, servo, bl):
    assert abs(d["squareness_um_per_m"] - square) <= max(0.02 * abs(square), 5.0)
    assert abs(d["scale_mismatch_ppm"] - mismatch) <= 3.0
    assert abs(d["servo_mismatch_ms"] - servo) <= 0.05
    for k, v in bl.items():
        assert abs(d["backlash_um"][k] - v) <= 1.5, (k, d["backlash_um"])


@pytest.fixture(scope="module")
def paper_trace():
    return simulate_program(generate(TestSpec()), paper_truth(noise_um=0.5))


def test_xy_360_recovers_the_paper_errors(paper_trace):
    d = analyse(parse_csv_trace(paper_trace.to_text()))["diagnostics"]
    check(
        d,
        -3638.6,
        -451.7 - 287.0,
        0.62,
        {"a_plus": 4.4, "a_minus": 37.4, "b_plus": 11.3, "b_minus": 5.4},
    )
    assert d["simulated"] is True
    assert d["fit"]["rms_um"] < 0.7


@pytest.mark.parametrize("spikes", [0.0, 15.0])
def test_xz_220_recovers_errors_and_masks_spikes(spikes):
    truth = Truth(noise_um=0.5, spike_um=spikes, spike_decay_mm=3.0, **XZ_TRUTH)
    trace = simulate_program(generate(TestSpec(plane="XZ", centre=(110, 110, 100))), truth)
    d = analyse(trace)["diagnostics"]
    assert d["plane"] == "XZ" and d["axes"] == {"a": "X", "b": "Z"}
    # A = X, B = Z: servo mismatch TA - TB = -1 ms
    check(d, 300.0, 200.0, -1.0, {"a_plus": 18, "a_minus": 30, "b_plus": 26, "b_minus": 20})


def test_spikes_bias_the_fit_without_mask():
    truth = Truth(noise_um=0.5, spike_um=15.0, spike_decay_mm=3.0, **XZ_TRUTH)
    trace = simulate_program(generate(TestSpec(plane="XZ", centre=(110, 110, 100))), truth)
    g, runs = load_runs(trace)
    unmasked = fit(g, runs, mask_deg=0.0).values
    masked = fit(g, runs, mask_deg=15.0).values

    def err(v):
        return abs(v["bBm"] * 1e3 - 20.0)

    assert err(unmasked) > 1.5 and err(masked) < 1.0


def test_exact_geometry_removes_first_order_bias():
    truth = paper_truth(noise_um=0.0)
    trace = simulate_program(generate(TestSpec()), truth)
    g, runs = load_runs(trace)
    first_order = fit(g, runs, max_iter=1).values  # one linear step = the first-order fit
    exact = fit(g, runs).values
    truth_ds = -738.7e-6
    assert abs(first_order["ds"] - truth_ds) * 1e6 > 4.0  # several ppm of bias
    assert abs(exact["ds"] - truth_ds) * 1e6 < 1.0


def test_backlash_per_side_is_the_local_step_when_it_varies():
    # 40 um at the -X end, 10 um at the +X end; constant Y
    truth = Truth(
        errors=Params.from_dict(
            {"backlash": {"x": [{"at_mm": 10, "um": 40}, {"at_mm": 210, "um": 10}], "y": 12.0}}
        ),
        noise_um=0.5,
    )
    d = analyse(simulate_program(generate(TestSpec()), truth))["diagnostics"]
    assert d["backlash_um"]["a_minus"] == pytest.approx(40, abs=1.0)
    assert d["backlash_um"]["a_plus"] == pytest.approx(10, abs=1.0)
    assert d["backlash_um"]["b_plus"] == pytest.approx(12, abs=1.0)
    assert d["backlash_um"]["b_minus"] == pytest.approx(12, abs=1.0)


def test_setup_offset_and_bar_error_do_not_leak():
    truth = paper_truth(noise_um=0.5, setup_offset_um=(40.0, -25.0, 0.0), bar_length_error_um=30.0)
    d = analyse(simulate_program(generate(TestSpec()), truth))["diagnostics"]
    check(d, -3638.6, -738.7, 0.62, {"a_plus": 4.4, "a_minus": 37.4})
    assert d["centre_offset_um"]["a"] == pytest.approx(40, abs=1)
    assert d["centre_offset_um"]["b"] == pytest.approx(-25, abs=1)


def test_angle_domain_trace():
    """An angle-domain trace built from the first-order deviations of 150 um/m squareness
    and 100 ppm scale mismatch is fitted back to them."""
    model_rows = []
    rng = np.random.default_rng(4)
    for direction, _w in (("ccw", 1), ("cw", -1)):
        for deg in np.arange(0, 360, 0.5):
            t = math.radians(deg)
            # first-order deviation of squareness and scale mismatch
            dev = 100 * 150e-6 / 2 * math.sin(2 * t) + 100 * 100e-6 / 2 * math.cos(2 * t)
            model_rows.append((direction, float(deg), dev * 1e3 + rng.normal(0, 0.3)))
    tr = AngleTrace(
        meta={"plane": "XY", "radius_mm": "100", "feed_mm_min": "1850", "centre": "110,110,10"},
        rows=model_rows,
    )
    d = analyse(parse_csv_trace(tr.to_text()))["diagnostics"]
    assert d["squareness_um_per_m"] == pytest.approx(150, abs=3)
    assert d["scale_mismatch_ppm"] == pytest.approx(100, abs=3)


def test_iso_metrics(paper_trace):
    d = analyse(paper_trace)["diagnostics"]
    c, z = d["circularity_um"], d["circularity_mzc_um"]
    for k in ("cw", "ccw", "bidirectional"):
        assert 0 < z[k] <= c[k] + 1e-6  # minimum zone never exceeds least squares
    assert c["bidirectional"] >= max(c["cw"], c["ccw"]) - 1e-6
    # squareness dominates: an ellipse of +-(alpha R / 2) = +-182 um
    assert 330 < c["ccw"] < 420
    assert d["hysteresis_um"] > 20  # servo mismatch and backlash separate the runs
    assert d["radial_deviation_um"] is None  # bar not calibrated
    assert "least-squares" in d["iso_centre"]


def test_mask_angles():
    theta = np.radians(np.array([1.0, 10.0, 16.0, 91.0, 359.5, 200.0]))
    keep = reversal_mask(theta, np.ones(6), 15.0)
    assert keep.tolist() == [False, False, True, False, False, True]
    keep = reversal_mask(theta, -np.ones(6), 15.0)  # cw: masked before the quadrant angle
    assert keep.tolist() == [True, True, True, True, False, True]


def test_residual_update_is_current_plus_residual():
    current = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -3000.0},
            "scale_ppm": {"x": -300.0, "y": 200.0},
            "backlash": {"x": 20.0, "fraction": 0.5},
        }
    )
    diag = {
        "squareness_um_per_m": -600.0,
        "scale_mismatch_ppm": -100.0,
        "backlash_um": {"a_plus": 2.0, "a_minus": 8.0, "b_plus": 1.0, "b_minus": 1.0},
        "servo_mismatch_ms": 0.3,
    }
    g = Geometry("XY", 100.0, (110, 110, 10), 1850.0)
    p = propose_params(diag, g, current, [])
    assert p.squareness_um_per_m["xy"] == pytest.approx(-3600.0, abs=0.5)
    assert p.scale_ppm["x"] - p.scale_ppm["y"] == pytest.approx(-600.0, abs=0.2)
    assert (p.scale_ppm["x"] + p.scale_ppm["y"]) / 2 == pytest.approx(-50.0, abs=0.1)
    # applied was 0.5 * 20 um: the true backlash is residual + 10 um at each end
    assert p.backlash["x"].points == ((10.0, pytest.approx(18.0)), (210.0, pytest.approx(12.0)))
    assert p.backlash["y"].points == ((10.0, pytest.approx(1.0)), (210.0, pytest.approx(1.0)))
    assert p.servo_lag_ms["x"] == pytest.approx(0.3) and p.servo_precomp is False
    # exact composition: forward(true) == residual o current on the plane
    assert p.hash() != current.hash()


def test_summary_maps_to_parameters():
    s = parse_summary(
        {
            "plane": "XY",
            "radius_mm": 150,
            "centre": "150,150,5",
            "squareness_um_per_m": -9.7,
            "scale_mismatch_ppm": 20,
            "backlash_um": {"a_plus": 3, "a_minus": 5},
        }
    )
    out = analyse(s)
    p = Params.from_dict(out["parameters"])
    assert p.squareness_um_per_m["xy"] == pytest.approx(-9.7)
    assert p.backlash["x"].points == ((0.0, 5.0), (300.0, 3.0))
    assert "M852 I-0.000010" in out["firmware"]["marlin"][0]


def test_cli_analyze_json(tmp_path, paper_trace, capsys):
    path = tmp_path / "trace.csv"
    path.write_text(paper_trace.to_text())
    assert main(["analyze", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    d = out["diagnostics"]
    for key in (
        "squareness_um_per_m",
        "scale_mismatch_ppm",
        "servo_mismatch_ms",
        "backlash_um",
        "centre_offset_um",
        "circularity_um",
    ):
        assert key in d
    assert set(d["backlash_um"]) == {"a_plus", "a_minus", "b_plus", "b_minus"}
    assert set(d["centre_offset_um"]) == {"a", "b"}
    assert set(d["circularity_um"]) == {"cw", "ccw", "bidirectional"}
    # parameters is a valid params file for compensate
    p = Params.from_dict(out["parameters"])
    assert p.squareness_um_per_m["xy"] == pytest.approx(-3638.6, rel=0.02)
    pfile = tmp_path / "p.json"
    pfile.write_text(json.dumps(out["parameters"]))
    prog = tmp_path / "prog.gcode"
    prog.write_text(generate(TestSpec()))
    assert main(["compensate", str(prog), "--params", str(pfile)]) == 0


def test_cli_analyze_errors(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("# plane: XY\n# radius_mm: 100\ndirection,angle_deg,deviation_um\nccw,x,1\n")
    assert main(["analyze", str(bad)]) == 1
    assert "line 4: not a number" in capsys.readouterr().err


def test_cli_analyze_refuses_implausible_proposals(tmp_path, capsys):
    """A summary (or a residual on top of the current model) that would propose parameters
    beyond the params limits: a clear one-line error, no traceback."""
    summary = tmp_path / "s.json"
    summary.write_text(json.dumps({"plane": "XY", "squareness_um_per_m": 60000}))
    assert main(["analyze", str(summary)]) == 1
    err = capsys.readouterr().err
    assert "out of range" in err and "squareness_um_per_m.xy" in err and "Traceback" not in err
    current = tmp_path / "c.json"
    current.write_text(json.dumps({"squareness_um_per_m": {"xy": -30000}}))
    summary.write_text(json.dumps({"plane": "XY", "squareness_um_per_m": -30000}))
    assert main(["analyze", str(summary), "--current", str(current), "--json"]) == 1
    assert "out of range" in capsys.readouterr().err


def test_cli_simulate(tmp_path):
    prog = tmp_path / "p.gcode"
    assert main(["program", "--centre", "110,110,10", "-o", str(prog)]) == 0
    truth = tmp_path / "truth.json"
    truth.write_text(
        json.dumps({"errors": {"squareness_um_per_m": {"xy": 200}}, "servo_lag_ms": {"x": 0.5}})
    )
    out = tmp_path / "trace.csv"
    assert (
        main(["simulate", str(prog), "--truth", str(truth), "--noise-um", "0.5", "-o", str(out)])
        == 0
    )
    text = out.read_text()
    assert "# simulated: true" in text and "SIMULATED" in text
    d = analyse(parse_csv_trace(text))["diagnostics"]
    assert d["squareness_um_per_m"] == pytest.approx(200, abs=5)
    assert d["servo_mismatch_ms"] == pytest.approx(0.5, abs=0.05)


def test_artifact_route(capsys):
    from octoprint_kincomp.calibration.artifact.diagonals import (
        scale_from_lengths,
        squareness_from_diagonals,
    )
    from octoprint_kincomp.firmware.export import klipper_skew_lengths

    for f in (-3.6386e-3, 3e-4, 0.0):
        ac, bd, ad = klipper_skew_lengths(f)
        assert squareness_from_diagonals(ac, bd, ad) == pytest.approx(f * 1e6, abs=1e-6)
    # AC long => positive (acute angle at A)
    assert squareness_from_diagonals(141.6, 141.2, 100.0) > 0
    s = scale_from_lengths([(100, 100.05), (80, 80.04), (120, 120.06)])
    assert s["scale_ppm"] == pytest.approx(500.0) and s["n"] == 3
    assert main(["artifact", "--diagonals", "141.6,141.2,100", "--length", "x:100:100.05"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["parameters"]["scale_ppm"]["x"] == pytest.approx(500.0)
    assert out["parameters"]["meta"]["source"] == "printed artifact"
    assert out["trusted"] is True
    assert [f["code"] for f in out["findings"]][0] == "artifact.hand_measured"


def test_optional_cyclic_error():
    truth = Truth(
        errors=Params.from_dict({"squareness_um_per_m": {"xy": 100}}),
        cyclic={"x": (3.0, 40.0, 30.0)},
        noise_um=0.5,
    )
    trace = simulate_program(generate(TestSpec()), truth)
    with_cyclic = analyse(trace, cyclic_pitch=40.0)["diagnostics"]
    assert with_cyclic["cyclic_error_um"]["a"] == pytest.approx(3.0, abs=0.3)
    assert with_cyclic["cyclic_error_um"]["b"] < 0.3
    without = analyse(trace, cyclic_pitch=0.0)["diagnostics"]  # 0: never fitted
    assert "cyclic_error_um" not in without
    assert without["fit"]["rms_um"] > 2 * with_cyclic["fit"]["rms_um"]
    # by default the residual shows it: fitted, pitch and amplitude reported (issue 23)
    auto = analyse(trace)
    d = auto["diagnostics"]
    assert d["cyclic_error_um"]["pitch_mm"] == pytest.approx(40.0, rel=0.01)
    assert d["cyclic_error_um"]["a"] == pytest.approx(3.0, abs=0.3)
    assert d["fit"]["rms_um"] < 1.1 * with_cyclic["fit"]["rms_um"]
    assert [f["code"] for f in auto["findings"]].count("model.cyclic_fitted") == 1


def test_a_trace_with_one_direction_is_refused():
    """Review finding: with the CW run missing (a capture stopped early, a truncated file)
    the servo mismatch went into the squareness (hundreds of um/m, with a 1 um/m sigma)."""
    spec = TestSpec(radius_mm=50.0)
    truth = Truth(
        errors=Params.from_dict({"squareness_um_per_m": {"xy": 150.0}}),
        servo_lag_ms={"x": 2.0, "y": 3.0},
        noise_um=0.3,
    )
    text = simulate_program(generate(spec), truth).to_text()
    one = "\n".join(line for line in text.splitlines() if not line.startswith("cw,")) + "\n"
    with pytest.raises(TraceError, match="no CW run"):
        analyse(parse_csv_trace(one))
    assert analyse(parse_csv_trace(text))["diagnostics"]["squareness_um_per_m"] == pytest.approx(
        150.0, abs=5.0
    )
