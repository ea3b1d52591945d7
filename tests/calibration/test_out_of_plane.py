"""Issue 23 item 5, the re-test bias: a vertical plane tested alone cannot see the squareness
that moves its third axis out of the plane (YZ: X = xy Y + xz Z; XZ: Y = yz Z), which reads
as a scale mismatch of (oA^2 - oB^2)/2 and a squareness of oA oB. Known (an XY result, a
campaign, ``--out-of-plane``), it is fitted as a fixed motion, as the joint fit does. Every
trace here is SIMULATED (noise 0.05 um: the scale mismatch's 1 sigma is about 0.3 ppm)."""

import json

import pytest

from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.formats import parse_csv_trace
from octoprint_kincomp.calibration.ballbar.model import (
    OUT_OF_PLANE,
    out_of_plane_bias,
    out_of_plane_terms,
)
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth

YZ = TestSpec(plane="YZ", centre=(110, 110, 38), radius_mm=50)
XZ = TestSpec(plane="XZ", centre=(110, 110, 60), radius_mm=50)


def printer(xy=0.0, xz=0.0, yz=0.0, seed=0):
    """The whole-volume simulated printer with the squareness (um/m) given."""
    t = volume_truth(noise_um=0.05, seed=seed)
    t.errors = t.errors.replace(squareness_um_per_m={"xy": xy, "xz": xz, "yz": yz})
    return t


def trace_of(spec, truth, current=None):
    program = generate(spec, params_hash=current.hash() if current else None)
    if current is not None:
        from octoprint_kincomp.simulator.closed_loop import compensate_text

        program = compensate_text(program, current)
    return parse_csv_trace(simulate_program(program, truth, spec).to_text())


def truth_of(spec, t):
    a, b = spec.plane.lower()
    e = t.errors
    return e.scale_ppm[a] - e.scale_ppm[b], e.squareness_um_per_m[spec.plane.lower()]


def predicted(spec, known):
    terms = out_of_plane_terms(spec.plane, {k: v * 1e-6 for k, v in known.items()})
    return out_of_plane_bias(terms["oA"], terms["oB"])


def same_numbers(a, b, rel=1e-9) -> bool:
    """``a`` equals ``b`` (nested dicts and lists), numbers within ``rel`` of each other."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_numbers(a[k], b[k], rel) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_numbers(x, y, rel) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return a == pytest.approx(b, rel=rel, abs=1e-12)
    return a == b


def finding(result, code):
    hits = [f for f in result["findings"] if f["code"] == code]
    return hits[0] if hits else None


def no_warning(result):
    assert [f for f in result["findings"] if f["severity"] != "info"] == []
    assert result["trusted"] is True


CASES = [
    ("YZ, xy only", YZ, {"xy": -3638.6, "xz": 0.0}),
    ("YZ, xy and xz", YZ, {"xy": -3638.6, "xz": 800.0}),
    ("XZ, yz", XZ, {"yz": -4000.0}),
]


@pytest.mark.parametrize("name,spec,known", CASES, ids=[c[0] for c in CASES])
def test_known_out_of_plane_squareness_removes_the_bias(name, spec, known):
    t = printer(**known)
    ds_true, sq_true = truth_of(spec, t)
    ppm, um_per_m = predicted(spec, known)
    trace = trace_of(spec, t)
    # (a) not known: today's info finding, and the bias of about the predicted size
    before = analyse(trace)
    d0 = before["diagnostics"]
    oop = finding(before, "model.out_of_plane")
    assert oop is not None and oop["severity"] == "info"
    assert oop["evidence"]["uncorrected"] == [k for k in OUT_OF_PLANE[spec.plane] if k]
    assert finding(before, "model.out_of_plane_used") is None
    sig = d0["uncertainty"]["scale_mismatch_ppm"]
    assert abs(ppm) > 6.0  # each case is beyond the 5 ppm tolerance
    assert d0["scale_mismatch_ppm"] - ds_true == pytest.approx(ppm, abs=3 * sig + 0.3)
    assert d0["squareness_um_per_m"] - sq_true == pytest.approx(um_per_m, abs=0.5)
    # (b) known: fitted as a fixed motion, the mismatch within 1.5 ppm of the truth
    after = analyse(trace, known_squareness_um_per_m=known, known_sources={"xy": "an XY run"})
    d1 = after["diagnostics"]
    assert abs(d1["scale_mismatch_ppm"] - ds_true) <= 1.5
    assert abs(d1["squareness_um_per_m"] - sq_true) <= max(0.02 * abs(sq_true), 5.0)
    assert abs(d1["squareness_um_per_m"] - sq_true) <= 1.0  # the oA oB part is gone too
    # the same samples: the readings move by the predicted bias, not by noise
    assert d0["scale_mismatch_ppm"] - d1["scale_mismatch_ppm"] == pytest.approx(ppm, abs=0.3)
    assert finding(after, "model.out_of_plane") is None
    used = finding(after, "model.out_of_plane_used")
    assert used is not None and used["severity"] == "info"
    ev = used["evidence"]
    assert ev["known_um_per_m"] == known
    assert ev["out_of_plane_um_per_m"] == known  # nothing in force
    assert ev["bias_removed_scale_mismatch_ppm"] == pytest.approx(ppm, abs=1e-3)
    assert ev["bias_removed_squareness_um_per_m"] == pytest.approx(um_per_m, abs=1e-3)
    assert set(ev["sources"]) == set(known)
    assert d1["fit"]["out_of_plane_um_per_m"] == pytest.approx(
        {
            o: v * 1e6
            for o, v in out_of_plane_terms(
                spec.plane, {k: v * 1e-6 for k, v in known.items()}
            ).items()
        }
    )
    no_warning(after)


def test_yz_with_only_xy_known_still_says_xz_is_not():
    """Half known: xy is fitted, xz (not known, not in force) stays today's info finding."""
    t = printer(xy=-3638.6, xz=800.0)
    out = analyse(trace_of(YZ, t), known_squareness_um_per_m={"xy": -3638.6})
    assert finding(out, "model.out_of_plane")["evidence"]["uncorrected"] == ["xz"]
    assert finding(out, "model.out_of_plane_used")["evidence"]["known_um_per_m"] == {"xy": -3638.6}
    ds_true, _ = truth_of(YZ, t)
    # what is left is xz's -0.32 ppm
    assert abs(out["diagnostics"]["scale_mismatch_ppm"] - ds_true) <= 1.5


