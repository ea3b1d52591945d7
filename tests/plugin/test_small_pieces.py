"""The small pieces of the plugin floor on their own: notifications, request helpers, the
firmware check, demo mode."""

from unittest import mock

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec
from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.messages import Msg
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.plugin import http
from octoprint_kincomp.service.calibration.demo_mode import DemoMode
from octoprint_kincomp.service.notify import Notifier
from octoprint_kincomp.service.printing.firmware_check import FirmwareCheck
from octoprint_kincomp.service.printing.firmware_watch import FirmwareWatcher
from octoprint_kincomp.service.printing.queue import QueueCompensator
from tests.support.mocked_plugin import api_app, wait_for

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}, "backlash": {"x": 20.0}})


def messages(plugin_manager):
    return [c[0][1] for c in plugin_manager.send_plugin_message.call_args_list]


# -- notify ---------------------------------------------------------------------------------


def test_a_notification_carries_its_message_id_parameters_and_english_text():
    pm, bus = mock.MagicMock(), mock.MagicMock()
    n = Notifier(pm, bus, "kincomp")
    n.notify(
        "warning",
        "%(kind)s at %(where)s",
        tr_params=("kind",),
        kind="skew",
        where=Msg("line %(n)s", n=3),
    )
    (ident, msg), _ = pm.send_plugin_message.call_args
    assert ident == "kincomp" and msg["type"] == "notify" and msg["severity"] == "warning"
    assert msg["msgid"] == "%(kind)s at %(where)s" and msg["translate"] == ["kind"]
    assert msg["params"]["where"] == {
        "text": "line 3",
        "template": "line %(n)s",
        "params": {"n": 3},
    }
    assert msg["text"] == "skew at line 3"
    n.notify("info", "100% done")  # no parameters: the text is the id, not %-formatted
    assert messages(pm)[-1]["text"] == "100% done"
    n.event("params_applied", {"params_hash": "x"})
    bus.fire.assert_called_once_with("plugin_kincomp_params_applied", {"params_hash": "x"})


# -- http -----------------------------------------------------------------------------------


def test_request_helpers():
    app = api_app()
    with app.test_request_context("/x", method="POST", json=[1, 2]):
        assert http.json_object() is None  # not an object
        resp = http.error("No such G-code file", 404)
        assert resp.status_code == 404 and resp.get_json() == {"error": "No such G-code file"}
    with app.test_request_context("/x", method="POST", json={"print": True, "no": "false"}):
        data = http.json_object()
        assert http.flag(data, "print") is True and http.flag(data, "absent") is False
        with pytest.raises(http.BadRequest, match="'no' must be true or false"):
            http.flag(data, "no")
        allowed, refused = mock.MagicMock(), mock.MagicMock()
        allowed.can.return_value, refused.can.return_value = True, False
        http.require(allowed)
        with pytest.raises(Exception) as exc:
            http.require(refused)
        assert getattr(exc.value, "code", None) == 403
        assert http.tr(ValueError("plain")) == "plain"
    eq = http.with_i18n({"notes": [Msg("note %(a)s", a=1)]})
    assert eq["notes_i18n"] == [{"text": "note 1", "template": "note %(a)s", "params": {"a": 1}}]
    (perm,) = http.permissions()
    assert perm["key"] == "ADMIN" and perm["dangerous"] and perm["roles"] == ["admin"]


# -- firmware check -------------------------------------------------------------------------


def firmware_check():
    queue = QueueCompensator(SKEW, Options(), enabled=True)
    printer, pm = mock.MagicMock(), mock.MagicMock()
    check = FirmwareCheck(
        FirmwareWatcher(), queue, printer, Notifier(pm, None, "kincomp"), mock.MagicMock()
    )
    return check, queue, printer, pm


def test_each_conflict_is_reported_once_and_only_with_compensation_on():
    check, queue, _, pm = firmware_check()
    queue.set_enabled(False)
    check.received("echo:  M425 F1.00 X0.05 Y0.00 Z0.00")
    assert messages(pm) == []
    queue.set_enabled(True)
    check.sent("M852 I0.002")
    check.received("ok")  # not about compensation: nothing happens
    check.sent("M852 I0.002")
    kinds = sorted(m["params"]["kind"]["text"] for m in messages(pm))
    assert kinds == ["backlash", "skew"]
    # the parameters do not say how they were measured: no "turn one of them off"
    assert all("keep both" in m["text"] for m in messages(pm))
    check.sent("M852 I0.003")  # another finding: said again
    assert len(messages(pm)) == 3


def test_only_marlin_is_asked_for_its_settings():
    check, _, printer, _ = firmware_check()
    check.query({"name": "RepRapFirmware"})
    check.query({})
    assert not printer.commands.called
    check.query({"name": "Marlin bugfix-2.1.x"})
    # (its soft endstops first: its M503 leaves them out)
    assert printer.commands.call_args[0][0] == ["M211", "M503"]
    printer.commands.side_effect = RuntimeError("not connected")
    check.query({"name": "Marlin"})  # logged, not raised


# -- demo mode ------------------------------------------------------------------------------


def test_demo_mode_records_only_the_program_it_wrote_and_simulates_when_done():
    pm = mock.MagicMock()
    demo = DemoMode(Notifier(pm, None, "kincomp"), mock.MagicMock())
    spec = TestSpec(plane="XY", centre=(110, 110, 10), radius_mm=50.0, feed_mm_min=1000.0)
    demo.program_written("kincomp/p.gcode", spec, "abc")
    demo.print_begins({"path": "kincomp/p.gcode"})  # off: nothing
    demo.record("G1 X1", None)
    assert demo.ballbar is None and demo.last_trace() is None
    demo.set_enabled(True)
    ballbar = demo.ballbar
    demo.set_enabled(True)
    assert demo.ballbar is ballbar  # kept while on
    demo.print_begins({"path": "other.gcode"})
    assert not ballbar.recording
    demo.print_begins({"path": "kincomp/p.gcode"})
    assert ballbar.recording
    demo.print_ends(False)  # failed or cancelled: dropped
    assert not ballbar.recording
    demo.print_begins({"path": "kincomp/p.gcode"})
    with mock.patch.object(ballbar, "finish", return_value="a trace") as finish:
        demo.print_ends(True)  # simulated on its own thread, then the UI is told
        wait_for(lambda: len(messages(pm)) == 2)
    finish.assert_called_once_with()
    assert [m["type"] for m in messages(pm)] == ["notify", "demo_trace"]
    assert "SIMULATED" in messages(pm)[0]["text"]
    demo.set_enabled(False)
    assert demo.ballbar is None
