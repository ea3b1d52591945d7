"""Issue 28, first half: a calibration belongs to one printer (OctoPrint printer profile).
Switching profiles switches the parameters, home and motion limits in force; a profile
without a calibration prints uncompensated and says so; the settings from before profiles
move onto the profile active then; the history shows the runs of the profile in force."""

import json
import os
from unittest import mock

import pytest
import yaml

from tests.support.blueprint import PREFIX, blueprint_client

VOLUME = {"width": 220, "depth": 220, "height": 200, "origin": "lowerleft"}
A = {"id": "printer_a", "name": "Printer A", "volume": VOLUME}
B = {"id": "printer_b", "name": "Printer B", "volume": VOLUME}
# today's global set (from before profiles): XY squareness 1000 um/m, the home known
CALIBRATED = {
    "enabled": True,
    "params": {"squareness_um_per_m": {"xy": 1000.0, "xz": 0.0, "yz": 0.0}},
    "home_mm": [0.0, 0.0, 0.0],
    "motion_limits": {
        "text": "M203 X500 Y500 Z12 E120\nM201 X3000 Y3000 Z100 E5000",
        "firmware": "Marlin",
    },
}
MOVE = "G1 X100 Y100 F3000"


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path), stored=CALIBRATED, profile=A)
    ns.config = os.path.join(str(tmp_path), "base", "config.yaml")
    yield ns
    ns.stop()


def status(api):
    return api.client.get(PREFIX + "/status").get_json()


def connect(api, profile):
    """A printer connected with ``profile``: a new connection's first command."""
    pm = api.plugin._printer_profile_manager
    pm.get_current.return_value = profile
    pm.get_current_or_default.return_value = profile
    comm = mock.MagicMock()
    api.plugin.queuing_hook(comm, "queuing", "M110 N0", None, "M110")
    return comm


def sent(api, comm, line):
    """What KinComp sends for ``line`` (None: the line as written)."""
    return api.plugin.queuing_hook(
        comm, "queuing", line, None, line.split()[0], tags={"source:file"}
    )


def messages(api):
    return [
        c[0][1]
        for c in api.plugin._plugin_manager.send_plugin_message.call_args_list
        if c[0][1].get("type") == "notify"
    ]


def stored(api):
    with open(api.config) as f:
        return yaml.safe_load(f)["plugins"]["kincomp"]


def test_the_settings_from_before_profiles_move_onto_the_active_profile(api):
    doc = stored(api)
    assert doc["profile"] == "printer_a" and doc["legacy_profile"] == "printer_a"
    kept = doc["profiles"]["printer_a"]
    assert kept["params"]["squareness_um_per_m"]["xy"] == 1000.0
    assert kept["home_mm"] == [0.0, 0.0, 0.0]
    assert kept["motion_limits"]["text"].startswith("M203 X500")
    st = status(api)
    assert st["profile"] == {
        "id": "printer_a",
        "name": "Printer A",
        "calibrated": True,
        "known": ["printer_a"],
        "deleted": [],
    }
    assert st["compensation"]["enabled"] is True


