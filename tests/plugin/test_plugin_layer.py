"""The OctoPrint glue with mocked OctoPrint objects (issue 3)."""

import io
from unittest import mock

import pytest

from octoprint_kincomp.core.compensator import LimitError, Options
from octoprint_kincomp.core.kinematics import changes_nothing
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.plugin.firmware_watch import FirmwareWatcher
from octoprint_kincomp.plugin.queue import QueueCompensator
from octoprint_kincomp.plugin.settings import (
    SettingsError,
    defaults,
    engine_config,
    limits_from_profile,
    max_feeds_from_profile,
    migrate,
    validate_settings,
)
from tests.support.mocked_plugin import api_app, mocked_plugin

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}, "backlash": {"x": 20.0}})


def normalize(result, cmd="X", cmd_type=None, tags=None):
    """What OctoPrint's comm layer makes of a queuing-hook result."""
    from octoprint.util.comm import _normalize_command_handler_result

    return _normalize_command_handler_result(cmd, cmd_type, None, None, tags or set(), result)


# -- queue adapter ---------------------------------------------------------------------------

def test_hook_results_normalise_like_octoprint():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    assert q.handle("G28") is None
    res = q.handle("G1 X10 Y50 Z1 F3000")
    norm = normalize(res, "G1 X10 Y50 Z1 F3000")
    assert [c for c, *_ in norm] == res
    # x - 1000 um/m * 50 mm = 9.950, plus half the 20 um take-up: after homing the direction of
    # the last motion is unknown, so the first move takes up half the play either way
    assert norm[-1][0].startswith("G1 X9.960 Y50.000")
    # a reversal: the take-up comes out as its own command, in order
    res = q.handle("G1 X5")
    assert len(res) == 2 and len(normalize(res, "G1 X5")) == 2


def test_disabled_and_non_moves_pass_unchanged():
    q = QueueCompensator(SKEW, Options(), enabled=False)
    assert q.handle("G1 X10 Y10") is None
    q.set_enabled(True)
    for cmd in ("M105", "G28", "M104 S200"):
        assert q.handle(cmd) is None


def test_precompensated_file_lines_are_not_touched():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.print_started(precompensated=True)
    q.handle("G28", {"source:file"})
    assert q.handle("G1 X10 Y50 Z1", {"source:file", "fileline:3"}) is None
    # but commands from elsewhere (a jog during the print) are compensated
    q.handle("G28", {"source:api"})
    assert q.handle("G1 X10 Y50 Z1", {"source:api"}) is not None
    q.print_ended()
    assert q.skip_file is False


def test_failure_suppresses_and_reports():
    errors = []
    q = QueueCompensator(Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
                         Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
                         enabled=True, on_error=lambda c, e: errors.append((c, e)))
    q.print_started(precompensated=False)
    f = {"source:file"}
    q.handle("G28", f)
    res = q.handle("G1 X0 Y100 Z1", f)  # compensated X would be -0.2: outside
    assert res == [] and normalize(res, "G1 X0 Y100 Z1") == []
    assert errors and isinstance(errors[0][1], LimitError)
    assert q.status()["errors"] == 1 and q.status()["last_error"]["command"] == "G1 X0 Y100 Z1"
    # the refused line changed nothing: the position before it is still known
    assert q.comp.known == (True, True, True) and q.comp.m == [0.0, 0.0, 0.0]
    # until the print resumes or ends, the print's later moves are held back (not sent as
    # written); other commands, and moves from scripts or the user, still go through
    assert q.handle("G1 X10 Y10 Z1", f) == [] and q.handle("g01 x5", f) == []
    assert q.handle("M104 S0", f) is None
    assert q.handle("G28", {"source:script"}) is None
    assert q.handle("G1 X10 Y50 Z5", {"source:script"}) is not None
    assert q.status()["held_moves"] == 2 and q.status()["halted"]
    q.resume()
    assert q.handle("G1 X10 Y10 Z1", f) is not None


