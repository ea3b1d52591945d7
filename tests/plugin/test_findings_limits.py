"""Issue 23 on the plugin (mocked OctoPrint objects, tests/support/mocked_plugin.py): every
stored result carries findings and trusted, an untrusted one is applied only with "force";
the printer's motion limits are read from its answer to M503 (or pasted), validated as a
setting, shown in /status and respected by the test program and the campaign plan."""

from unittest import mock

import pytest

from octoprint_kincomp.calibration import findings as F
from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.core.messages import Msg
from tests.support import permissions
from tests.support.mocked_plugin import api_app, mocked_plugin, wait_for

PROFILE = {
    "id": "_default",
    "name": "Virtual P1",
    "volume": {"width": 220, "depth": 220, "height": 250, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 3000}},
}
SUMMARY = {"summary": {"plane": "XY", "squareness_um_per_m": 400.0}}
MARLIN_M503 = [
    "echo:; Maximum feedrates (units/s):",
    "echo:  M203 X500.00 Y500.00 Z10.00 E25.00",
    "echo:; Maximum Acceleration (units/s2):",
    "echo:  M201 X500.00 Y500.00 Z100.00 E5000.00",
    "echo:  M204 P500.00 R500.00 T1000.00",
    "echo:  M205 B20000.00 S0.00 T0.00 J0.08",
    "ok",
]


@pytest.fixture
def plugin(tmp_path):
    from octoprint_kincomp.service.files.worker import InProcessWorker

    p = mocked_plugin(str(tmp_path))
    p.jobs.worker = InProcessWorker()  # (the analyses patched below run in this process)
    p._printer_profile_manager.get_current_or_default.return_value = PROFILE
    p._printer.is_printing.return_value = False
    p._printer.is_operational.return_value = True
    return p


@pytest.fixture
def app():
    return api_app()


def call(app, view, *args, json=None, method="POST"):
    with app.test_request_context("/", method=method, json=json):
        with permissions.granted():
            resp = view(*args)
    return resp.status_code, resp.get_json()


def _with_error(trace, current=None, **kw):
    """The real analysis, with an error finding as issue 23's motion check gives one."""
    result = analyse(trace, current=current, **kw)
    found = [
        F.info("note", "said for the record"),
        F.error(
            "motion.feed_capped",
            Msg("the run took %(s)s s longer than planned", s="19.1"),
            Msg("lower the feed to what the Z axis reaches"),
            sync_mismatch_ms=19074.0,
        ),
    ]
    # (the analysis's own shapes: English dicts and the translatable wire form)
    result["findings"] = [f.to_dict() for f in found]
    result["findings_i18n"] = [f.to_wire() for f in found]
    result["trusted"] = F.trusted(found)
    return result


# ~~ findings ------------------------------------------------------------------------------------
def test_notes_become_info_findings_and_the_run_is_trusted(app, plugin):
    code, run = call(app, plugin.calibration.analyze, json=SUMMARY)
    assert code == 200 and run["trusted"] is True
    # a clean summary: info findings only, every note among them, messages translatable
    assert run["findings"] and {f["severity"] for f in run["findings"]} == {"info"}
    texts = [f["message"]["text"] for f in run["findings"]]
    assert all(n in texts for n in run["notes"])
    assert all(f["message"].get("template") for f in run["findings"])
    code, stored = call(app, plugin.calibration.run, run["id"], method="GET")
    assert stored["findings"] == run["findings"]
    code, _ = call(app, plugin.calibration.apply, json={"run": run["id"]})
    assert code == 200  # trusted: no confirmation needed


