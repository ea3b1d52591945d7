"""Campaigns (issue 12): programs on the machine volume, checks that traces form one complete
campaign, the joint fit of all traces into ONE parameter set, the servo decision from two
feeds. Every trace here is SIMULATED (small circles and 200 Hz where the point is plumbing)."""

import json

import pytest

from octoprint_kincomp.calibration.ballbar.campaign import (
    MANIFEST_NAME,
    CampaignError,
    load_manifest,
    plan_campaign,
)
from octoprint_kincomp.calibration.ballbar.campaign_analysis import analyse_campaign
from octoprint_kincomp.calibration.ballbar.formats import parse_csv_trace, parse_summary
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.closed_loop import compensate_text
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth

VOLUME = (0, 220, 0, 220, 0, 250)


def simulate(spec, truth, params=None):
    text = generate(spec, params_hash=(params or Params()).hash())
    if params is not None:
        text = compensate_text(text, params)
        return parse_csv_trace(simulate_program(text, truth, spec, _hash(spec)).to_text())
    return parse_csv_trace(simulate_program(text, truth).to_text())


def _hash(spec):
    from octoprint_kincomp.calibration.ballbar.program import body_hash

    return body_hash(spec)


@pytest.fixture(scope="module")
def small():
    """A cheap campaign: XY R40 at two feeds, XZ and YZ R30, 200 Hz."""
    steps = plan_campaign(
        VOLUME,
        radius_xy=40,
        radius_vertical=30,
        second_feed=3700,
        campaign_id="test",
        printer="virtual",
    )
    truth = volume_truth(noise_um=0.5, sample_rate_hz=200)
    items = [(s.file.replace(".gcode", ".csv"), simulate(s.spec, truth)) for s in steps]
    return steps, truth, items


