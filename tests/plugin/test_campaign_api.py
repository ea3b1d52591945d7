"""The campaign endpoints (plugin/calibration/campaign_api.py) on the plugin with mocked OctoPrint
objects (tests/support/mocked_plugin.py): planning on the profile's volume, printing test by test,
each test measured in demo mode by the live capture of the virtual bar (a real pseudo-terminal read
through pyserial, as a USB sensor) or, with the live path off, by the demo's SIMULATED trace
collected per test, the joint analysis, ONE apply, the re-test compared with the campaign before it,
and every way a campaign refuses to go on (issues 12 and 15)."""

import os
import re
import time
from unittest import mock

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.demo import demo_truth
from octoprint_kincomp.simulator.printer import simulate_program
from tests.support import permissions
from tests.support.mocked_plugin import api_app, mocked_plugin, queue_lines, wait_for

PROFILE = {
    "id": "_default",
    "name": "Virtual P1",
    "volume": {"width": 200, "depth": 200, "height": 200, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 3000}},
}
# another printer (profile id and name), without a calibration of its own
OTHER = dict(PROFILE, id="printer_b", name="Printer B")
PLAN = {"radius_xy": 50}
SKEW = {"squareness_um_per_m": {"xy": 500.0, "xz": 0.0, "yz": 0.0}}
# the demo's virtual bar streams at 20 times the feed (its 500 Hz: 10,000 lines/s)
QUICKER = mock.patch("octoprint_kincomp.service.calibration.demo_mode.DEMO_SPEEDUP", 20.0)


@pytest.fixture
def plugin(tmp_path):
    p = mocked_plugin(str(tmp_path))
    p._printer_profile_manager.get_current_or_default.return_value = PROFILE
    p._printer.is_printing.return_value = False
    yield p
    p.sensor._preview = False
    p.sensor._release()  # the demo's virtual bar stops


@pytest.fixture
def app():
    return api_app()


def call(app, view, *args, json=None, data=None, path="/"):
    """(status, JSON body) of a view, every permission granted."""
    with app.test_request_context(path, method="POST", json=json, data=data):
        with permissions.granted():
            resp = view(*args)
    return resp.status_code, resp.get_json()


def switch_profile(plugin, profile):
    """A printer connected with ``profile``: its set comes into force."""
    pm = plugin._printer_profile_manager
    pm.get_current.return_value = pm.get_current_or_default.return_value = profile
    plugin.store.follow_profile()
    assert plugin.store.current()["profile"] == profile["id"]


def plan(app, plugin, **options):
    code, doc = call(app, plugin.campaign.plan, json=dict(PLAN, **options))
    assert code == 200, doc
    return doc


def offline_trace(doc, n, truth=None):
    """The SIMULATED trace of test n of campaign ``doc`` as a printer without compensation
    would give it (the program as KinComp writes it)."""
    step = doc["steps"][n - 1]
    text = generate(TestSpec(**step["spec"]), params_hash=doc["params_hash"])
    spec, prog_hash = spec_from_program(text)
    return simulate_program(text, truth or demo_truth(), spec, prog_hash).to_text()


def upload(app, plugin, tmp_path, cid, n, text, name="trace.csv", **fields):
    """The test's trace as OctoPrint hands an upload to a view (a temporary file; ``fields``:
    more form fields)."""
    path = tmp_path / f"upload-{n}-{name}"
    path.write_text(text)
    return call(
        app,
        plugin.campaign.trace,
        cid,
        n,
        data=dict(fields, **{"file.path": str(path), "file.name": name}),
    )


def messages(plugin, kind):
    return [
        c[0][1]
        for c in plugin._plugin_manager.send_plugin_message.call_args_list
        if c[0][1].get("type") == kind
    ]


def print_in_demo_mode(plugin, path):
    """The program at ``path`` printed on the demo's virtual printer: its commands go out
    through KinComp's queuing hook (comments stripped as OctoPrint does; nothing pauses at
    its M0), then the print is done and the SIMULATED trace is made."""
    text = plugin._file_manager.add_file.call_args[0][2].stream().read().decode()
    plugin._printer.get_current_job.return_value = {"file": {"origin": "local", "path": path}}
    plugin.on_event("PrintStarted", {"origin": "local", "path": path})
    queue_lines(plugin, text.splitlines())
    plugin.on_event("PrintDone", {"origin": "local", "path": path})
    wait_for(lambda: plugin.demo.last_trace() is not None, 60)


def run_campaign(app, plugin, doc):
    """Every test printed and measured by collecting the demo's simulated trace (its live
    path off); returns the campaign analysed."""
    for step in doc["steps"]:
        code, resp = call(app, plugin.campaign.program, doc["id"], step["n"], json={"print": True})
        assert code == 200 and resp["printing"], resp
        assert resp["path"] == f"kincomp/{doc['id']}_{step['n']}_{step['name']}.gcode"
        assert not resp["capture"]
        print_in_demo_mode(plugin, resp["path"])
        code, resp = call(app, plugin.campaign.trace, doc["id"], step["n"], json={"demo": True})
        assert code == 200, resp
        run = resp["run"]
        assert run["campaign"] == doc["id"] and run["campaign_step"] == step["name"]
        assert run["simulated"] and run["diagnostics"]["plane"] == step["plane"]
    code, done = call(app, plugin.campaign.analyze, doc["id"])
    assert code == 200, done
    return done


