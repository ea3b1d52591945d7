"""SettingsStore on a real OctoPrint settings object (config.yaml in a temporary basedir):
migration of old stored settings, saving (the params document replaced whole, the
params_applied event), applying now or from the next print on, and the printer profile's
limits."""

import os
from types import SimpleNamespace
from unittest import mock

import yaml
from octoprint.plugin import PluginSettings
from octoprint.settings import Settings

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.plugin.settings.settings_store import SettingsStore
from octoprint_kincomp.service.notify import Notifier
from octoprint_kincomp.service.printing.queue import QueueCompensator
from octoprint_kincomp.service.settings.schema import SETTINGS_VERSION, defaults, validate_settings

BED = {
    "volume": {"width": 200, "depth": 200, "height": 200, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 5000}, "z": {"speed": 200}},
}


def make_store(tmp_path, stored=None):
    """A store whose config.yaml holds ``stored`` for KinComp (as written by an older
    version, say); the current profile is a 200 mm bed."""
    basedir = str(tmp_path / "base")
    os.makedirs(basedir, exist_ok=True)
    if stored is not None:
        with open(os.path.join(basedir, "config.yaml"), "w") as f:
            yaml.safe_dump({"plugins": {"kincomp": stored}}, f)
    settings = PluginSettings(Settings(basedir=basedir), "kincomp", defaults=defaults())
    queue = QueueCompensator(Params(), Options())
    plugin_manager, event_bus, profiles = mock.MagicMock(), mock.MagicMock(), mock.MagicMock()
    profiles.get_current_or_default.return_value = BED
    applied = []
    store = SettingsStore(
        settings,
        "kincomp",
        profiles,
        queue,
        Notifier(plugin_manager, event_bus, "kincomp"),
        mock.MagicMock(),
        on_applied=applied.append,
    )
    return SimpleNamespace(
        store=store,
        settings=settings,
        queue=queue,
        profiles=profiles,
        plugin_manager=plugin_manager,
        event_bus=event_bus,
        applied=applied,
    )


def sent(t):
    return [c[0][1] for c in t.plugin_manager.send_plugin_message.call_args_list]


def test_migration_moves_flat_keys_into_params_and_drops_unknown_ones(tmp_path):
    t = make_store(tmp_path, {"enabled": True, "skew_xy": 250.0, "scale_x": -100.0, "obsolete": 3})
    t.store.migrate(SETTINGS_VERSION, None)
    raw = t.settings.get_all_data(merged=False)
    assert "obsolete" not in raw and raw["params"]["squareness_um_per_m"]["xy"] == 250.0
    s = t.store.current()
    assert s["enabled"] is True and s["params"]["squareness_um_per_m"]["xy"] == 250.0
    assert s["params"]["scale_ppm"]["x"] == -100.0 and t.store.problem is None


def test_migration_of_unusable_settings_keeps_the_defaults_and_says_why(tmp_path):
    t = make_store(tmp_path, {"enabled": True, "limits_policy": "explode"})
    t.store.migrate(SETTINGS_VERSION, None)
    assert t.store.current() == defaults()
    assert str(t.store.problem).startswith("limits_policy: must be one of")


def test_nothing_stored_or_current_version_migrates_nothing(tmp_path):
    t = make_store(tmp_path)
    t.store.migrate(SETTINGS_VERSION, None)
    assert t.store.current() == defaults() and t.store.problem is None
    t = make_store(tmp_path / "b", {"skew_xy": 250.0})
    t.store.migrate(SETTINGS_VERSION, SETTINGS_VERSION)
    assert t.settings.get_all_data(merged=False) == {"skew_xy": 250.0}


def test_saving_replaces_the_params_document_and_reports_the_change(tmp_path):
    t = make_store(tmp_path)
    first = validate_settings(
        {
            "enabled": True,
            "params": {"squareness_um_per_m": {"xy": 500.0}, "servo_lag_ms": {"x": 0.5}},
        }
    )
    t.store.save(first)
    assert t.store.current()["params"]["servo_lag_ms"]["x"] == 0.5
    assert t.queue.enabled and t.queue.params.hash() == Params.from_dict(first["params"]).hash()
    name, payload = t.event_bus.fire.call_args[0]
    assert name == "plugin_kincomp_params_applied"
    assert payload["pending_until_next_print"] is False
    assert payload["previous_hash"] == Params().hash()
    # a complete document without the optional term: the stored one loses it too
    second = validate_settings(
        {"params": {"squareness_um_per_m": {"xy": 400.0}}}, first, replace_params=True
    )
    t.store.save(second)
    assert "servo_lag_ms" not in t.store.current()["params"]
    assert t.applied == [first, second]
    # the same parameters again: no event
    t.event_bus.fire.reset_mock()
    t.store.save(dict(second, chord_tol_mm=0.02))
    assert not t.event_bus.fire.called


def test_changes_wait_for_the_next_print_unless_asked_for_now(tmp_path):
    t = make_store(tmp_path)
    t.queue.print_started(False)
    new = validate_settings({"enabled": True, "params": {"scale_ppm": {"x": 100.0}}})
    t.store.save(new)
    assert not t.queue.enabled and t.queue.pending is not None
    assert t.event_bus.fire.call_args[0][1]["pending_until_next_print"] is True
    assert sent(t)[-1]["severity"] == "info" and "next print" in sent(t)[-1]["text"]
    t.store.apply(dict(new, apply_changes="immediately"))
    assert t.queue.enabled and t.queue.pending is None


def test_refused_dialog_settings_change_nothing(tmp_path):
    t = make_store(tmp_path)
    assert t.store.dialog_save({"decimals": 9}) == {}
    assert t.store.current() == defaults() and not t.applied
    msg = sent(t)[-1]
    assert msg["severity"] == "error" and msg["params"]["reason"]["params"]


def test_limits_and_feeds_come_from_the_printer_profile(tmp_path):
    t = make_store(tmp_path)
    assert t.store.limits() == (0.0, 200.0, 0.0, 200.0, 0.0, 200.0)
    assert t.store.max_feeds() == {"x": 6000.0, "y": 5000.0, "z": 200.0}
    other = {"volume": {"width": 300, "depth": 100, "height": 50, "origin": "center"}}
    _, options = t.store.engine_config(defaults(), other)
    assert options.limits == (-150.0, 150.0, -50.0, 50.0, 0.0, 50.0)
    _, options = t.store.engine_config(defaults())
    assert options.limits == (0.0, 200.0, 0.0, 200.0, 0.0, 200.0)
    t.profiles.get_current_or_default.side_effect = RuntimeError("no profile")
    assert t.store.limits() is None and t.store.max_feeds() is None
    assert t.store.upload_fields() == ("path", "name")