def test_an_untrusted_result_is_applied_only_with_force(app, plugin):
    before = plugin.store.current()["params"]
    with mock.patch("octoprint_kincomp.service.calibration.measurement.analyse", _with_error):
        code, run = call(app, plugin.calibration.analyze, json=SUMMARY)
    assert code == 200 and run["trusted"] is False
    # worst first, message and advice translatable, evidence kept
    first = run["findings"][0]
    assert first["severity"] == "error" and first["code"] == "motion.feed_capped"
    assert first["message"]["template"] == "the run took %(s)s s longer than planned"
    assert first["advice"]["text"] == "lower the feed to what the Z axis reaches"
    assert first["evidence"] == {"sync_mismatch_ms": 19074.0}
    code, listed = call(app, plugin.calibration.runs, method="GET")
    assert [r["trusted"] for r in listed["runs"] if r["id"] == run["id"]] == [False]
    code, body = call(app, plugin.calibration.apply, json={"run": run["id"]})
    assert code == 409 and "not trusted" in body["error"]
    assert "19.1 s longer than planned" in body["error"] and '"force": true' in body["error"]
    assert plugin.store.current()["params"] == before  # nothing applied
    code, body = call(app, plugin.calibration.apply, json={"run": run["id"], "force": "yes"})
    assert code == 400  # a flag is a boolean
    code, body = call(app, plugin.calibration.apply, json={"run": run["id"], "force": True})
    assert code == 200
    assert plugin.store.current()["params"]["squareness_um_per_m"]["xy"] != before.get(
        "squareness_um_per_m", {}
    ).get("xy")
    code, stored = call(app, plugin.calibration.run, run["id"], method="GET")
    assert stored["applied"]


def test_a_campaign_result_that_is_not_trusted_needs_force(app, plugin):
    with mock.patch("octoprint_kincomp.service.calibration.measurement.analyse", _with_error):
        code, run = call(app, plugin.calibration.analyze, json=SUMMARY)
    doc = call(app, plugin.campaign.plan, json={"radius_xy": 50})[1]
    stored = plugin.campaign._campaigns.get(doc["id"])
    stored["result"] = run["id"]  # as if its joint analysis gave this result
    plugin.campaign._campaigns.save(stored)
    code, view = call(app, plugin.campaign.get, doc["id"], method="GET")
    assert view["analysis"]["trusted"] is False and view["analysis"]["findings"]
    code, body = call(app, plugin.campaign.apply, doc["id"], json={})
    assert code == 409 and "not trusted" in body["error"]
    assert not plugin.campaign._campaigns.get(doc["id"]).get("applied")
    code, _ = call(app, plugin.campaign.apply, doc["id"], json={"force": True})
    assert code == 200 and plugin.campaign._campaigns.get(doc["id"]).get("applied")


# ~~ motion limits ---------------------------------------------------------------------------------
def _read_m503(plugin, lines=MARLIN_M503):
    for line in lines:
        plugin.received_hook(None, line)


def test_m503_answer_is_stored_and_caps_the_vertical_feed(app, plugin):
    plugin.on_event("FirmwareData", {"name": "Marlin 2.1.2", "data": {}})
    plugin.received_hook(None, "ok T:20.0 /0.0")  # other traffic changes nothing
    _read_m503(plugin)
    wait_for(lambda: plugin.store.current()["motion_limits"]["source"] == "m503")
    stated = plugin.store.current()["motion_limits"]
    assert (
        "M203 X500.00 Y500.00 Z10.00" in stated["text"]
        and stated["firmware"] == "Marlin 2.1.2"
        and stated["captured"]
    )
    with app.test_request_context("/"):
        with permissions.granted():
            status = plugin.settings_api.status().get_json()["motion_limits"]
    assert status["read"]["max_feed_mm_min"]["z"] == 600.0  # 10 mm/s
    assert status["effective"]["max_feed_mm_min"] == {"x": 6000.0, "y": 6000.0, "z": 600.0}
    assert status["effective"]["sources"]["max_feed_mm_min.x"] == "printer profile"
    # the program keeps within them and says why
    code, prog = call(
        app,
        plugin.calibration.program,
        json={"plane": "XZ", "radius": 50, "centre": [110, 110, 70]},
    )
    assert code == 200 and prog["spec"]["feed_mm_min"] == 600.0
    assert "Z axis' max feed is 600 mm/min" in prog["feed_lowered"][0]["text"]
    ((args, _),) = list(plugin._file_manager.add_file.call_args_list)
    text = args[2].stream().read().decode() if hasattr(args[2], "stream") else ""
    assert "M220 S100" in text and "F1850" not in text
    # and so does a campaign plan
    code, doc = call(app, plugin.campaign.plan, json={"dry_run": True})
    feeds = {s["name"]: s["spec"]["feed_mm_min"] for s in doc["steps"]}
    assert feeds == {"xy": 1850.0, "xz": 600.0, "yz": 600.0}