def test_a_campaign_is_planned_on_the_profiles_volume_and_feeds(app, plugin):
    slow_z = dict(PROFILE, axes=dict(PROFILE["axes"], z={"speed": 1200}))
    plugin._printer_profile_manager.get_current_or_default.return_value = slow_z
    code, dry = call(
        app,
        plugin.campaign.plan,
        json=dict(PLAN, dry_run=True, second_feed=3700, second_height=100),
    )
    assert code == 200 and dry["stored"] is False
    assert [s["name"] for s in dry["steps"]] == ["xy", "xz", "yz", "xy-z100", "xy-f3700"]
    assert [s["plane"] for s in dry["steps"]] == ["XY", "XZ", "YZ", "XY", "XY"]
    # each test in words for the page (the names above are keys)
    words = [s["test"]["text"] for s in dry["steps"]]
    assert words == ["XY", "XZ", "YZ", "XY at Z 100 mm", "XY at 3700 mm/min"]
    xy, xz = dry["steps"][0], dry["steps"][1]
    assert xy["centre"] == [100.0, 100.0, 10.0] and xy["radius_mm"] == 50.0
    # vertical tests: capped to the slowest axis of their plane (Z: 1200 mm/min)
    assert xz["feed_mm_min"] == 1200.0 and xz["requested_feed_mm_min"] == 1850.0
    assert dry["steps"][3]["centre"][2] == 100.0
    assert dry["printer"] == "Virtual P1" and dry["volume"] == [0, 200, 0, 200, 0, 200]
    assert dry["params_hash"] == Params().hash() and dry["state"] == "measuring"
    assert dry["next_step"] == 1 and dry["measured"] == 0
    with app.test_request_context("/campaigns"):
        with permissions.granted():
            assert plugin.campaign.list().get_json()["campaigns"] == []  # a dry run
    doc = plan(app, plugin)
    assert doc["stored"] and [s["name"] for s in doc["steps"]] == ["xy", "xz", "yz"]
    with app.test_request_context("/campaigns"):
        with permissions.granted():
            listed = plugin.campaign.list().get_json()["campaigns"]
            assert [c["id"] for c in listed] == [doc["id"]]
            assert (
                plugin.campaign.get(doc["id"]).get_json()["steps"][0]["program_hash"]
                == doc["steps"][0]["program_hash"]
            )
            assert plugin.campaign.get("c20990101-000000-abcdef").status_code == 404
            assert plugin.campaign.get("../../etc/passwd").status_code == 404


@pytest.mark.parametrize(
    "body, field",
    [
        ({"radius_xy": "100"}, "radius_xy"),
        ({"radius_xy": True}, "radius_xy"),
        ({"radius_vertical": 2}, "radius_vertical"),
        ({"feed": None}, "feed"),
        ({"second_feed": "fast"}, "second_feed"),
        ({"second_height": [1]}, "second_height"),
        ({"dry_run": "true"}, "dry_run"),
        ({"retest_of": "c20990101-000000-abcdef"}, "campaign to re-test no longer exists"),
    ],
)
def test_bad_plan_requests_are_refused_naming_the_field(app, plugin, body, field):
    code, resp = call(app, plugin.campaign.plan, json=dict(PLAN, **body))
    assert code == 400 and field in resp["error"], resp


def test_a_plan_that_does_not_fit_names_the_test(app, plugin):
    code, resp = call(app, plugin.campaign.plan, json={"radius_xy": 100})
    assert code == 400 and "campaign test XY" in resp["error"] and "does not fit" in resp["error"]
    code, resp = call(app, plugin.campaign.plan, json=dict(PLAN, feed=6000, second_feed=9000))
    assert code == 400 and "second XY feed is capped" in resp["error"]
    code, resp = call(app, plugin.campaign.plan, json=["radius_xy"])
    assert code == 400
    assert os.listdir(plugin.campaign._campaigns.folder) == []