def test_a_clean_printer_gives_the_same_result_with_the_option():
    """(e) xy = xz = 0 known: the fit is the same (no fixed terms), no false alarm."""
    t = printer(yz=-500.0)
    trace = trace_of(YZ, t)
    plain = analyse(trace)
    known = analyse(trace, known_squareness_um_per_m={"xy": 0.0, "xz": 0.0})
    # (the same fit; to the last digits only as far as the linear algebra repeats itself)
    assert same_numbers(known["diagnostics"], plain["diagnostics"])
    assert same_numbers(known["parameters"], plain["parameters"])
    no_warning(known)
    used = finding(known, "model.out_of_plane_used")["evidence"]
    assert used["bias_removed_scale_mismatch_ppm"] == 0.0
    assert used["bias_removed_squareness_um_per_m"] == 0.0


def test_what_the_parameters_in_force_correct_is_taken_off():
    """The XY and XZ results in force (the program moves X back): the known values equal
    them, nothing is left out of the plane; the result is the one without the option."""
    t = printer(xy=-3638.6, xz=800.0)
    current = Params.from_dict({"squareness_um_per_m": {"xy": -3638.6, "xz": 800.0}})
    trace = trace_of(YZ, t, current)
    plain = analyse(trace, current=current)
    known = analyse(trace, current=current, known_squareness_um_per_m={"xy": -3638.6, "xz": 800.0})
    assert known["diagnostics"] == plain["diagnostics"]
    ev = finding(known, "model.out_of_plane_used")["evidence"]
    assert ev["in_force_um_per_m"] == {"xy": -3638.6, "xz": 800.0}
    assert ev["out_of_plane_um_per_m"] == {"xy": 0.0, "xz": 0.0}
    ds_true, _ = truth_of(YZ, t)
    assert abs(known["diagnostics"]["scale_mismatch_ppm"] - ds_true) <= 1.5


def test_an_xy_test_has_nothing_out_of_the_plane():
    t = printer(xy=-3638.6)
    out = analyse(trace_of(TestSpec(), t), known_squareness_um_per_m={"xz": 800.0})
    assert finding(out, "model.out_of_plane_used") is None
    assert "out_of_plane_um_per_m" not in out["diagnostics"]["fit"]


@pytest.mark.parametrize("bad", [{"xx": 1.0}, {"xy": float("nan")}, {"xy": "big"}, {"xy": True}])
def test_bad_known_values_are_refused_by_name(bad):
    t = printer()
    with pytest.raises(ValueError, match="known squareness"):
        analyse(trace_of(YZ, t), known_squareness_um_per_m=bad)


def test_cli_out_of_plane_option(tmp_path, capsys):
    t = printer(xy=-3638.6, xz=800.0)
    path = tmp_path / "yz.csv"
    path.write_text(simulate_program(generate(YZ), t, YZ).to_text())
    assert main(["analyze", str(path), "--json", "--out-of-plane", "xy=-3638.6,xz=800"]) == 0
    out = json.loads(capsys.readouterr().out)
    used = finding(out, "model.out_of_plane_used")
    assert used["evidence"]["sources"] == {"xy": "--out-of-plane", "xz": "--out-of-plane"}
    ds_true, _ = truth_of(YZ, t)
    assert abs(out["diagnostics"]["scale_mismatch_ppm"] - ds_true) <= 1.5
    # repeatable, the same result
    assert main(["analyze", str(path), "--json", "--out-of-plane", "xy=-3638.6",
                 "--out-of-plane", "xz=800"]) == 0  # fmt: skip
    again = json.loads(capsys.readouterr().out)
    assert again["diagnostics"] == out["diagnostics"]
    # the text output names it
    assert main(["analyze", str(path), "--out-of-plane", "xy=-3638.6,xz=800"]) == 0
    assert "was fitted as a known motion" in capsys.readouterr().out
    for bad in ("xx=1", "xy", "xy=abc", "xy=inf"):
        assert main(["analyze", str(path), "--out-of-plane", bad]) == 1
        assert "--out-of-plane" in capsys.readouterr().err
    # a campaign measures it itself
    assert main(["analyze", str(path), str(path), "--out-of-plane", "xy=1"]) == 1
    assert "for one trace" in capsys.readouterr().err
