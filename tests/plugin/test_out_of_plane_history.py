"""Issue 23 item 5 in the plugin: a vertical test analysed alone takes the squareness that
moves its third axis out of the plane from the run history of the printer profile in force
(the newest trusted result that measured that plane), for uploads and live captures; another
profile's runs, untrusted or failed runs, and simulated runs for measured traces are not used.
Every trace here is SIMULATED."""

import json
from types import SimpleNamespace

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.sensor import CaptureResult
from octoprint_kincomp.service.calibration.known_squareness import for_trace, known_squareness
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth
from tests.support.blueprint import PREFIX, blueprint_client

VOLUME = {"width": 220, "depth": 220, "height": 200, "origin": "lowerleft"}
A = {"id": "printer_a", "name": "Printer A", "volume": VOLUME}
B = {"id": "printer_b", "name": "Printer B", "volume": VOLUME}
YZ = TestSpec(plane="YZ", centre=(110, 110, 38), radius_mm=50)
XY = TestSpec(plane="XY", centre=(110, 110, 10), radius_mm=50)
TRUTH = volume_truth(noise_um=0.05)  # xy -3638.6, xz +800, yz -500 um/m
DS_TRUE = TRUTH.errors.scale_ppm["y"] - TRUTH.errors.scale_ppm["z"]  # YZ's scale mismatch


# ---------------------------------------------------------------------------------------
# which run informs which key


def doc(run_id, plane=None, xy=0.0, xz=0.0, yz=0.0, **kw):
    d = {
        "id": run_id,
        "date": "2026-11-27T10:00:00",
        "source": kw.pop("source", "trace"),
        "trusted": kw.pop("trusted", True),
        "diagnostics": {"plane": plane, "simulated": kw.pop("simulated", False)},
        "proposed": {"squareness_um_per_m": {"xy": xy, "xz": xz, "yz": yz}},
    }
    d.update(kw)
    return d


def test_the_newest_trusted_run_of_each_plane_is_used():
    runs = [  # newest first, as RunStore.documents gives them
        doc("r6", "XY", xy=999.0, trusted=False),
        doc("r5", "XY", xy=888.0, status="failed"),
        doc("r4", "YZ", xy=777.0, yz=-510.0),
        doc("r3", "XY", xy=-3600.0),
        doc("r2", "XY", xy=-3000.0),
        doc("r1", "XZ", xz=790.0),
        doc("r0", "XY", xy=555.0, simulated=True),
    ]
    known = known_squareness(runs)
    assert known["measured"]["values"] == {"xy": -3600.0, "yz": -510.0, "xz": 790.0}
    assert known["measured"]["sources"]["xy"] == "run r3 (XY, 2026-11-27T10:00:00)"
    assert known["simulated"]["values"] == {"xy": 555.0}


def test_a_campaign_informs_the_planes_it_measured():
    camp = doc("c1", xy=-3630.0, xz=805.0, yz=-1.0, source="campaign")
    camp["diagnostics"] = {"campaign": {"planes": ["XY", "XZ"]}, "simulated": False}
    known = known_squareness([camp])["measured"]
    assert known["values"] == {"xy": -3630.0, "xz": 805.0}  # yz kept from current: not it
    assert known["sources"]["xz"] == "run c1 (campaign, 2026-11-27T10:00:00)"


def test_broken_history_documents_inform_nothing():
    runs = [
        {"id": "x1"},
        doc("x2", "XY", proposed=None),
        doc("x3", "XY", proposed={"squareness_um_per_m": {"xy": None}}),
        doc("x4", "XY", proposed={"squareness_um_per_m": {"xy": "big"}}),
        doc("x5", "QQ"),
    ]
    assert known_squareness(runs)["measured"]["values"] == {}


def test_a_trace_takes_the_values_of_its_kind():
    known = known_squareness([doc("m", "XY", xy=1.0), doc("s", "XY", xy=2.0, simulated=True)])
    assert for_trace(known, SimpleNamespace(meta={"simulated": "true"}))[0] == {"xy": 2.0}
    assert for_trace(known, SimpleNamespace(meta={}))[0] == {"xy": 1.0}
    assert for_trace({}, SimpleNamespace(meta={})) == ({}, {})