@QUICKER
def test_a_whole_campaign_in_demo_mode_applied_once_and_re_tested(app, plugin):
    # demo mode with its live path off: each test is measured by collecting the simulated
    # trace of the printed commands. (The live path, each test measured by the capture of
    # the virtual bar in real time, is walked whole on the real server in the browser:
    # tests/browser/test_campaign_ui.py; in-process: the live test below.)
    plugin.on_settings_save({"demo": {"enabled": True, "live": False}})
    assert plugin.demo.live is False
    doc = plan(app, plugin)
    done = run_campaign(app, plugin, doc)
    assert done["state"] == "analysed" and done["next_step"] is None
    a = done["analysis"]
    assert a["source"] == "campaign" and a["simulated"] and a["campaign"] == doc["id"]
    assert [t["plane"] for t in a["diagnostics"]["traces"]] == ["XY", "XZ", "YZ"]
    assert len(a["plots"]) == 3 and a["campaign_steps"] == ["xy", "xz", "yz"]
    # one parameter set for the whole volume: the demo printer's hidden errors
    p = a["proposed"]
    assert p["squareness_um_per_m"] == pytest.approx(
        {"xy": -3638.6, "xz": 800.0, "yz": -500.0}, abs=10
    )
    # the first campaign has nothing to compare with: the rows hold the measured values
    xz = a["comparison"][1]
    assert xz["step"] == "xz" and xz["before_plot"] is None
    rows = {r["key"]: r for r in xz["rows"]}
    assert rows["squareness_um_per_m"]["before"] is None
    assert rows["squareness_um_per_m"]["after"] == pytest.approx(800.0, abs=10)
    servo = a["diagnostics"]["campaign"]["servo_precomp"]
    assert servo["reason_i18n"]["template"].startswith("XY ran at one feed only")
    # the campaign's runs: one per test, grouped by the campaign id in the history
    runs = plugin.runs.list()
    assert sorted(r["campaign_step"] or "" for r in runs if r["campaign"] == doc["id"]) == [
        "",
        "xy",
        "xz",
        "yz",
    ]
    assert sum(r["has_trace"] for r in runs) == 3
    # analysed: closed to more measurements
    code, resp = call(app, plugin.campaign.program, doc["id"], 1, json={})
    assert code == 409 and "re-test" in resp["error"]

    # ONE apply: the joint proposal becomes the parameters, compensation on
    code, applied = call(app, plugin.campaign.apply, doc["id"], json={"enabled": True})
    assert code == 200, applied
    assert plugin.queue.enabled and plugin.queue.params.hash() == applied["params_hash"]
    assert plugin.queue.params.squareness_um_per_m["xz"] == pytest.approx(
        p["squareness_um_per_m"]["xz"]
    )
    assert plugin.runs.get(a["id"])["applied"]
    with app.test_request_context("/"):
        with permissions.granted():
            assert plugin.campaign.get(doc["id"]).get_json()["state"] == "applied"

    # the re-test: the same plan, measured with the new parameters in force (the demo
    # records the compensated commands), compared test by test with the first campaign
    code, again = call(app, plugin.campaign.plan, json={"retest_of": doc["id"]})
    assert code == 200 and again["retest_of"] == doc["id"]
    assert again["options"] == doc["options"]
    assert again["params_hash"] == applied["params_hash"]
    after = run_campaign(app, plugin, again)["analysis"]
    for cmp in after["comparison"]:
        rows = {r["key"]: r for r in cmp["rows"]}
        assert cmp["before_plot"] is not None and cmp["before_run"] == a["id"]
        assert rows["squareness_um_per_m"]["reduction_pct"] > 95, cmp["step"]
        assert rows["scale_mismatch_ppm"]["reduction_pct"] > 95, cmp["step"]
        assert abs(rows["squareness_um_per_m"]["after"]) < 5, cmp["step"]