def test_marlins_soft_endstops_are_asked_and_kept_with_its_m503_answer(app, plugin):
    """Marlin's M503 leaves out its soft endstops: KinComp asks M211 first and keeps its
    answer (an ok of its own in between, and a temperature poll's) for the M503 answer's,
    so the travel the compensation keeps inside is the firmware's."""
    from octoprint_kincomp.firmware.motion_limits import travel_limits

    plugin.on_event("FirmwareData", {"name": "Marlin 2.1.2", "data": {}})
    assert call(app, plugin.limits.read_request)[0] == 202
    (args, _) = plugin._printer.commands.call_args
    assert args[0] == ["M211", "M503"]
    m211 = "echo:Soft endstops: ON  Min:  X-2.00 Y-3.00 Z0.00   Max:  X218.00 Y215.00 Z250.00"
    _read_m503(plugin, [m211, "ok", "ok T:20.0 /0.0"] + MARLIN_M503)
    wait_for(lambda: "Soft endstops" in plugin.store.current()["motion_limits"]["text"])
    text = plugin.store.current()["motion_limits"]["text"]
    assert "M203 X500.00" in text
    assert travel_limits(text) == {"x": (-2.0, 218.0), "y": (-3.0, 215.0), "z": (0.0, 250.0)}


def test_pasted_limits_stay_until_the_user_asks_the_printer(app, plugin):
    code, body = call(
        app,
        plugin.settings_api.save,
        json={
            "motion_limits": {
                "text": "[printer]\nmax_velocity: 300\nmax_accel: 3000\nmax_z_velocity: 8"
            }
        },
    )
    assert code == 200 and body["settings"]["motion_limits"]["source"] == "pasted"
    _read_m503(plugin)  # e.g. the firmware check's M503 on connecting
    assert plugin.limits.store("\n".join(MARLIN_M503[:2]), replace=False) is False
    assert plugin.store.current()["motion_limits"]["source"] == "pasted"
    # asked explicitly: the printer's answer replaces them
    code, body = call(app, plugin.limits.read_request)
    assert code == 202
    (args, kwargs) = plugin._printer.commands.call_args
    assert args[0] == ["M503"] and "kincomp:motion-limits" in kwargs["tags"]
    _read_m503(plugin)
    wait_for(lambda: plugin.store.current()["motion_limits"]["source"] == "m503")
    plugin._printer.is_printing.return_value = True
    assert call(app, plugin.limits.read_request)[0] == 409


@pytest.mark.parametrize(
    "value, field",
    [
        ({"text": "hello"}, "motion_limits.text"),
        ({"text": 5}, "motion_limits.text"),
        ({"source": "guess"}, "motion_limits.source"),
        ({"speed": 1}, "motion_limits.speed"),
    ],
)
def test_bad_limits_are_refused_naming_the_field(app, plugin, value, field):
    code, body = call(app, plugin.settings_api.save, json={"motion_limits": value})
    assert code == 400 and field in body["error"]
    assert plugin.store.current()["motion_limits"]["text"] == ""


def test_a_feed_no_axis_can_reach_is_refused(app, plugin):
    call(
        app,
        plugin.settings_api.save,
        json={"motion_limits": {"text": "M203 X200 Y200 Z0.5 ; mm/s"}},
    )
    code, body = call(
        app,
        plugin.calibration.program,
        json={"plane": "YZ", "radius": 50, "centre": [110, 110, 70]},
    )
    assert code == 400 and "Z axis' max feed is 30 mm/min" in body["error"]
    assert not plugin._file_manager.add_file.called