def test_after_a_refused_line_the_resumed_print_is_compensated_from_where_it_was():
    """XZ skew needs Z for every X command: forgetting positions after the error sent every
    later move as written until the next Z move. The refused line leaves the state as it was
    (take-up direction included), so the resumed print goes on compensated, exactly as a
    stream that never contained the refused line."""
    p = Params.from_dict({"squareness_um_per_m": {"xz": 3000.0, "xy": 1000.0},
                          "backlash": {"x": 20.0, "y": 10.0}})
    opts = Options(limits=(0, 200, 0, 200, 0, 200), policy="error")
    q = QueueCompensator(p, opts, enabled=True, on_error=lambda c, e: None)
    ref = QueueCompensator(p, opts, enabled=True)
    q.print_started(precompensated=False)
    f = {"source:file"}
    before = ["G28", "G1 X50 Y50 Z10 F3000", "G1 X60 Y40", "G1 X55 Y45"]
    for line in before:
        q.handle(line, f)
        ref.handle(line, f)
    assert q.handle("G1 X0.001 Y199", f) == []  # X command < 0 at Y=199: refused
    assert q.comp.known == (True, True, True)
    assert q.handle("G1 X70 Y70", f) == [] and q.halted  # held until resumed
    q.resume()
    for line in ("G1 X80 Y60", "G1 X30 Y90", "G1 X40 Y80 Z12"):
        got = q.handle(line, f)
        assert got is not None and got == ref.handle(line, f), line
    assert q.comp.report.untouched_unknown == 0


def test_failure_outside_a_print_suppresses_only_that_command():
    q = QueueCompensator(Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
                         Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
                         enabled=True, on_error=lambda c, e: None)
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") == []
    assert not q.status()["halted"]
    q.handle("G28")
    assert q.handle("G1 X10 Y100 Z1") is not None


def test_malformed_move_passes_but_is_reported_and_forgets_the_position():
    seen = []
    q = QueueCompensator(SKEW, Options(), enabled=True,
                         on_untouched=lambda c, why: seen.append((c, why)))
    q.handle("G28")
    q.handle("G1 X50 Y50")
    assert q.handle("G1 X80 Y80 Q") is None  # sent as written: the firmware may run it
    assert seen == [("G1 X80 Y80 Q", "malformed")]
    # the next move is not computed from the stale start: X-only needs Y, now unknown
    assert q.handle("G1 X90") is None and seen[-1] == ("G1 X90", "unknown")


def test_failure_pass_through_when_chosen():
    q = QueueCompensator(Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
                         Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
                         enabled=True, pass_through_on_error=True,
                         on_error=lambda c, e: None)
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") is None
    assert q.status()["passed_on_error"] == 1


def test_internal_exception_never_sends_the_move_raw():
    q = QueueCompensator(SKEW, Options(), enabled=True, on_error=lambda c, e: None)
    q.handle("G28")
    with mock.patch.object(q.comp, "process", side_effect=RuntimeError("boom")):
        assert q.handle("G1 X10 Y10") == []


def test_new_params_wait_for_the_next_print_unless_forced():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.print_started(False)
    new = Params.from_dict({"scale_ppm": {"x": 500.0}})
    assert q.configure(new, Options(), True, immediately=False) is False
    assert q.params.hash() == SKEW.hash() and q.status()["pending_params_hash"] == new.hash()
    q.print_ended()
    assert q.params.hash() == new.hash()
    # forced: applies now and keeps the tracked position
    q.handle("G28")
    q.handle("G1 X100 Y100 Z1")
    q.print_started(False)
    q.handle("G28")
    q.handle("G1 X100 Y100 Z1")
    assert q.configure(SKEW, Options(), True, immediately=True) is True
    assert q.comp.known == (True, True, True)
    out = q.handle("G1 X100 Y101")
    # new model at once: x = 100 - 1000 um/m * 101 mm = 99.899, X reverses: -10 um backlash
    assert out is not None and out[-1].startswith("G1 X99.889 Y101.000")


def test_reset_forgets_positions():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.handle("G28")
    q.reset()
    assert q.handle("G1 X10") is None  # unknown position: passes untouched (counted)
    assert q.status()["report"]["untouched_unknown_position"] == 1