@pytest.mark.alone  # (the virtual bar streams in real time: another test's load makes it miss)
@QUICKER
def test_demo_live_a_test_is_measured_by_its_capture_once_a_failed_one_left_open(app, plugin):
    plugin.on_settings_save({"demo": {"enabled": True}})
    doc = plan(app, plugin)
    cid = doc["id"]
    code, resp = call(app, plugin.campaign.program, cid, 1, json={"print": True})
    assert code == 200 and resp["capture"]["armed"] and resp["capture"]["source"] == "demo"
    # the printer waits at the mount pause (M0): the virtual bar does not play the test yet
    text = plugin._file_manager.add_file.call_args[0][2].stream().read().decode()
    lines = text.splitlines()
    mount = next(i for i, ln in enumerate(lines) if ln.startswith("M0 "))
    plugin.on_event("PrintStarted", {"origin": "local", "path": resp["path"]})
    queue_lines(plugin, lines[: mount + 1])
    time.sleep(1.0)
    status = plugin.sensor._status(plugin.sensor._cap)
    assert status["state"] == "armed" and status["reading_mm"] == pytest.approx(1.0, abs=0.01)
    assert plugin.demo.stream_end() == float("inf")  # (its end not known yet)
    # the user goes on: the test is played, captured and taken as its measurement
    queue_lines(plugin, lines[mount + 1 :])
    plugin.on_event("PrintDone", {"origin": "local", "path": resp["path"]})
    wait_for(lambda: messages(plugin, "sensor_run"), 60)
    told = messages(plugin, "sensor_run")[-1]["run"]
    assert told["campaign"] == cid and told["campaign_step"] == "xy", told
    camp = plugin.campaign._campaigns.get(cid)
    assert camp["steps"][0]["run"] == told["id"]
    wait_for(lambda: plugin.demo.last_trace() is not None, 60)
    time.sleep(0.2)
    assert not messages(plugin, "demo_trace")  # not measured a second time
    # the recorded trace stays an API fallback (it replaces the capture as the measurement)
    code, resp = call(app, plugin.campaign.trace, cid, 1, json={"demo": True})
    assert code == 200 and resp["campaign"]["steps"][0]["run"] == resp["run"]["id"] != told["id"]

    # test 2: the virtual bar is unplugged mid-test: a failed run, the test left unmeasured
    plugin._plugin_manager.send_plugin_message.reset_mock()
    code, resp = call(app, plugin.campaign.program, cid, 2, json={"print": True})
    assert resp["capture"]["armed"]
    plugin.on_event("PrintStarted", {"origin": "local", "path": resp["path"]})
    queue_lines(
        plugin, plugin._file_manager.add_file.call_args[0][2].stream().read().decode().splitlines()
    )
    wait_for(lambda: plugin.sensor._cap.state == "capturing", 30)
    plugin.demo._sensor.unplug()
    wait_for(lambda: messages(plugin, "sensor_run"), 30)
    told = messages(plugin, "sensor_run")[-1]["run"]
    assert told["status"] == "failed" and "disconnected" in told["message"]
    assert told["campaign"] is None
    assert told["test_of"] == {"campaign": cid, "campaign_step": "xz"}  # the UI says which
    assert plugin.runs.get(told["id"])["status"] == "failed"  # kept in the history
    note = [m for m in messages(plugin, "notify") if "capture failed" in m["text"]]
    assert note and note[-1]["severity"] == "error"
    plugin.on_event("PrintDone", {"origin": "local", "path": resp["path"]})
    wait_for(lambda: plugin.demo.last_trace() is not None, 60)
    camp = plugin.campaign._campaigns.get(cid)
    assert camp["steps"][1]["run"] is None and camp["steps"][1]["printed"]
    time.sleep(0.2)
    assert not messages(plugin, "demo_trace")  # nor collected by itself: the user chooses
    with app.test_request_context("/"):
        with permissions.granted():
            view = plugin.campaign.get(cid).get_json()
    assert view["measured"] == 1 and view["next_step"] == 2


def test_a_campaign_refuses_to_go_on_when_the_parameters_changed(app, plugin, tmp_path):
    doc = plan(app, plugin)
    trace = offline_trace(doc, 1)
    code, _ = upload(app, plugin, tmp_path, doc["id"], 1, trace)
    assert code == 200
    plugin.on_settings_save({"enabled": True, "params": SKEW})
    for view, args, body in (
        (plugin.campaign.program, (doc["id"], 2), {"print": True}),
        (plugin.campaign.trace, (doc["id"], 2), {"demo": True}),
        (plugin.campaign.analyze, (doc["id"],), {}),
    ):
        code, resp = call(app, view, *args, json=body)
        assert code == 409 and "parameters in force changed" in resp["error"], resp
        assert doc["params_hash"] not in resp["error"]  # (no hashes: issue 35)
    assert not plugin._printer.select_file.called
    with app.test_request_context("/"):
        with permissions.granted():
            view = plugin.campaign.get(doc["id"]).get_json()
    assert view["params_changed"] and view["in_force_hash"] == Params.from_dict(SKEW).hash()
    # back to the campaign's parameters (compensation off: none in force): it goes on
    plugin.on_settings_save({"enabled": False})
    code, resp = call(app, plugin.campaign.program, doc["id"], 2, json={})
    assert code == 200 and resp["printing"] is False
    # the same profile renamed: it goes on (the profile id decides, not the name)
    plugin._printer_profile_manager.get_current_or_default.return_value = dict(
        PROFILE, name="Other"
    )
    code, resp = call(app, plugin.campaign.program, doc["id"], 2, json={})
    assert code == 200, resp
    # another printer profile in force: refused too
    switch_profile(plugin, OTHER)
    code, resp = call(app, plugin.campaign.program, doc["id"], 2, json={})
    assert code == 409 and "planned for printer profile Virtual P1" in resp["error"], resp


def _edited(text, key, value):
    """``text`` (a trace) with its metadata line ``key`` set to ``value``."""
    assert f"# {key}: " in text
    return (
        "\n".join(
            f"# {key}: {value}" if ln.startswith(f"# {key}: ") else ln for ln in text.splitlines()
        )
        + "\n"
    )