# ---------------------------------------------------------------------------------------
# the plugin: uploads and live captures


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path), profile=A)
    yield ns
    ns.stop()


def connect(api, profile):
    pm = api.plugin._printer_profile_manager
    pm.get_current.return_value = profile
    pm.get_current_or_default.return_value = profile
    from unittest import mock

    api.plugin.queuing_hook(mock.MagicMock(), "queuing", "M110 N0", None, "M110")
    assert api.plugin.store.current()["profile"] == profile["id"]


def simulated(spec):
    text = generate(spec)
    stated, prog_hash = spec_from_program(text)
    return simulate_program(text, TRUTH, stated, prog_hash)


def upload(api, spec, name):
    resp = api.client.post(
        PREFIX + "/trace", data=simulated(spec).to_text().encode(), content_type="text/csv"
    )
    assert resp.status_code == 200, resp.get_data()[:300]
    return resp.get_json()


def codes(run):
    return {f["code"]: f for f in run["findings"]}


def test_an_upload_takes_the_profiles_xy_result_and_not_another_profiles(api):
    xy = upload(api, XY, "xy.csv")
    assert xy["trusted"] is True and xy["profile"] == "printer_a"
    xy_value = xy["proposed"]["squareness_um_per_m"]["xy"]
    assert xy_value == pytest.approx(-3638.6, rel=0.02)
    # the YZ test of the same printer: xy fitted as known, xz still unknown (info)
    yz = upload(api, YZ, "yz.csv")
    found = codes(yz)
    used = found["model.out_of_plane_used"]["evidence"]
    assert used["known_um_per_m"] == {"xy": xy_value}
    assert used["sources"]["xy"].startswith(f"run {xy['id']} (XY, ")
    assert used["bias_removed_scale_mismatch_ppm"] == pytest.approx(6.6, abs=0.2)
    assert found["model.out_of_plane"]["evidence"]["uncorrected"] == ["xz"]
    d = yz["diagnostics"]
    assert abs(d["scale_mismatch_ppm"] - DS_TRUE) <= 1.5
    assert d["fit"]["out_of_plane_um_per_m"]["oA"] == pytest.approx(xy_value)
    # printer B has no XY result: A's is not used, the bias is there and said (info)
    connect(api, B)
    other = upload(api, YZ, "yz_b.csv")
    found = codes(other)
    assert "model.out_of_plane_used" not in found
    assert found["model.out_of_plane"]["evidence"]["uncorrected"] == ["xy", "xz"]
    biased = other["diagnostics"]["scale_mismatch_ppm"] - DS_TRUE
    assert biased == pytest.approx(6.3, abs=1.2)
    assert other["trusted"] is True


def test_a_live_capture_takes_the_profiles_xy_result(api):
    xy = upload(api, XY, "xy.csv")
    recorder = api.plugin.sensor._recorder
    recorder.on_recorded = None  # (no campaign to hand it to)
    trace = simulated(YZ)
    res = CaptureResult(True, None, trace, None, YZ, "")
    armed = SimpleNamespace(source="sensor", path="kincomp/ballbar_YZ.gcode")
    run = recorder.record(res, armed, "/dev/null")
    assert run["source"] == "live" and run["status"] == "ok"
    used = codes(run)["model.out_of_plane_used"]["evidence"]
    assert used["sources"]["xy"].startswith(f"run {xy['id']} ")
    assert abs(run["diagnostics"]["scale_mismatch_ppm"] - DS_TRUE) <= 1.5
    # the same trace uploaded gives the same result
    again = api.client.post(
        PREFIX + "/trace", data=trace.to_text().encode(), content_type="text/csv"
    ).get_json()
    assert again["diagnostics"]["scale_mismatch_ppm"] == pytest.approx(
        run["diagnostics"]["scale_mismatch_ppm"]
    )
    assert json.dumps(run["findings"])  # stored as plain JSON