# -- firmware watch --------------------------------------------------------------------------

def test_firmware_watch():
    w = FirmwareWatcher()
    w.received("echo:  M852 I0.0010 J0.0000 K0.0000")
    w.received("echo:  M425 F1.00 X0.05 Y0.00 Z0.00")
    assert w.skew and w.backlash
    assert set(w.conflicts(SKEW)) == {"skew", "backlash"}
    w.sent("M852 I0 J0 K0")
    w.sent("M425 X0 Y0 Z0")
    assert w.skew is None and w.backlash is None
    w.sent("SET_SKEW XY=141.6,141.2,100")
    assert w.skew
    w.sent("SET_SKEW CLEAR=1")
    assert w.skew is None
    assert w.conflicts(Params()) == {}
    # lower case, RepRapFirmware scale factors
    w.sent("m852 i0.002")
    assert w.skew
    w.received("M579 X1.0020 Y1.0000")
    scaled = Params.from_dict({"scale_ppm": {"x": 100.0}})
    assert set(w.conflicts(scaled)) == {"scale"}
    w.sent("M579 X1 Y1")
    assert w.scale is None
    assert FirmwareWatcher.relevant("m425 x0.1") and not FirmwareWatcher.relevant("G1 X5")


# -- settings --------------------------------------------------------------------------------

def test_settings_validation():
    s = validate_settings({"enabled": True, "params": {"squareness_um_per_m": {"xy": 12}}})
    assert s["enabled"] is True and s["params"]["squareness_um_per_m"]["xy"] == 12
    for bad, field in (({"enabled": "yes"}, "enabled"), ({"mode": "sometimes"}, "mode"),
                       ({"chord_tol_mm": 5}, "chord_tol_mm"), ({"decimals": 2}, "decimals"),
                       ({"bogus": 1}, "bogus"),
                       ({"params": {"squareness_um_per_m": {"xy": 1e9}}},
                        "params.squareness_um_per_m.xy"),
                       ({"params": {"backlash": {"x": -3}}}, "params.backlash.x"),
                       ({"home_mm": [0, 0]}, "home_mm")):
        with pytest.raises(SettingsError) as exc:
            validate_settings(bad)
        assert exc.value.field == field