def test_settings_from_before_profiles_wait_for_the_first_printer_that_connects(tmp_path):
    """OctoPrint's default profile (B here) need not be the printer the old calibration was
    measured on: nothing is adopted while no printer is connected; the first one that
    connects (A) adopts it."""
    ns = blueprint_client(str(tmp_path), stored=CALIBRATED, profile=B, connected=False)
    try:
        ns.config = os.path.join(str(tmp_path), "base", "config.yaml")
        assert not stored(ns).get("profile")  # not adopted by the default profile B
        comm = connect(ns, A)
        doc = stored(ns)
        assert doc["profile"] == "printer_a" and doc["legacy_profile"] == "printer_a"
        assert doc["profiles"]["printer_a"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
        sent(ns, comm, "G28")
        assert sent(ns, comm, MOVE) is not None and ns.plugin.queue.enabled
    finally:
        ns.stop()


def test_a_switch_that_cannot_be_stored_leaves_compensation_off(api):
    """config.yaml not writable when printer B connects: A's set stays stored, so it must
    not be applied to B; said as an error, and no exception reaches OctoPrint's hook."""
    comm = connect(api, A)
    assert api.plugin.queue.enabled
    api.plugin._plugin_manager.send_plugin_message.reset_mock()
    with mock.patch.object(
        api.plugin.store, "_store", side_effect=OSError(28, "No space left on device")
    ):
        comm = connect(api, B)  # (raises nothing)
    assert not api.plugin.queue.enabled
    assert any(m["severity"] == "error" and "could not switch" in m["text"] for m in messages(api))
    sent(api, comm, "G28")
    assert sent(api, comm, MOVE) is None  # A's skew is not applied to B


def test_switching_profiles_switches_the_calibration_in_force(api):
    comm = connect(api, A)
    sent(api, comm, "G28")
    assert sent(api, comm, MOVE) is not None  # A's skew moves the point
    api.plugin._plugin_manager.send_plugin_message.reset_mock()

    comm = connect(api, B)
    st = status(api)
    assert st["profile"]["id"] == "printer_b" and st["profile"]["calibrated"] is False
    assert st["compensation"]["enabled"] is False and not api.plugin.queue.enabled
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert st["settings"]["home_mm"] is None and st["settings"]["motion_limits"]["text"] == ""
    # said, not silent
    warned = [m for m in messages(api) if m["severity"] == "warning"]
    assert any("Printer B has no KinComp calibration" in m["text"] for m in warned)
    sent(api, comm, "G28")
    assert sent(api, comm, MOVE) is None  # B prints as written: A's skew is not applied

    # B gets its own parameters; A's are kept
    resp = api.client.post(
        PREFIX + "/settings",
        data=json.dumps(
            {"params": {"scale_ppm": {"x": 500.0}}, "home_mm": [0, 0, 0], "apply_now": True}
        ),
        content_type="application/json",
    )
    assert resp.status_code == 200, resp.get_json()
    st = status(api)
    assert st["profile"]["calibrated"] is True and st["compensation"]["enabled"] is True
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    doc = stored(api)
    assert doc["profiles"]["printer_b"]["params"]["scale_ppm"]["x"] == 500.0
    assert doc["profiles"]["printer_a"]["params"]["squareness_um_per_m"]["xy"] == 1000.0

    # back to A (on OctoPrint's event): A's set is in force again, B's kept
    api.plugin._printer_profile_manager.get_current.return_value = A
    api.plugin.on_event("Connected", {})
    st = status(api)
    assert st["profile"]["id"] == "printer_a" and st["profile"]["calibrated"] is True
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
    assert st["settings"]["params"]["scale_ppm"]["x"] == 0.0
    assert st["settings"]["motion_limits"]["text"].startswith("M203 X500")
    assert stored(api)["profiles"]["printer_b"]["params"]["scale_ppm"]["x"] == 500.0


def test_a_request_cannot_name_the_profile_in_force(api):
    resp = api.client.post(
        PREFIX + "/settings",
        data=json.dumps({"profile": "printer_b", "profiles": {}}),
        content_type="application/json",
    )
    assert resp.status_code == 200
    doc = stored(api)
    assert doc["profile"] == "printer_a" and "printer_a" in doc["profiles"]


def test_without_a_printer_connected_the_last_profile_stays_in_force(api):
    pm = api.plugin._printer_profile_manager
    pm.get_current.return_value = None  # disconnected: OctoPrint deselects the profile
    pm.get_current_or_default.return_value = B
    api.plugin.on_event("PrinterProfileModified", {"identifier": "printer_b"})
    assert status(api)["profile"]["id"] == "printer_a" and api.plugin.queue.enabled


def test_the_history_shows_the_runs_of_the_profile_in_force(api):
    runs = api.plugin.runs
    old = runs.new_id()  # a run recorded before profiles: no profile in it
    with open(os.path.join(runs.folder, old + ".json"), "w") as f:
        json.dump({"id": old, "source": "trace"}, f)
    on_a = runs.new_id()
    runs.save({"id": on_a, "source": "trace"})
    assert runs.get(on_a)["profile"] == "printer_a"

    def listed():
        return {r["id"] for r in api.client.get(PREFIX + "/runs").get_json()["runs"]}

    assert listed() == {old, on_a}
    connect(api, B)
    on_b = runs.new_id()
    runs.save({"id": on_b, "source": "summary"})
    assert listed() == {on_b}
    runs.save(dict(runs.get(on_a), applied=True))  # an update keeps the run's profile
    assert runs.get(on_a)["profile"] == "printer_a"
    connect(api, A)
    assert listed() == {old, on_a}


def trusted_run(api, source, xy):
    """A trusted run recorded now (for the profile in force) proposing XY squareness
    ``xy`` um/m; its id."""
    runs = api.plugin.runs
    run_id = runs.new_id()
    runs.save(
        {
            "id": run_id,
            "source": source,
            "trusted": True,
            "proposed": {"squareness_um_per_m": {"xy": xy}},
        }
    )
    return run_id


def _apply(api, body):
    resp = api.client.post(
        PREFIX + "/apply", data=json.dumps(body), content_type="application/json"
    )
    return resp.status_code, resp.get_json()


def test_a_run_of_another_printer_is_applied_only_when_forced(api):
    """A stale page (or the API) applying printer A's run while B is in force: refused
    (409) unless forced; a page loaded for A (``expected_profile``) is refused with force
    too. Forced: applied to B, the answer and the run carry the warning
    ``applied.other_profile`` naming both profiles; A's set unchanged."""
    on_a = trusted_run(api, "trace", 500.0)
    connect(api, B)
    code, resp = _apply(api, {"run": on_a, "enabled": True})
    assert code == 409 and "printer_a" in resp["error"]
    code, resp = _apply(
        api, {"run": on_a, "enabled": True, "force": True, "expected_profile": "printer_a"}
    )
    assert code == 409 and resp["profile_changed"]["current"] == "printer_b"
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert not api.plugin.runs.get(on_a).get("applied")
    code, resp = _apply(api, {"run": on_a, "enabled": True, "force": True})
    assert code == 200, resp
    (warned,) = resp["findings"]
    assert warned["code"] == "applied.other_profile" and warned["severity"] == "warning"
    assert warned["evidence"] == {"run_profile": "printer_a", "profile_in_force": "printer_b"}
    text = warned["message"]["text"]  # (the mocked profile manager names no profiles)
    assert "profile printer_b although" in text and "profile printer_a" in text
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 500.0
    run = api.plugin.runs.get(on_a)
    assert run["applied"] and run["applied_profile"] == "printer_b"
    assert [f["code"] for f in run["findings"]] == ["applied.other_profile"]
    assert run["profile"] == "printer_a"  # still A's run, in A's history
    connect(api, A)
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
    code, resp = _apply(api, {"run": on_a})
    assert code == 200 and resp["findings"] == []
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 500.0


def test_a_bad_stored_profile_set_is_reported_and_compensation_is_off(tmp_path):
    bad = dict(
        CALIBRATED,
        profile="printer_a",
        profiles={"printer_a": {"params": {"scale_ppm": {"x": "garbage"}}}},
    )
    ns = blueprint_client(str(tmp_path), stored=bad, profile=A)
    try:
        st = status(ns)
        assert st["settings_problem_field"] == "profiles.printer_a.params.scale_ppm.x"
        assert st["compensation"]["enabled"] is False and not ns.plugin.queue.enabled
    finally:
        ns.stop()


def test_a_fix_of_bad_stored_settings_on_another_printer_never_applies_the_first_ones(tmp_path):
    bad = dict(
        CALIBRATED,
        profile="printer_a",
        decimals="garbage",
        profiles={"printer_a": {"params": CALIBRATED["params"]}},
    )
    ns = blueprint_client(str(tmp_path), stored=bad, profile=A)
    try:
        pm = ns.plugin._printer_profile_manager
        pm.get_current.return_value = pm.get_current_or_default.return_value = B
        ns.plugin.on_event("Connected", {})  # B connected while the settings are invalid
        assert not ns.plugin.queue.enabled
        resp = ns.client.post(
            PREFIX + "/settings",
            data=json.dumps({"decimals": 3, "apply_now": True}),
            content_type="application/json",
        )
        assert resp.status_code == 200, resp.get_json()
        st = status(ns)
        assert st["profile"]["id"] == "printer_b" and st["profile"]["calibrated"] is False
        assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
        assert not ns.plugin.queue.enabled
        assert ns.plugin.queue.comp.params.squareness_um_per_m["xy"] == 0.0
    finally:
        ns.stop()


def post_settings(api, body):
    return api.client.post(
        PREFIX + "/settings", data=json.dumps(body), content_type="application/json"
    )


def test_a_stale_settings_page_does_not_write_one_printers_values_into_another(api):
    """The page was loaded while A was in force and saved after a switch to B: refused
    (409 naming both, ``profile_changed``), nothing stored; the same save for the profile
    in force goes through, and a save that names no profile (a script) goes to it."""
    connect(api, A)
    loaded = status(api)["profile"]["id"]
    assert loaded == "printer_a"
    connect(api, B)
    before = stored(api)
    page = {"params": {"squareness_um_per_m": {"xy": 1000.0}}, "expected_profile": loaded}
    for body in (page, {"motion_limits": {"text": "M203 X9", "source": "pasted"}, **page}):
        resp = post_settings(api, body)
        assert resp.status_code == 409, resp.get_json()
        doc = resp.get_json()
        assert doc["profile_changed"] == {"expected": "printer_a", "current": "printer_b"}
        assert "printer_a" in doc["error"] and "printer_b" in doc["error"]
        assert stored(api) == before  # nothing stored
    # the same for parameters applied through the API (POST /apply with "params")
    resp = api.client.post(
        PREFIX + "/apply",
        data=json.dumps({"params": page["params"], "expected_profile": loaded}),
        content_type="application/json",
    )
    assert resp.status_code == 409 and resp.get_json()["profile_changed"]["current"] == "printer_b"
    assert stored(api) == before
    st = status(api)
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert st["profile"]["calibrated"] is False and not api.plugin.queue.enabled

    resp = post_settings(api, dict(page, expected_profile="printer_b"))
    assert resp.status_code == 200, resp.get_json()
    assert stored(api)["profiles"]["printer_b"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
    assert post_settings(api, {"decimals": 4}).status_code == 200
    assert post_settings(api, {"expected_profile": 3}).status_code == 400
    # A's set untouched all along
    assert stored(api)["profiles"]["printer_a"]["params"]["squareness_um_per_m"]["xy"] == 1000.0


def test_the_stale_page_check_names_profiles_by_their_names(api):
    api.plugin._printer_profile_manager.get_all.return_value = {"printer_a": A, "printer_b": B}
    connect(api, B)
    resp = post_settings(api, {"decimals": 4, "expected_profile": "printer_a"})
    assert resp.status_code == 409
    assert "Printer A" in resp.get_json()["error"] and "Printer B" in resp.get_json()["error"]


def _apply_campaign(api, cid, body):
    resp = api.client.post(
        PREFIX + f"/campaigns/{cid}/apply", data=json.dumps(body), content_type="application/json"
    )
    return resp.status_code, resp.get_json()


def test_campaigns_belong_to_the_printer_they_were_planned_on(api):
    """Planned on A: tagged A, listed for A only (kept while B is in force); its joint result
    is not applied to B (409; forced from a page loaded for A: 409 too; forced from the API:
    applied with a warning, tests/plugin/test_campaign_api.py), and is to A."""
    connect(api, A)
    resp = api.client.post(
        PREFIX + "/campaign/plan", data=json.dumps({}), content_type="application/json"
    )
    assert resp.status_code == 200, resp.get_json()
    cid = resp.get_json()["id"]
    campaigns = api.plugin.campaign._campaigns
    assert campaigns.get(cid)["profile"] == "printer_a"
    result = trusted_run(api, "campaign", 400.0)
    campaigns.save(dict(campaigns.get(cid), result=result))

    def listed():
        return [c["id"] for c in api.client.get(PREFIX + "/campaigns").get_json()["campaigns"]]

    assert listed() == [cid]
    connect(api, B)
    assert listed() == []
    code, resp = _apply_campaign(api, cid, {})
    assert code == 409 and "printer_a" in resp["error"]
    code, resp = _apply_campaign(api, cid, {"force": True, "expected_profile": "printer_a"})
    assert code == 409 and resp["profile_changed"] == {
        "expected": "printer_a",
        "current": "printer_b",
    }
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert campaigns.get(cid)["applied"] is None
    connect(api, A)
    assert listed() == [cid]
    resp = api.client.post(
        PREFIX + f"/campaigns/{cid}/apply", data=json.dumps({}), content_type="application/json"
    )
    assert resp.status_code == 200, resp.get_json()
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 400.0


def test_a_campaign_from_before_profiles_belongs_to_the_legacy_profile(api):
    campaigns = api.plugin.campaign._campaigns
    old = campaigns.new_id()
    with open(os.path.join(campaigns.folder, old + ".json"), "w") as f:
        json.dump({"id": old, "steps": [], "params_hash": "x", "result": None}, f)

    def listed():
        return [c["id"] for c in api.client.get(PREFIX + "/campaigns").get_json()["campaigns"]]

    assert listed() == [old]
    connect(api, B)
    assert listed() == []


def test_a_profile_deleted_in_octoprint_keeps_its_set_and_is_reported(api):
    connect(api, B)
    post_settings(api, {"params": {"scale_ppm": {"x": 10.0}}})
    pm = api.plugin._printer_profile_manager
    pm.get_all.return_value = {"printer_b": B}  # A deleted in OctoPrint
    st = status(api)
    assert st["profile"]["deleted"] == ["printer_a"]
    assert stored(api)["profiles"]["printer_a"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
    pm.get_all.return_value = {"printer_a": A, "printer_b": B}  # made again
    assert status(api)["profile"]["deleted"] == []
    connect(api, A)
    assert status(api)["settings"]["params"]["squareness_um_per_m"]["xy"] == 1000.0


def test_a_file_compensated_for_another_printer_prints_as_it_is_and_says_so(api, tmp_path):
    """A file compensated while A was in force, printed on B (calibrated with its own set):
    passed through as written (never compensated twice, B's skew not added), and a warning
    names printer A, in the UI and the log."""
    from octoprint_kincomp.core.marker import marker_line
    from octoprint_kincomp.core.params import Params

    a_hash = Params.from_dict(status(api)["settings"]["params"]).hash()
    gcode = tmp_path / "uploads" / "part.gcode"  # (the test storage's folder)
    gcode.write_text(marker_line(a_hash, "0") + "\nG28\n" + MOVE + "\n")
    api.plugin._printer_profile_manager.get_all.return_value = {"printer_a": A, "printer_b": B}
    comm = connect(api, B)
    post_settings(api, {"params": {"squareness_um_per_m": {"xy": -800.0}}, "apply_now": True})
    assert api.plugin.queue.enabled
    api.plugin._plugin_manager.send_plugin_message.reset_mock()
    with mock.patch.object(api.plugin._logger, "warning") as log:
        api.plugin.on_event("PrintStarted", {"origin": "local", "path": "part.gcode"})
    warned = [m for m in messages(api) if m["severity"] == "warning"]
    assert len(warned) == 1 and "compensated for printer profile Printer A" in warned[0]["text"]
    assert any("Printer A" in str(c) for c in log.call_args_list)
    sent(api, comm, "G28")
    assert sent(api, comm, MOVE) is None  # as written: A's corrections only, not B's too

    # the same file on A: no warning, and still never compensated twice
    api.plugin.on_event("PrintDone", {"origin": "local", "path": "part.gcode"})
    comm = connect(api, A)
    api.plugin._plugin_manager.send_plugin_message.reset_mock()
    api.plugin.on_event("PrintStarted", {"origin": "local", "path": "part.gcode"})
    assert not [m for m in messages(api) if m["severity"] == "warning"]
    sent(api, comm, "G28")
    assert sent(api, comm, MOVE) is None