# ~~ the speed factor ------------------------------------------------------------------------------
def test_the_speed_factor_stays_at_100_while_a_test_prints(plugin):
    from octoprint_kincomp.service.printing.speed_factor import changes_factor

    assert changes_factor("M220 S80") == 80.0 and changes_factor("M220") is None
    assert changes_factor("M221 S80") is None and changes_factor("m220 r") != 100.0
    ui = {"source:api", "api:printer.command"}
    plugin._printer.is_printing.return_value = True
    plugin._printer.get_current_job.return_value = {"file": {"path": "kincomp/ballbar_XZ.gcode"}}
    assert plugin.queuing_hook(None, "queuing", "M220 S80", None, "M220", tags=ui) == (None,)
    (_, msg), _ = plugin._plugin_manager.send_plugin_message.call_args
    assert msg["severity"] == "warning" and msg["params"]["command"] == "M220 S80"
    # the program's own line, a query and S100 pass
    for cmd, tags in (
        ("M220 S100", {"source:file", "fileline:3"}),
        ("M220", ui),
        ("M220 S100", ui),
    ):
        assert plugin.queuing_hook(None, "queuing", cmd, None, "M220", tags=tags) != (None,)
    # any other print: the user's speed factor is theirs
    plugin._printer.get_current_job.return_value = {"file": {"path": "benchy.gcode"}}
    assert plugin.queuing_hook(None, "queuing", "M220 S80", None, "M220", tags=ui) != (None,)


def test_a_campaign_test_is_refused_when_the_limits_changed_since_the_plan(app, plugin):
    code, doc = call(app, plugin.campaign.plan, json={"radius_xy": 50})
    assert code == 200 and doc["steps"][1]["spec"]["feed_mm_min"] == 1850.0  # profile Z 3000
    _read_m503(plugin)  # the printer answers M503 after the plan: Z 10 mm/s
    wait_for(lambda: plugin.store.current()["motion_limits"]["source"] == "m503")
    code, body = call(app, plugin.campaign.program, doc["id"], 2, json={})
    assert code == 409 and "planned at 1850 mm/min" in body["error"]
    assert "allow 600 mm/min now" in body["error"] and "plan the campaign again" in body["error"]
    assert not plugin._file_manager.add_file.called
    code, _ = call(app, plugin.campaign.program, doc["id"], 1, json={})  # XY: still fine
    assert code == 200


def test_the_reversal_deadband_follows_the_printers_steps_per_mm(app, plugin):
    """Issue 28: M92 in the M503 answer is kept with the limits and the compensator's
    reversal deadband is a twentieth of the finer X/Y step (160 steps/mm: 0.3125 um); the
    setting ``steps_per_mm`` overrides it; with neither, 80 steps/mm (0.625 um)."""
    assert plugin.queue.comp.options.deadband_mm == pytest.approx(0.000625)
    plugin.on_event("FirmwareData", {"name": "Marlin 2.1.2", "data": {}})
    _read_m503(
        plugin, ["echo:; Steps per unit:", "echo:  M92 X80.00 Y160.00 Z400.00 E93.00"] + MARLIN_M503
    )
    wait_for(lambda: plugin.store.current()["motion_limits"]["source"] == "m503")
    assert "M92 X80.00 Y160.00" in plugin.store.current()["motion_limits"]["text"]
    assert plugin.queue.comp.options.deadband_mm == pytest.approx(0.0003125)
    code, body = call(app, plugin.settings_api.save, json={"steps_per_mm": 100, "apply_now": True})
    assert code == 200, body
    assert plugin.queue.comp.options.deadband_mm == pytest.approx(0.0005)
    code, body = call(app, plugin.settings_api.save, json={"steps_per_mm": 0})
    assert code == 400 and "steps_per_mm" in body["error"]