def test_partial_params_update_keeps_the_other_terms():
    """{"params": {"scale_ppm": {"x": 100}}} changes X scale only (it used to reset the
    squareness and backlash it did not mention to zero); null resets a term; applying a
    complete proposal (replace_params) replaces the document."""
    base = validate_settings({"params": {"squareness_um_per_m": {"xy": -3000.0},
                                         "backlash": {"x": 30.0, "y": [{"at_mm": 0, "um": 5},
                                                                       {"at_mm": 200,
                                                                        "um": 9}]},
                                         "servo_lag_ms": {"x": 0.5}}})
    s = validate_settings({"params": {"scale_ppm": {"x": 100}}}, base)
    p = s["params"]
    assert p["scale_ppm"]["x"] == 100.0 and p["squareness_um_per_m"]["xy"] == -3000.0
    assert p["backlash"]["x"] == 30.0 and p["backlash"]["y"][1] == {"at_mm": 200.0, "um": 9.0}
    assert p["servo_lag_ms"]["x"] == 0.5
    # a table replaced by a number, a whole term removed with null
    s = validate_settings({"params": {"backlash": {"y": 4}, "servo_lag_ms": None}}, base)
    assert s["params"]["backlash"]["y"] == 4.0 and "servo_lag_ms" not in s["params"]
    assert s["params"]["backlash"]["x"] == 30.0
    full = validate_settings({"params": {"scale_ppm": {"x": 100}}}, base, replace_params=True)
    assert full["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert "servo_lag_ms" not in full["params"]
    # a merged document is still validated as a whole
    with pytest.raises(SettingsError) as exc:
        validate_settings({"params": {"scale_ppm": {"q": 1}}}, base)
    assert exc.value.field.startswith("params.scale_ppm")


def test_settings_migration_from_flat_keys():
    old = {"enabled": True, "skew_xy": 250.0, "scale_x": -100.0}
    new = validate_settings(migrate(old, None))
    assert new["params"]["squareness_um_per_m"]["xy"] == 250.0
    assert new["params"]["scale_ppm"]["x"] == -100.0


def test_profile_limits_and_feeds():
    prof = {"volume": {"width": 220, "depth": 210, "height": 250, "origin": "lowerleft"},
            "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 200}}}
    assert limits_from_profile(prof) == (0, 220, 0, 210, 0, 250)
    prof["volume"]["origin"] = "center"
    assert limits_from_profile(prof) == (-110, 110, -105, 105, 0, 250)
    prof["volume"]["custom_box"] = {"x_min": -5, "x_max": 225, "y_min": -3, "y_max": 215,
                                    "z_min": 0, "z_max": 250}
    assert limits_from_profile(prof) == (-5, 225, -3, 215, 0, 250)
    assert max_feeds_from_profile(prof) == {"x": 6000.0, "y": 6000.0, "z": 200.0}
    params, options = engine_config(defaults(), (0, 1, 0, 1, 0, 1))
    assert changes_nothing(params) and options.limits == (0, 1, 0, 1, 0, 1)


# -- the plugin class with mocked OctoPrint ------------------------------------------------

@pytest.fixture
def plugin(tmp_path):
    return mocked_plugin(str(tmp_path))


def test_settings_save_applies_and_rejects(plugin):
    plugin.on_settings_save({"enabled": True,
                             "params": {"squareness_um_per_m": {"xy": 500.0}}})
    assert plugin.queue.enabled and plugin.queue.params.squareness_um_per_m["xy"] == 500.0
    plugin._event_bus.fire.assert_called()
    assert plugin._event_bus.fire.call_args[0][0] == "plugin_kincomp_params_applied"
    before = plugin._settings.get(["params"])
    plugin.on_settings_save({"params": {"squareness_um_per_m": {"xy": "lots"}}})
    assert plugin._settings.get(["params"]) == before  # kept, not silently dropped
    msg = plugin._plugin_manager.send_plugin_message.call_args[0][1]
    assert msg["severity"] == "error" and "squareness_um_per_m.xy" in msg["text"]


def test_before_request_hook_answers_400_for_bad_settings(plugin):
    import flask
    import flask_babel

    app = flask.Flask("t")
    flask_babel.Babel(app)
    body = {"plugins": {"kincomp": {"limits_policy": "explode"}}}
    with app.test_request_context("/api/settings", method="POST", json=body):
        with mock.patch("octoprint_kincomp.plugin.settings_store.Permissions") as perms:
            perms.SETTINGS.can.return_value = True
            resp = plugin.store.check_settings_request()
    assert resp.status_code == 400 and b"limits_policy" in resp.get_data()
    ok = {"plugins": {"kincomp": {"limits_policy": "clamp"}}}
    with app.test_request_context("/api/settings", method="POST", json=ok):
        with mock.patch("octoprint_kincomp.plugin.settings_store.Permissions") as perms:
            perms.SETTINGS.can.return_value = True
            assert plugin.store.check_settings_request() is None


def test_compensation_error_pauses_the_print(plugin):
    plugin.queue.on_error("G1 X0", LimitError("outside", 3))
    plugin._printer.pause_print.assert_called_once()
    msg = plugin._plugin_manager.send_plugin_message.call_args[0][1]
    assert msg["severity"] == "error" and "paused" in msg["text"]


def test_preprocessor_compensates_uploads_in_on_upload_mode(plugin, tmp_path):
    plugin.on_settings_save({"enabled": True, "mode": "on_upload",
                             "params": {"squareness_um_per_m": {"xy": 1000.0}}})
    src = b"G28\nG1 X10 Y50 Z1 F3000 ; first\nM104 S200\n"
    fo = mock.MagicMock()
    fo.filename = "part.gcode"
    fo.stream.return_value = io.BytesIO(src)
    with mock.patch("octoprint_kincomp.plugin.files_api.valid_file_type", return_value=True):
        wrapped = plugin.preprocessor_hook("part.gcode", fo)
    out = wrapped.stream().read().decode()
    lines = out.splitlines()
    assert lines[0].startswith("; kincomp: compensated params=")
    assert lines[1] == "G28" and lines[2].startswith("G1 X9.950 Y50.000") and \
        lines[2].endswith("; first")
    assert lines[3] == "M104 S200"
    # an already compensated upload goes through untouched
    fo.stream.return_value = io.BytesIO(out.encode())
    with mock.patch("octoprint_kincomp.plugin.files_api.valid_file_type", return_value=True):
        again = plugin.preprocessor_hook("part.gcode", fo).stream().read().decode()
    assert again == out


def test_hook_registration_runs_last():
    from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin, plugin_hooks

    hooks = plugin_hooks(KinCompPlugin())
    cb, order = hooks["octoprint.comm.protocol.gcode.queuing"]
    assert order >= 10000
    perms = hooks["octoprint.access.permissions"]()
    assert perms[0]["key"] == "ADMIN" and perms[0]["default_groups"] == ["admins"]
    assert ("POST", r"/trace", 16 * 1024 * 1024) in hooks["octoprint.server.http.bodysize"]([])


def test_print_events_drive_the_state(plugin, tmp_path):
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    marked = tmp_path / "m.gcode"
    marked.write_text("; kincomp: compensated params=abcdef012345 kincomp=0\nG28\n")
    plugin._file_manager.path_on_disk.return_value = str(marked)
    plugin.on_event("PrintStarted", {"origin": "local", "path": "m.gcode"})
    assert plugin.queue.skip_file and plugin.queue.printing
    assert "other KinComp parameters" in \
        plugin._plugin_manager.send_plugin_message.call_args[0][1]["text"]
    plugin.on_event("PrintDone", {})
    assert not plugin.queue.printing and not plugin.queue.skip_file


def test_firmware_conflict_is_reported_once(plugin):
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    plugin._plugin_manager.send_plugin_message.reset_mock()
    plugin.received_hook(None, "echo:  M852 I0.0010 J0.0000 K0.0000")
    plugin.received_hook(None, "echo:  M852 I0.0010 J0.0000 K0.0000")
    texts = [c[0][1]["text"] for c in plugin._plugin_manager.send_plugin_message.call_args_list]
    assert sum("compensates skew too" in t for t in texts) == 1


def test_print_state_is_set_up_by_the_first_file_line(plugin, tmp_path):
    """PRINT_STARTED arrives on the event thread, possibly after the first lines were
    queued: the queuing hook itself must notice the print, or a pre-compensated file's
    first moves would be compensated twice."""
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    comm = object()
    plugin.queuing_hook(comm, "queuing", "G28", None, "G28", tags={"source:api"})
    marked = tmp_path / "m.gcode"
    marked.write_text(f"; kincomp: compensated params={plugin.queue.params.hash()} "
                      "kincomp=0\nG1 X10 Y50\n")
    plugin._file_manager.path_on_disk.return_value = str(marked)
    plugin._printer.get_current_job.return_value = {
        "file": {"origin": "local", "path": "m.gcode"}}
    tags = {"source:file", "fileline:1", "filepos:60"}
    assert plugin.queuing_hook(comm, "queuing", "G1 X10 Y50", None, "G1", tags=tags) is None
    assert plugin.queue.printing and plugin.queue.skip_file
    # the late event changes nothing
    plugin.on_event("PrintStarted", {"origin": "local", "path": "m.gcode"})
    assert plugin.queue.skip_file
    plugin.on_event("PrintDone", {})
    assert not plugin.queue.printing


def test_new_connection_forgets_positions_synchronously(plugin):
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    first, second = object(), object()
    plugin.queuing_hook(first, "queuing", "G28", None, "G28", tags={"source:api"})
    assert plugin.queuing_hook(first, "queuing", "G1 X10 Y50", None, "G1") is not None
    assert plugin.queue.comp.known == (True, True, True)
    plugin._plugin_manager.send_plugin_message.reset_mock()
    # reconnected (a new comm object): the position is unknown until homed again; an X-only
    # move (its correction needs Y) goes out as written, and that is reported, not silent
    assert plugin.queuing_hook(second, "queuing", "G1 X10", None, "G1") is None
    assert plugin.queue.comp.known == (True, False, False)
    texts = [c[0][1]["text"] for c in plugin._plugin_manager.send_plugin_message.call_args_list]
    assert any("uncompensated because the printer's position is unknown" in t for t in texts)


def _printing_plain_file(plugin, tmp_path, job=True):
    """The printer's current job is a local file without KinComp's marker."""
    plain = tmp_path / "p.gcode"
    plain.write_text("G28\n")
    plugin._file_manager.path_on_disk.return_value = str(plain)
    if job:
        plugin._printer.get_current_job.return_value = {"file": {"origin": "local",
                                                                 "path": "p.gcode"}}


def test_print_start_is_counted_once_whichever_comes_first(plugin, tmp_path):
    """PRINT_STARTED before or after the first file line: one print begins; a PrintDone of
    the previous print that arrives after the next print's first line is ignored."""
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    _printing_plain_file(plugin, tmp_path)
    comm = object()
    line = {"source:file", "fileline:1"}
    # print A: the event first, then its first line
    plugin.on_event("PrintStarted", {"origin": "local", "path": "p.gcode"})
    plugin.queuing_hook(comm, "queuing", "G28", None, "G28", tags=line)
    plugin.queuing_hook(comm, "queuing", "G1 X10 Y10", None, "G1",
                        tags={"source:file", "fileline:2"})
    assert plugin.prints.begun == 1 and plugin.queue.comp.known == (True, True, True)
    # print B starts before A's PrintDone is processed
    plugin.queuing_hook(comm, "queuing", "G28", None, "G28", tags=line)
    assert plugin.prints.begun == 2
    plugin.on_event("PrintDone", {"origin": "local", "path": "p.gcode"})  # A's, late
    assert plugin.queue.printing and plugin.queue.comp.known == (True, True, True)
    plugin.on_event("PrintStarted", {"origin": "local", "path": "p.gcode"})  # B's
    assert plugin.prints.begun == 2
    plugin.on_event("PrintDone", {"origin": "local", "path": "p.gcode"})  # B's
    assert not plugin.queue.printing


def test_print_start_race_between_the_hook_and_the_event_thread(plugin, tmp_path):
    """The first file line (file reader thread) and PRINT_STARTED (event thread) at the same
    moment: one print begins, not two. Two would leave every later end event looking like a
    late one, so the print would never end for KinComp: background jobs stay paused and the
    demo never simulates its trace (what CI saw)."""
    import threading
    import time

    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict(),
                             "mode": "background"})
    _printing_plain_file(plugin, tmp_path, job=False)
    in_lookup = threading.Event()

    def slow_job():  # the hook is between its check and its action for 0.3 s
        in_lookup.set()
        time.sleep(0.3)
        return {"file": {"origin": "local", "path": "p.gcode"}}

    plugin._printer.get_current_job.side_effect = slow_job
    hook = threading.Thread(target=plugin.queuing_hook,
                            args=(object(), "queuing", "G28", None, "G28"),
                            kwargs={"tags": {"source:file", "fileline:1"}})
    hook.start()
    assert in_lookup.wait(5)
    plugin.on_event("PrintStarted", {"origin": "local", "path": "p.gcode"})
    hook.join(5)
    assert plugin.prints.begun == 1 and plugin.jobs.paused
    plugin.on_event("PrintDone", {"origin": "local", "path": "p.gcode"})
    assert not plugin.queue.printing and not plugin.jobs.paused