def test_a_test_takes_only_its_own_trace(app, plugin, tmp_path):
    doc = plan(app, plugin)
    other = plan(app, plugin)
    cid = doc["id"]
    xy = offline_trace(doc, 1)
    cases = [
        (2, xy, "xy.csv", "it is the trace of test XY, not of test 2 (XZ)"),
        (1, offline_trace(other, 1), "other.csv", "belongs to another campaign, not to this one"),
        (
            1,
            _edited(xy, "program_hash", "0123456789ab"),
            "edited.csv",
            "the metadata was edited or belongs to another test",
        ),
        (
            1,
            _edited(xy, "params_hash", "ffffffffffff"),
            "params.csv",
            "measured with other parameters than the campaign runs with",
        ),
        (
            1,
            _edited(xy, "printer", "Other printer"),
            "printer.csv",
            "comes from printer Other printer",
        ),
        (1, "plane: XY\nsquareness_um_per_m: 5\n", "summary.json", "not a summary"),
        (1, "direction,time_s,reading_mm\nccw,zero,1\n", "broken.csv", "broken.csv: "),
    ]
    for n, text, name, expected in cases:
        code, resp = upload(app, plugin, tmp_path, cid, n, text, name)
        assert code == 400 and resp["error"].startswith(name), resp
        assert expected in resp["error"], resp
    code, resp = call(app, plugin.campaign.trace, cid, 1, json={"demo": True})
    assert code == 404 and "No simulated trace of test 1" in resp["error"]
    code, resp = call(app, plugin.campaign.trace, cid, 1, json={"demo": "yes"})
    assert code == 400 and "'demo'" in resp["error"]
    code, resp = call(app, plugin.campaign.trace, cid, 1, json={})
    assert code == 400 and "multipart field 'file'" in resp["error"]
    code, resp = call(app, plugin.campaign.trace, cid, 9, json={"demo": True})
    assert code == 404
    assert plugin.runs.list() == []
    # its own trace is taken (again: the newer replaces the older)
    for _ in range(2):
        code, resp = upload(app, plugin, tmp_path, cid, 1, xy, "xy.csv")
        assert code == 200 and resp["campaign"]["steps"][0]["run"] == resp["run"]["id"]
    assert resp["campaign"]["measured"] == 1 and resp["campaign"]["next_step"] == 2