def test_program_campaign_writes_programs_and_manifest(tmp_path, capsys):
    out = tmp_path / "camp"
    assert (
        main(
            [
                "program",
                "--campaign",
                "--volume",
                "0,220,0,220,0,250",
                "--max-feed",
                "18000,18000,2400",
                "--second-feed",
                "3700",
                "--second-height",
                "100",
                "--printer",
                "P1",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    m = load_manifest(str(out / MANIFEST_NAME))
    names = [s["name"] for s in m["steps"]]
    assert names == ["xy", "xz", "yz", "xy-z100", "xy-f3700"]
    for s in m["steps"]:
        text = (out / s["file"]).read_text()
        assert f"; ballbar program_hash: {s['program_hash']}" in text
        assert "; ballbar campaign_tests: xy,xz,yz,xy-z100,xy-f3700" in text
        assert "; ballbar printer: P1" in text and "M0 Mount the ballbar now" in text
    xz = m["steps"][1]
    assert xz["radius_mm"] == 50 and xz["centre"][2] == 38  # lowest point 5 mm above Z0
    # a volume too small names the test that does not fit
    assert (
        main(["program", "--campaign", "--volume", "0,150,0,150,0,250", "-o", str(tmp_path / "x")])
        == 1
    )
    assert "campaign test XY" in capsys.readouterr().err
    assert main(["program", "--campaign", "-o", str(tmp_path / "y")]) == 1
    assert "--volume" in capsys.readouterr().err


def test_joint_fit_json_contract(small, tmp_path, capsys):
    steps, truth, items = small
    paths = []
    for name, trace in items:
        p = tmp_path / name
        p.write_text(trace.to_text())
        paths.append(str(p))
    assert main(["analyze", *paths, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    p = Params.from_dict(out["parameters"])  # ONE valid params file for all traces
    d = out["diagnostics"]
    assert [t["plane"] for t in d["traces"]] == ["XY", "XZ", "YZ", "XY"]
    assert [t["file"] for t in d["traces"]] == [n for n, _ in items]
    for t in d["traces"]:
        for key in (
            "squareness_um_per_m",
            "scale_mismatch_ppm",
            "servo_mismatch_ms",
            "backlash_um",
            "circularity_um",
            "uncertainty",
            "fit",
        ):
            assert key in t
    c = d["campaign"]
    assert set(c["squareness_um_per_m"]) == {"xy", "xz", "yz"}
    assert set(c["uncertainty"]["scale_ppm"]) == {"x", "y", "z"}
    assert c["squareness_um_per_m"]["xz"] == pytest.approx(800, abs=8)
    assert c["scale_mismatch_ppm"]["x-z"] == pytest.approx(-601.7, abs=8)
    # the mean scale of the measured axes is left as it was (zero)
    assert sum(p.scale_ppm.values()) == pytest.approx(0.0, abs=0.01)
    assert p.servo_lag_ms["y"] == 0.0 and p.servo_lag_ms["x"] == pytest.approx(0.62, abs=0.02)
    assert p.servo_precomp is True and c["servo_precomp"]["proposed"] is True
    assert isinstance(p.backlash["z"].points, tuple)
    assert "xy-f3700" in c["servo_precomp"]["by_feed"][1]["file"]
    from octoprint_kincomp.cli.calibration_commands import format_diagnostics

    text = format_diagnostics(out)  # what analyze prints without --json
    assert "campaign: 4 traces" in text and "servo pre-compensation: proposed" in text


def names(items):
    return [n for n, _ in items]


def copy(trace):
    return parse_csv_trace(trace.to_text())


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing", r"incomplete: test YZ missing"),
        ("printer", r"ballbar_3_yz.csv comes from another printer than ballbar_1_xy.csv"),
        ("params", r"ballbar_2_xz.csv comes from another parameter set"),
        ("edited", r"ballbar_2_xz.csv: its metadata does not match the test program it names"),
        ("duplicate", r"ballbar_1_xy.csv and again.csv are the same test \(XY at 10 mm"),
        ("failed", r"ballbar_3_yz.csv: the cw run is missing"),
        ("truncated", r"ballbar_2_xz.csv: the ccw run covers"),
        ("summary", r"summary.json: a campaign needs measured traces"),
    ],
)
def test_bad_campaigns_name_the_file(small, case, message):
    _, _, items = small
    items = [(n, copy(t)) for n, t in items]
    if case == "missing":
        items = [it for it in items if "yz" not in it[0]]
    elif case == "printer":
        items[2][1].meta["printer"] = "other"
    elif case == "params":
        items[1][1].meta["params_hash"] = "0123456789ab"
    elif case == "edited":
        items[1][1].meta["radius_mm"] = "31"
    elif case == "duplicate":
        items.append(("again.csv", copy(items[0][1])))
    elif case == "failed":
        items[2][1].rows = [r for r in items[2][1].rows if r[0] == "ccw"]
    elif case == "truncated":  # the logger lost a third of the ccw run
        ccw = [r for r in items[1][1].rows if r[0] == "ccw"]
        n = len(ccw)
        items[1][1].rows = (
            ccw[: n // 3] + ccw[2 * n // 3 :] + [r for r in items[1][1].rows if r[0] == "cw"]
        )
    elif case == "summary":
        items.append(("summary.json", parse_summary({"plane": "XY", "squareness_um_per_m": 3})))
    with pytest.raises(CampaignError, match=message):
        analyse_campaign(items)


def test_params_in_force_must_match(small, tmp_path, capsys):
    _, _, items = small
    current = Params.from_dict({"squareness_um_per_m": {"xy": 100.0}})
    with pytest.raises(
        CampaignError,
        match="measured with parameters .* the current parameters are " + current.hash(),
    ):
        analyse_campaign(items, current=current)
    # on the command line: one line naming the file, nothing written
    paths = []
    for name, trace in items:
        (tmp_path / name).write_text(trace.to_text())
        paths.append(str(tmp_path / name))
    cur = tmp_path / "cur.json"
    cur.write_text(current.to_json())
    out = tmp_path / "new.json"
    assert main(["analyze", *paths, "--current", str(cur), "--params-out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "ballbar_1_xy.csv was measured with parameters" in err and "Traceback" not in err
    assert not out.exists()


def test_manifest_names_a_foreign_trace(small, tmp_path):
    steps, truth, items = small
    other = TestSpec(
        plane="XY",
        centre=(100, 100, 10),
        radius_mm=40,
        campaign="test",
        campaign_step="xy",
        campaign_tests="xy,xz,yz,xy-f3700",
        printer="virtual",
        mount_pause=True,
    )
    manifest = {
        "kincomp_campaign": 1,
        "steps": [{"name": s.name, "program_hash": _hash(s.spec)} for s in steps],
    }
    foreign = [("foreign.csv", simulate(other, truth))] + items[1:]
    with pytest.raises(
        CampaignError, match="foreign.csv: it was not measured with one of this campaign"
    ):
        analyse_campaign(foreign, manifest=manifest)


def test_servo_precomp_left_off_when_the_lag_depends_on_speed(small):
    steps, truth, items = small
    slow_lag = volume_truth(noise_um=0.5, sample_rate_hz=200)
    slow_lag.servo_lag_ms = {"x": 0.31, "y": 0.0, "z": 0.3}  # half the lag at F3700
    items = items[:3] + [(items[3][0], simulate(steps[3].spec, slow_lag))]
    out = analyse_campaign(items)
    sp = out["diagnostics"]["campaign"]["servo_precomp"]
    assert sp["proposed"] is False and out["parameters"]["servo_precomp"] is False
    assert "not proportional to speed" in sp["reason"]
    assert any("not proportional to speed" in n for n in out["notes"])


def test_unmeasured_parameters_stay_and_single_feed_keeps_precomp():
    """XY at two heights only: xz, yz, the Z scale and Z backlash are not measured and stay
    as they were; the X/Y mean scale stays; servo pre-compensation (one feed) stays on."""
    current = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -3000.0, "xz": 123.0, "yz": -45.0},
            "scale_ppm": {"x": -300.0, "y": 200.0, "z": 77.0},
            "backlash": {"x": 20.0, "y": 5.0, "z": 9.0},
            "servo_lag_ms": {"x": 0.5, "y": 0.0, "z": 0.2},
            "servo_precomp": True,
        }
    )
    truth = volume_truth(noise_um=0.5, sample_rate_hz=200)
    specs = [TestSpec(plane="XY", centre=(110, 110, z), radius_mm=40) for z in (10, 90)]
    items = [(f"xy{i}.csv", simulate(s, truth, current)) for i, s in enumerate(specs)]
    out = analyse_campaign(items, current=current)
    p = Params.from_dict(out["parameters"])
    assert p.squareness_um_per_m["xz"] == pytest.approx(123.0, abs=0.5)
    assert p.squareness_um_per_m["yz"] == pytest.approx(-45.0, abs=0.5)
    assert p.scale_ppm["z"] == pytest.approx(77.0, abs=0.1)
    assert p.backlash["z"].points == ((0.0, 9.0),)
    assert p.servo_lag_ms["z"] == 0.2 and p.servo_precomp is True
    assert (p.scale_ppm["x"] + p.scale_ppm["y"]) / 2 == pytest.approx(-50.0, abs=0.5)
    assert p.squareness_um_per_m["xy"] == pytest.approx(-3638.6, abs=10)
    assert p.scale_ppm["x"] - p.scale_ppm["y"] == pytest.approx(-738.7, abs=5)
    c = out["diagnostics"]["campaign"]
    assert len(c["squareness_xy_by_height"]) == 2
    assert "one feed only" in c["servo_precomp"]["reason"]


@pytest.mark.slow
@pytest.mark.parametrize("accel", [500.0, 3000.0])
@pytest.mark.parametrize("domain", ["native", "angle"])
def test_joint_identification_whole_machine(accel, domain):
    """The paper-like machine, full-size campaign: every plane's values in the joint fit
    within the issue's tolerances, also YZ (whose single-trace fit would be biased by the
    out-of-plane motion of the XY squareness)."""
    from octoprint_kincomp.firmware.planner import MotionSettings
    from octoprint_kincomp.simulator.printer import simulate_angle_trace

    truth = volume_truth(noise_um=0.5, motion=MotionSettings(accel_mm_s2=accel))
    steps = plan_campaign(VOLUME, campaign_id="ident")
    sim = simulate_program if domain == "native" else simulate_angle_trace
    items = [(s.name, parse_csv_trace(sim(generate(s.spec), truth).to_text())) for s in steps]
    out = analyse_campaign(items)
    c = out["diagnostics"]["campaign"]
    e = truth.errors
    for plane, v in c["squareness_um_per_m"].items():
        want = e.squareness_um_per_m[plane]
        assert abs(v - want) <= max(0.02 * abs(want), 5.0), (plane, v)
    for pair, v in c["scale_mismatch_ppm"].items():
        a, b = pair.split("-")
        assert abs(v - (e.scale_ppm[a] - e.scale_ppm[b])) <= 5.0, (pair, v)
    for pair, v in c["servo_mismatch_ms"].items():
        a, b = pair.split("-")
        assert abs(v - (truth.servo_lag_ms[a] - truth.servo_lag_ms[b])) <= 0.05
    for axis, pts in c["backlash_um"].items():
        pts = pts if isinstance(pts, list) else [{"at_mm": 100.0, "um": pts}]
        for pt in pts:
            assert abs(pt["um"] - e.backlash[axis].um_at(pt["at_mm"])) <= 1.5, (axis, pt)
    for t in out["diagnostics"]["traces"]:
        j = t["joint"]
        plane_sq = e.squareness_um_per_m[t["plane"].lower()]
        assert abs(j["squareness_um_per_m"] - plane_sq) <= max(0.02 * abs(plane_sq), 5.0)


def test_calibrated_bar_gives_absolute_scales(small):
    """With a bar of known length the mean radius of each test measures the mean scale of its
    two axes, so the campaign fits absolute per-axis scales (not just differences)."""
    _, truth, items = small
    out = analyse_campaign(items, calibrated=True)
    c = out["diagnostics"]["campaign"]
    assert c["scale_rule"].startswith("absolute")
    for axis, v in c["scale_ppm"].items():
        want = truth.errors.scale_ppm[axis]
        assert abs(v - want) < max(3 * c["uncertainty"]["scale_ppm"][axis], 1.0), (axis, v)
    assert out["parameters"]["scale_ppm"]["z"] == pytest.approx(150.0, abs=8)


def test_servo_precomp_stays_on_at_the_re_test(small):
    """The re-test measures with the proposed parameters in force: the servo mismatch left is
    about zero at both feeds, which means the pre-compensation works, not that it is not
    needed (the re-test once proposed switching it off, flipping at every round)."""
    steps, truth, items = small
    first = Params.from_dict(analyse_campaign(items)["parameters"])
    assert first.servo_precomp is True
    again = [(name, simulate(step.spec, truth, first)) for (name, _), step in zip(items, steps)]
    out = analyse_campaign(again, current=first)
    sp = out["diagnostics"]["campaign"]["servo_precomp"]
    assert sp["proposed"] is True and out["parameters"]["servo_precomp"] is True, sp["reason"]
    assert "pre-compensation works" in sp["reason"]
    lag = out["parameters"]["servo_lag_ms"]["x"]
    assert lag == pytest.approx(first.servo_lag_ms["x"], abs=0.05)


def test_glitches_and_drift_in_a_campaign_trace_are_reported_like_a_single_trace():
    """Outliers the checks leave out of a campaign trace's fit are said (data.outliers, with
    the file name), and its ISO circularity is the raw one, as for a single trace, beside the
    circularity without them (circularity_robust_um); a bar drift is said per trace too."""
    steps = plan_campaign(
        VOLUME, radius_xy=40, radius_vertical=30, campaign_id="glitch", printer="virtual"
    )
    clean = volume_truth(noise_um=0.5, sample_rate_hz=200)
    knocked = volume_truth(
        noise_um=0.5, sample_rate_hz=200, glitches=(8, 200.0), bar_drift_um_per_min=10.0
    )
    items = [
        (
            s.file.replace(".gcode", ".csv"),
            simulate(s.spec, knocked if s.spec.plane == "XY" else clean),
        )
        for s in steps
    ]
    out = analyse_campaign(items, Params())
    xy = [t for t in out["diagnostics"]["traces"] if t["plane"] == "XY"][0]
    f = [x for x in out["findings"] if x["code"] == "data.outliers"]
    assert len(f) == 1 and f[0]["severity"] == "warning", out["findings"]
    assert f[0]["message"].startswith(xy["file"] + ": ")
    assert xy["circularity_um"]["bidirectional"] > 150.0
    assert (
        xy["circularity_robust_um"]["bidirectional"] < 0.5 * xy["circularity_um"]["bidirectional"]
    )
    drift = [x for x in out["findings"] if x["code"] == "model.drift"]
    assert [x["message"].split(":")[0] for x in drift] == [xy["file"]], out["findings"]
    assert drift[0]["evidence"]["bar_drift_um_per_min"] == pytest.approx(10.0, abs=0.5)


def test_a_campaign_test_is_named_in_words():
    """Issue 35: the web UI showed the plan's keys ("xy-f3700"); the server words them, the
    page shows what it sends (campaign_store.view's ``test``)."""
    from octoprint_kincomp.calibration.ballbar.campaign import test_words
    from octoprint_kincomp.core.messages import as_dict

    assert test_words("xy") == "XY" and test_words("yz") == "YZ"
    assert str(test_words("xy-f3700")) == "XY at 3700 mm/min"
    assert str(test_words("xy-z110")) == "XY at Z 110 mm"
    assert as_dict(test_words("xy-f3700"))["template"] == "%(plane)s at %(feed)s mm/min"