def test_switching_on_mid_print_waits_for_the_next_print_unless_forced():
    """Turning compensation on (or off) in the middle of a print would shift every later
    move by the correction; like new parameters it waits for the next print."""
    q = QueueCompensator(SKEW, Options(), enabled=False)
    q.print_started(False)
    new = Params.from_dict({"squareness_um_per_m": {"xy": -500.0}})
    assert q.configure(new, Options(), True, immediately=False) is False
    assert q.status()["pending_enabled"] is True
    f = {"source:file"}
    q.handle("G28", f)
    assert q.handle("G1 X10 Y50 Z1", f) is None  # still off, and not with the old params
    q.print_ended()
    assert q.enabled and q.params.hash() == new.hash() and q.pending is None
    # switching off waits too; forcing applies at once
    q.print_started(False)
    assert q.configure(new, Options(), False, immediately=False) is False and q.enabled
    assert q.configure(new, Options(), True, immediately=False) is True  # back to as-is
    assert q.pending is None
    assert q.configure(new, Options(), False, immediately=True) is True and not q.enabled


def test_plugin_enables_only_at_the_next_print(plugin):
    plugin._printer.get_current_job.return_value = {"file": {"origin": "local",
                                                             "path": "p.gcode"}}
    plugin._file_manager.path_on_disk.return_value = "/nonexistent"
    plugin.on_event("PrintStarted", {"origin": "local", "path": "p.gcode"})
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    assert not plugin.queue.enabled and plugin.queue.status()["pending_enabled"] is True
    plugin.on_event("PrintDone", {"origin": "local", "path": "p.gcode"})
    assert plugin.queue.enabled and plugin.queue.params.hash() == SKEW.hash()