def test_a_missing_or_failed_test_is_named_and_nothing_applied(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    before = plugin._settings.get(["params"])
    for n in (1, 2):
        code, _ = upload(app, plugin, tmp_path, cid, n, offline_trace(doc, n), f"t{n}.csv")
        assert code == 200
    code, resp = call(app, plugin.campaign.analyze, cid)
    assert code == 400 and "test 3 (YZ" in resp["error"] and "incomplete" in resp["error"]
    # the YZ test failed: the bar slipped half-way (a 30 um jump in every reading after it)
    lines = offline_trace(doc, 3).splitlines()
    rows = [i for i, ln in enumerate(lines) if ln.startswith("ccw,")]
    for i in rows[len(rows) // 2 :]:
        d, t, r = lines[i].split(",")
        lines[i] = f"{d},{t},{float(r) + 0.03:.7f}"
    code, resp = upload(app, plugin, tmp_path, cid, 3, "\n".join(lines) + "\n", "slipped.csv")
    assert code == 200
    code, resp = call(app, plugin.campaign.analyze, cid)
    assert code == 400 and resp["error"].startswith("slipped.csv: the fit leaves"), resp
    assert "repeat this test" in resp["error"]
    code, resp = call(app, plugin.campaign.apply, cid, json={"enabled": True})
    assert code == 409 and "analyse it first" in resp["error"]
    assert plugin._settings.get(["params"]) == before and not plugin.queue.enabled
    # the test measured again: the campaign is analysed
    code, _ = upload(app, plugin, tmp_path, cid, 3, offline_trace(doc, 3), "t3.csv")
    code, resp = call(app, plugin.campaign.analyze, cid)
    assert code == 200 and resp["state"] == "analysed"


def _live_run(plugin, text, name="live_XZ_R50.csv"):
    """A live capture of ``text`` as the sensor's recorder stores it (its trace names no
    parameters: a capture has only the program's metadata)."""
    from octoprint_kincomp.calibration.ballbar.analysis import analyse
    from octoprint_kincomp.calibration.ballbar.formats import load_any

    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("# params_hash:"))
    data = (text + "\n").encode()
    result = analyse(load_any(data, name), current=plugin.queue.params)
    run = plugin.calibration.record_run(
        result,
        name,
        "live",
        data,
        result.get("plot"),
        extra={"status": "ok", "capture": {"samples": 1}},
    )
    plugin.runs.save_raw(run["id"], b"time_s,reading_mm,line\n0.0,1.0,1.0\n")
    return run


def test_a_live_capture_of_a_test_becomes_its_measurement(app, plugin):
    recorder = plugin.sensor._recorder
    assert recorder.on_recorded == plugin.campaign.measure.take_capture
    doc = plan(app, plugin)
    live = _live_run(plugin, offline_trace(doc, 2))
    taken = recorder.on_recorded(live)
    # one run per trace: the capture's run is replaced by the campaign's, raw stream kept
    assert taken["id"] != live["id"] and taken["campaign"] == doc["id"]
    assert taken["campaign_step"] == "xz" and taken["source"] == "live"
    assert taken["capture"] == {"samples": 1} and plugin.runs.raw_path(taken["id"])
    assert [r["id"] for r in plugin.runs.list()] == [taken["id"]]
    assert plugin.campaign._campaigns.get(doc["id"])["steps"][1]["run"] == taken["id"]
    # a capture that is no campaign's test stays as it was
    single = _live_run(
        plugin, offline_trace(doc, 1).replace(f"# campaign: {doc['id']}", "# campaign: ")
    )
    assert recorder.on_recorded(single) is single
    # once the parameters changed, the campaign does not take it; the user is told
    plugin.on_settings_save({"enabled": True, "params": SKEW})
    plugin._plugin_manager.send_plugin_message.reset_mock()
    late = _live_run(plugin, offline_trace(doc, 3))
    assert recorder.on_recorded(late) is late
    msg = plugin._plugin_manager.send_plugin_message.call_args[0][1]
    assert msg["severity"] == "error" and "parameters in force changed" in msg["text"]
    assert plugin.campaign._campaigns.get(doc["id"])["steps"][2]["run"] is None


def test_printing_a_test_needs_a_ready_printer(app, plugin):
    doc = plan(app, plugin)
    plugin._printer.is_printing.return_value = True
    code, resp = call(app, plugin.campaign.program, doc["id"], 1, json={"print": True})
    assert code == 409 and "not ready" in resp["error"]
    step = plugin.campaign._campaigns.get(doc["id"])["steps"][0]
    assert step["path"] and step["printed"] is None
    code, resp = call(app, plugin.campaign.program, doc["id"], 1, json={"print": 1})
    assert code == 400 and "'print' must be true or false" in resp["error"]
    # the program the demo gets is the test as the program states it (campaign keys, the
    # parameters' hash): its simulated trace then names its campaign and test
    spec = plugin.demo._program_spec
    assert spec.campaign == doc["id"] and spec.campaign_step == "xy"
    assert spec.params_hash == doc["params_hash"] and spec.printer == "Virtual P1"
    # a live sensor in use is armed with the test as its program states it (the capture's
    # trace then names the campaign and the test); demo mode uses its own simulated trace
    plugin._printer.is_printing.return_value = False
    plugin.calibration.on_print = mock.MagicMock(return_value={"armed": True})
    code, resp = call(app, plugin.campaign.program, doc["id"], 2, json={"print": True})
    assert code == 200 and resp["capture"] == {"armed": True}
    path, armed, prog_hash = plugin.calibration.on_print.call_args[0]
    assert path == resp["path"] and prog_hash == resp["program_hash"]
    assert (armed.campaign, armed.campaign_step) == (doc["id"], "xz")
    # demo mode: its virtual bar is that live sensor; without the live path nothing is armed
    # (the demo's simulated trace is collected instead)
    plugin.on_settings_save({"demo": {"enabled": True}})
    plugin.calibration.on_print.reset_mock()
    code, resp = call(app, plugin.campaign.program, doc["id"], 3, json={"print": True})
    assert code == 200 and resp["capture"] == {"armed": True}
    assert plugin.calibration.on_print.call_args[0][1].campaign_step == "yz"
    plugin.on_settings_save({"demo": {"enabled": True, "live": False}})
    plugin.calibration.on_print.reset_mock()
    code, resp = call(app, plugin.campaign.program, doc["id"], 3, json={"print": True})
    assert code == 200 and resp["capture"] is None and not plugin.calibration.on_print.called


def test_each_route_asks_for_its_permissions(app, plugin):
    doc = plan(app, plugin)
    cid = doc["id"]
    routes = [
        (plugin.campaign.plan, (), {"dry_run": True}, {"ADMIN"}),
        (plugin.campaign.list, (), None, {"STATUS"}),
        (plugin.campaign.get, (cid,), None, {"STATUS"}),
        (plugin.campaign.program, (cid, 1), {}, {"ADMIN"}),
        (plugin.campaign.program, (cid, 1), {"print": True}, {"ADMIN", "PRINT"}),
        (plugin.campaign.trace, (cid, 1), {"demo": True}, {"ADMIN"}),
        (plugin.campaign.analyze, (cid,), {}, {"ADMIN"}),
        (plugin.campaign.apply, (cid,), {}, {"ADMIN"}),
        (plugin.campaign.delete, (cid,), None, {"ADMIN"}),
    ]
    for view, args, body, wanted in routes:
        asked = []
        perms = mock.Mock(STATUS="STATUS", PLUGIN_KINCOMP_ADMIN="ADMIN", PRINT="PRINT")
        with mock.patch("octoprint_kincomp.plugin.calibration.campaign_api.Permissions", perms):
            with mock.patch("octoprint_kincomp.plugin.http.Permissions", perms), mock.patch(
                "octoprint_kincomp.plugin.http.require", side_effect=asked.append
            ):
                with app.test_request_context(
                    "/", method="POST" if body is not None else "GET", json=body
                ):
                    view(*args)
        assert set(asked) == wanted, (view.__name__, asked)


def test_the_trace_upload_route_may_carry_a_large_trace():
    from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin, plugin_hooks

    sizes = plugin_hooks(KinCompPlugin())["octoprint.server.http.bodysize"]([])
    route = [r for m, r, s in sizes if m == "POST" and "campaigns" in r]
    assert route and re.match(route[0], "/campaigns/c20990101-000000-abcdef/steps/2/trace")


def _findings(run, code):
    return [f for f in run["findings"] if f["code"] == code]


def test_a_test_is_measured_on_the_printer_profile_it_was_planned_for(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    assert plugin.campaign._campaigns.get(cid)["profile"] == "_default"
    # the profile it was planned on: taken, nothing said of the printer
    code, resp = upload(app, plugin, tmp_path, cid, 1, offline_trace(doc, 1), "t1.csv")
    assert code == 200, resp
    assert not _findings(resp["run"], "campaign.other_profile")
    assert resp["run"]["profile"] == "_default"
    # another profile in force (the same name would not matter: the id decides): refused,
    # naming both, and nothing stored
    before = [r["id"] for r in plugin.runs.list()]
    t2 = offline_trace(doc, 2)
    switch_profile(plugin, dict(OTHER, name="Virtual P1"))
    code, resp = upload(app, plugin, tmp_path, cid, 2, t2, "t2.csv")
    assert code == 409 and "(printer_b) is in force" in resp["error"], resp
    switch_profile(plugin, OTHER)
    code, resp = upload(app, plugin, tmp_path, cid, 2, t2, "t2.csv")
    assert code == 409, resp
    # (names only: the ids are said when two profiles share a name, above)
    assert "planned for printer profile Virtual P1, but" in resp["error"]
    assert "printer profile Printer B is in force" in resp["error"]
    assert [r["id"] for r in plugin.runs.list()] == before
    assert plugin.campaign._campaigns.get(cid)["steps"][1]["run"] is None
    code, resp = upload(app, plugin, tmp_path, cid, 2, t2, "t2.csv", force="yes")
    assert code == 400 and "'force'" in resp["error"]
    code, resp = call(app, plugin.campaign.trace, cid, 2, json={"demo": True, "force": 1})
    assert code == 400 and "'force'" in resp["error"]
    assert [r["id"] for r in plugin.runs.list()] == before
    # a live capture of the test is not taken either (it stays a single run, the user told)
    live = _live_run(plugin, t2)
    assert plugin.sensor._recorder.on_recorded(live) is live
    msg = plugin._plugin_manager.send_plugin_message.call_args[0][1]
    assert msg["severity"] == "error" and "printer profile Printer B is in force" in msg["text"]
    plugin.runs.delete(live["id"])
    # taken anyway (force): the run says so in a warning finding and belongs to the campaign's
    # profile; the campaign remembers the test was measured under another one
    code, resp = upload(app, plugin, tmp_path, cid, 2, t2, "t2.csv", force="true")
    assert code == 200, resp
    run = resp["run"]
    (warned,) = _findings(run, "campaign.other_profile")
    assert warned["severity"] == "warning" and run["trusted"] is True
    assert warned["message"]["text"].startswith(
        "Measured while another printer profile was in force: This campaign was planned for"
    )
    assert warned["evidence"]["profile_in_force"] == "printer_b"
    assert warned["evidence"]["campaign_profile"] == "_default"
    assert run["profile"] == "_default" and resp["campaign"]["steps"][1]["run"] == run["id"]
    assert plugin.campaign._campaigns.get(cid)["steps"][1]["other_profile"] == "printer_b"
    # printing and the joint analysis stay refused while another profile is in force
    code, resp = call(app, plugin.campaign.program, cid, 3, json={})
    assert code == 409 and "Printer B" in resp["error"]
    # back on the campaign's printer: the last test, and the joint result repeats the warning
    switch_profile(plugin, PROFILE)
    code, resp = upload(app, plugin, tmp_path, cid, 3, offline_trace(doc, 3), "t3.csv")
    assert code == 200 and not _findings(resp["run"], "campaign.other_profile")
    code, done = call(app, plugin.campaign.analyze, cid)
    assert code == 200, done
    (joint,) = _findings(done["analysis"], "campaign.other_profile")
    assert joint["evidence"]["tests"] == [2] and "(printer_b)" in joint["message"]["text"]
    # applying it while another profile is in force: refused unless forced (issue 37)
    switch_profile(plugin, OTHER)
    code, resp = call(app, plugin.campaign.apply, cid, json={"enabled": True})
    assert code == 409 and "This campaign belongs to printer profile _default" in resp["error"]
    code, resp = call(app, plugin.campaign.apply, cid, json={"enabled": True, "force": True})
    assert code == 200, resp
    assert [f["code"] for f in resp["findings"]] == ["applied.other_profile"]
    applied = plugin.runs.get(plugin.campaign._campaigns.get(cid)["result"])
    assert applied["applied_profile"] == "printer_b"
    assert _findings(applied, "applied.other_profile")


def test_the_refusal_for_another_printer_comes_in_german(app, plugin):
    from babel.support import Translations

    from octoprint_kincomp.core.messages import translate

    doc = plugin.campaign._campaigns.get(plan(app, plugin)["id"])
    switch_profile(plugin, OTHER)
    de = Translations.load(os.path.join(os.path.dirname(plugin_dir()), "translations"), ["de"])
    german = translate(plugin.campaign.measure.other_printer(doc), de.gettext)
    assert german.startswith("Diese Kampagne wurde für das Druckerprofil Virtual P1 geplant")
    (found,) = plugin.campaign.measure.profile_findings(doc)
    assert translate(found.message, de.gettext).startswith("Gemessen, während")


def plugin_dir():
    import octoprint_kincomp.plugin as pkg

    return os.path.dirname(pkg.__file__)


def delete(app, plugin, cid):
    with app.test_request_context("/", method="DELETE"):
        with permissions.granted():
            resp = plugin.campaign.delete(cid)
    return resp.status_code, resp.get_json()


def test_a_campaign_is_deleted_its_runs_stay_in_the_history(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    code, resp = upload(app, plugin, tmp_path, cid, 1, offline_trace(doc, 1), "t1.csv")
    assert code == 200
    measured = resp["run"]["id"]
    kept = plan(app, plugin)["id"]
    assert delete(app, plugin, "c20990101-000000-abcdef") == (404, {"error": "No such campaign"})
    assert delete(app, plugin, "../../etc/passwd")[0] == 404
    code, resp = delete(app, plugin, cid)
    assert code == 200 and resp == {"deleted": cid}
    with app.test_request_context("/campaigns"):
        with permissions.granted():
            assert [c["id"] for c in plugin.campaign.list().get_json()["campaigns"]] == [kept]
            assert plugin.campaign.get(cid).status_code == 404
    assert plugin.runs.get(measured)["campaign"] == cid  # the measurement is kept
    assert delete(app, plugin, cid)[0] == 404
    # the measurement of a deleted campaign's test is refused, not stored
    code, resp = upload(app, plugin, tmp_path, cid, 2, offline_trace(doc, 2), "t2.csv")
    assert code == 404 and [r["id"] for r in plugin.runs.list()] == [measured]


def test_another_printers_campaign_is_not_deleted(app, plugin):
    cid = plan(app, plugin)["id"]
    switch_profile(plugin, OTHER)
    code, resp = delete(app, plugin, cid)
    assert code == 409 and "belongs to printer profile _default" in resp["error"], resp
    assert plugin.campaign._campaigns.get(cid)
    switch_profile(plugin, PROFILE)
    assert delete(app, plugin, cid)[0] == 200


def test_a_campaign_being_measured_is_not_deleted(app, plugin):
    doc = plan(app, plugin)
    cid = doc["id"]
    code, resp = call(app, plugin.campaign.program, cid, 2, json={"print": True})
    assert code == 200 and resp["printing"], resp
    # its test 2 printing (and paused at the mount pause): refused, saying why
    plugin._printer.get_current_job.return_value = {
        "file": {"origin": "local", "path": resp["path"]}
    }
    for printing, paused in ((True, False), (False, True)):
        plugin._printer.is_printing.return_value = printing
        plugin._printer.is_paused.return_value = paused
        code, out = delete(app, plugin, cid)
        assert code == 409, out
        assert out["error"].startswith("Test 2 (XZ) of this campaign is being printed")
    # another file printing: the campaign may go
    other = plan(app, plugin)["id"]
    code, out = delete(app, plugin, other)
    assert code == 200, out
    # a live capture armed for one of its tests (the demo's virtual bar, waiting for the
    # print to start): refused too
    plugin._printer.is_printing.return_value = plugin._printer.is_paused.return_value = False
    assert plugin.sensor.armed_campaign() is None and delete(app, plugin, plan(app, plugin)["id"])
    plugin.on_settings_save({"demo": {"enabled": True}})
    code, resp = call(app, plugin.campaign.program, cid, 3, json={"print": True})
    assert code == 200 and resp["capture"]["armed"], resp
    assert plugin.sensor.armed_campaign() == cid
    code, out = delete(app, plugin, cid)
    assert code == 409 and "live capture is armed for a test of this campaign" in out["error"], out
    assert plugin.campaign._campaigns.get(cid)


def test_findings_added_to_a_result_keep_it_worst_first():
    """A forced measurement's warning goes before the analysis's own info findings (the
    stored result is worst first, as every analysis's is)."""
    from octoprint_kincomp.calibration import findings as fnd
    from octoprint_kincomp.service.calibration.campaign_measure import with_findings

    note = fnd.info("model.cyclic_fitted", "a note")
    result = {"findings": [note.to_dict()], "findings_i18n": [note.to_wire()], "trusted": True}
    out = with_findings(result, [fnd.warning("campaign.other_profile", "another printer")])
    for key in ("findings", "findings_i18n"):
        assert [f["severity"] for f in out[key]] == ["warning", "info"], out[key]
    assert out["trusted"] is True and result["findings"] == [note.to_dict()]
