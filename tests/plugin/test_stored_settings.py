"""Issue 17, case 2: an invalid stored value never erases the calibration. The stored
document is kept untouched, compensation is off and the problem reported (status, log, UI
message) until the user fixes it; a partial save never drops stored keys it did not name;
compensation and file jobs refuse to run meanwhile (no file marked with the all-zero hash)."""

import json
import os

import pytest
import yaml

from tests.support.blueprint import PREFIX, blueprint_client

CALIBRATED = {
    "enabled": True,
    "params": {
        "squareness_um_per_m": {"xy": "garbage", "xz": 120.0, "yz": -80.0},
        "scale_ppm": {"x": 350.0, "y": -200.0, "z": 0.0},
        "backlash": {"x": 45.0, "y": 30.0, "z": 0.0},
    },
    "demo": {"enabled": True},
}


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path), stored=CALIBRATED)
    with open(os.path.join(ns.uploads, "ok.gcode"), "w") as f:
        f.write("G28\nG1 X10 Y10 Z1 F3000\nG1 X50 Y20\n")
    ns.config = os.path.join(str(tmp_path), "base", "config.yaml")
    yield ns
    ns.stop()


def stored(api):
    with open(api.config) as f:
        return (yaml.safe_load(f) or {}).get("plugins", {}).get("kincomp")


def post(api, path, body):
    resp = api.client.post(PREFIX + path, data=json.dumps(body), content_type="application/json")
    return resp.status_code, resp.get_json(silent=True) or {}


def test_an_invalid_value_is_reported_and_compensation_is_off(api):
    st = api.client.get(PREFIX + "/status").get_json()
    assert st["settings_problem_field"] == "params.squareness_um_per_m.xy"
    assert "garbage" in st["settings_problem"]
    assert st["compensation"]["enabled"] is False and not api.plugin.queue.enabled
    # the editable view keeps every valid stored value, only the bad one shows its default
    p = st["settings"]["params"]
    assert p["squareness_um_per_m"] == {"xy": 0.0, "xz": 120.0, "yz": -80.0}
    assert p["scale_ppm"]["x"] == 350.0 and p["backlash"]["x"] == 45.0
    logged = [c[0][0] for c in api.plugin._logger.error.call_args_list]
    assert any("invalid" in m for m in logged)
    texts = [
        c[0][1]["text"]
        for c in api.plugin._plugin_manager.send_plugin_message.call_args_list
        if "text" in c[0][1]
    ]
    assert any("compensation is off" in t for t in texts)


def test_a_partial_save_is_refused_until_the_value_is_fixed_and_keeps_everything(api):
    before = stored(api)
    code, resp = post(api, "/settings", {"limits_policy": "warn"})
    assert code == 400 and "params.squareness_um_per_m.xy" in resp["error"]
    assert stored(api) == before  # nothing lost, nothing written
    api.plugin.on_settings_save({"limits_policy": "warn"})  # OctoPrint's dialog: the same
    assert stored(api) == before
    code, resp = post(
        api,
        "/settings",
        {"params": {"squareness_um_per_m": {"xy": 250.0}}, "limits_policy": "warn"},
    )
    assert code == 200, resp
    p = stored(api)["params"]
    assert p["squareness_um_per_m"] == {"xy": 250.0, "xz": 120.0, "yz": -80.0}
    assert p["scale_ppm"]["x"] == 350.0 and p["backlash"]["y"] == 30.0
    assert stored(api)["demo"] == {"enabled": True} and stored(api)["limits_policy"] == "warn"
    st = api.client.get(PREFIX + "/status").get_json()
    assert st["settings_problem"] is None and st["compensation"]["enabled"] is True


def test_files_are_not_compensated_on_invalid_settings(api):
    code, resp = post(api, "/compensate", {"path": "ok.gcode"})
    assert code == 409 and "invalid" in resp["error"]
    resp = api.client.get(PREFIX + "/dryrun?path=ok.gcode")
    assert resp.status_code == 409
    api.plugin.files.file_added({"path": "ok.gcode", "storage": "local"})  # background mode
    assert not api.plugin.jobs.jobs
    assert api.plugin.files.preprocess("up.gcode", object()) is None  # on-upload mode
    assert not api.plugin._file_manager.add_file.called


def test_applying_a_calibration_fixes_the_settings_and_keeps_the_rest(api):
    code, resp = post(api, "/apply", {"params": {"scale_ppm": {"x": 10.0}}})
    assert code == 200, resp
    assert stored(api)["demo"] == {"enabled": True}
    assert api.client.get(PREFIX + "/status").get_json()["settings_problem"] is None