def test_limits_follow_the_printer_profile(plugin):
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    assert plugin.queue.comp.options.limits == (0.0, 200.0, 0.0, 200.0, 0.0, 200.0)
    plugin._printer_profile_manager.get_current_or_default.return_value = {
        "volume": {"width": 300, "depth": 250, "height": 400, "origin": "center"}}
    plugin.on_event("PrinterProfileModified", {"identifier": "_default"})
    assert plugin.queue.comp.options.limits == (-150.0, 150.0, -125.0, 125.0, 0.0, 400.0)
    plugin._printer_profile_manager.get_current_or_default.return_value = {
        "volume": {"width": 220, "depth": 220, "height": 250, "origin": "lowerleft"}}
    plugin.on_event("Connected", {"port": "VIRTUAL"})
    assert plugin.queue.comp.options.limits == (0.0, 220.0, 0.0, 220.0, 0.0, 250.0)


def test_a_failing_notification_never_lets_the_raw_move_out():
    def boom(*args):
        raise RuntimeError("notification failed")

    q = QueueCompensator(Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
                         Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
                         enabled=True, on_error=boom, on_untouched=boom)
    assert q.handle("G1 X5") is None  # unknown position: sent as written, as reported
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") == []  # refused, and still refused


def test_request_flags_must_be_booleans(plugin):
    app = api_app()
    with mock.patch("octoprint_kincomp.plugin.http.require"):
        for path, view, body in (("/settings", plugin.api_settings, {"apply_now": "false"}),
                                 ("/program", plugin.api_program, {"print": "no"}),
                                 ("/apply", plugin.api_apply, {"params": {},
                                                               "apply_now": 1})):
            with app.test_request_context(path, method="POST", json=body):
                resp = view()
            assert resp.status_code == 400 and b"must be true or false" in resp.data, path


def test_an_end_event_with_nothing_printing_always_ends_the_print(plugin, tmp_path):
    """Should the start/end counts ever drift (a print begun by the hook whose start event
    never came), the next end event with nothing printing still ends the print."""
    _printing_plain_file(plugin, tmp_path)
    plugin.queuing_hook(object(), "queuing", "G28", None, "G28",
                        tags={"source:file", "fileline:1"})
    plugin.prints.begun += 1  # drifted
    plugin._printer.is_printing.return_value = False
    plugin.on_event("PrintFailed", {"origin": "local", "path": "p.gcode"})
    assert not plugin.queue.printing and not plugin.jobs.paused
    assert plugin.prints.start_events == plugin.prints.begun


def test_marlin_is_asked_for_its_settings_after_m115(plugin):
    plugin.on_event("FirmwareData", {"name": "Marlin 2.1.2", "data": {}})
    (args, kwargs), = plugin._printer.commands.call_args_list
    assert args[0] == ["M503"] and "plugin:kincomp" in kwargs["tags"]
    plugin._printer.commands.reset_mock()
    plugin.on_event("FirmwareData", {"name": "Klipper", "data": {}})
    assert not plugin._printer.commands.called
    # the conflict notice names what is compensated twice, translatable in the browser
    plugin.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    plugin._plugin_manager.send_plugin_message.reset_mock()
    plugin.received_hook(None, "echo:  M425 F1.00 X0.05 Y0.00 Z0.00")
    (_, msg), _ = plugin._plugin_manager.send_plugin_message.call_args
    assert msg["params"]["kind"] == "backlash" and msg["translate"] == ["kind"]


def test_a_runs_measurement_file_can_be_downloaded(plugin, tmp_path):
    run_id = plugin.runs.new_id()
    plugin.runs.save({"id": run_id, "filename": "../../etc/passwd trace.csv",
                      "diagnostics": {}})
    plugin.runs.save_trace(run_id, b"direction,angle_deg,deviation_um\nccw,0,1.5\n")
    app = api_app()
    with mock.patch("octoprint_kincomp.plugin.http.require"):
        with app.test_request_context(f"/runs/{run_id}/trace"):
            resp = plugin.api_run_trace(run_id)
            resp.direct_passthrough = False
            assert resp.status_code == 200 and b"ccw,0,1.5" in resp.get_data()
            assert "attachment" in resp.headers["Content-Disposition"]
            assert "/" not in resp.headers["Content-Disposition"].split("filename=")[1]
        with app.test_request_context("/runs/x/trace"):
            assert plugin.api_run_trace("../../etc/passwd").status_code == 404
    assert [r["has_trace"] for r in plugin.runs.list()] == [True]


def test_unusable_stored_settings_are_reported_not_just_logged(plugin):
    plugin._settings.set(["limits_policy"], "explode")  # e.g. edited by hand in config.yaml
    assert plugin.store.current()["limits_policy"] == "warn"  # the defaults apply
    app = api_app()
    with mock.patch("octoprint_kincomp.plugin.http.require"):
        with app.test_request_context("/status"):
            body = plugin.api_status().get_json()
    assert body["settings_problem"].startswith("limits_policy: must be one of")


def test_a_line_sent_as_written_after_an_error_forgets_the_position():
    """With "send as written on error" the refused line does go out: the head is where the
    program put it, not where the compensator left it (review finding: the next Y-only move
    drove X back by 100 mm)."""
    q = QueueCompensator(Params.from_dict({"squareness_um_per_m": {"xy": 1000}}),
                         Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
                         enabled=True, pass_through_on_error=True)
    for cmd in ("G28", "G1 X100 Y100 Z1"):
        q.handle(cmd, {"source:file"})
    assert q.handle("G1 X0.05 Y150", {"source:file"}) is None  # sent as written
    assert q.comp.known == (False, False, False)
    assert q.handle("G1 Y160", {"source:file"}) is None  # no X move the program never made


def test_a_late_end_event_does_not_end_a_paused_next_print(plugin, tmp_path):
    _printing_plain_file(plugin, tmp_path)
    comm = object()
    line = {"source:file", "fileline:1"}
    plugin.on_event("PrintStarted", {"origin": "local", "path": "p.gcode"})  # print A
    plugin.queuing_hook(comm, "queuing", "G28", None, "G28", tags=line)
    plugin.queuing_hook(comm, "queuing", "G28", None, "G28", tags=line)  # print B begins
    plugin._printer.is_printing.return_value = False  # B is paused already
    plugin._printer.is_paused.return_value = True
    plugin.on_event("PrintDone", {"origin": "local", "path": "p.gcode"})  # A's, late
    assert plugin.queue.printing
