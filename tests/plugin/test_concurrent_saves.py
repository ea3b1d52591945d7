"""Issue 26, case 1: saves at the same time never erase a calibration.

A calibration is applied, then unrelated partial saves run at the same time through both
ways a save arrives: KinComp's ``POST /settings`` (the real blueprint in a Flask test app)
and OctoPrint's settings endpoint (``on_settings_save`` followed by OctoPrint's write of
config.yaml, as ``/api/settings`` does it). After every trial the calibration must still
be in the stored settings, in config.yaml on disk and in the live compensator, and each
save's own key must have arrived. (The real-server version: tests/e2e/test_settings_races.py.)
"""

import json
import os
import threading

import pytest
import yaml

from octoprint_kincomp.core.params import Params
from tests.support.blueprint import PREFIX, blueprint_client

TRIALS = 200
CALIBRATION = {
    "squareness_um_per_m": {"xy": 420.0, "xz": -130.0, "yz": 75.0},
    "scale_ppm": {"x": 310.0, "y": -120.0, "z": 0.0},
    "backlash": {"x": 45.0, "y": 30.0, "z": 0.0},
    "servo_lag_ms": {"x": 0.5, "y": 0.0, "z": 0.0},
    "servo_precomp": True,
}


def _on_disk(config):
    with open(config) as f:
        return ((yaml.safe_load(f) or {}).get("plugins") or {}).get("kincomp") or {}


def _calibrated(tmp_path):
    """A plugin (and its config.yaml path) with CALIBRATION applied through the API."""
    ns = blueprint_client(str(tmp_path))
    try:
        resp = ns.client.post(
            PREFIX + "/apply",
            data=json.dumps({"params": CALIBRATION, "enabled": True, "apply_now": True}),
            content_type="application/json",
        )
        assert resp.status_code == 200, resp.get_json()
    except BaseException:
        ns.stop()
        raise
    return ns, os.path.join(str(tmp_path), "base", "config.yaml")


def test_concurrent_partial_saves_keep_the_calibration(tmp_path):
    ns, config = _calibrated(tmp_path)
    try:
        plugin, client = ns.plugin, ns.client
        want = Params.from_dict(CALIBRATION).hash()
        assert plugin.queue.params.hash() == want
        failures = []
        for trial in range(TRIALS):
            decimals = 3 + trial % 4
            chord = round(0.001 * (1 + trial % 50), 3)
            barrier = threading.Barrier(3)
            codes = []

            def plugin_api(body):
                barrier.wait()
                r = client.post(
                    PREFIX + "/settings", data=json.dumps(body), content_type="application/json"
                )
                codes.append(r.status_code)

            def octoprint_api(body):
                barrier.wait()
                plugin.on_settings_save(body)  # OctoPrint's /api/settings: the plugin's part
                plugin._settings.save()  # ... then OctoPrint writes config.yaml

            threads = [
                threading.Thread(target=plugin_api, args=({"decimals": decimals},)),
                threading.Thread(target=plugin_api, args=({"chord_tol_mm": chord},)),
                threading.Thread(target=octoprint_api, args=({"demo": {"live": trial % 2 == 0}},)),
            ]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            s = plugin.store.current()
            disk = _on_disk(config)
            lost = []
            if codes != [200, 200]:
                lost.append(f"answers {codes}")
            if Params.from_dict(s["params"]).hash() != want:
                lost.append("stored params")
            if plugin.queue.params.hash() != want:
                lost.append("live compensator")
            if (
                disk.get("params", {}).get("squareness_um_per_m", {}).get("xy") != 420.0
                or disk.get("params", {}).get("servo_lag_ms", {}).get("x") != 0.5
            ):
                lost.append("config.yaml params")
            if (s["decimals"], s["chord_tol_mm"], s["demo"]["live"]) != (
                decimals,
                chord,
                trial % 2 == 0,
            ):
                lost.append(
                    (
                        "a save's own key",
                        (s["decimals"], s["chord_tol_mm"], s["demo"]["live"]),
                        (decimals, chord, trial % 2 == 0),
                    )
                )
            if not s["enabled"]:
                lost.append("enabled")
            if lost:
                failures.append((trial, lost))
        print(f"\n{TRIALS - len(failures)}/{TRIALS} concurrent-save trials kept everything")
        assert not failures, failures[:5]
    finally:
        ns.stop()


def test_a_failed_write_changes_nothing(tmp_path, monkeypatch):
    """Disk full while config.yaml is written: 507, the stored document (in memory, on disk
    and in the compensator) stays as it was."""
    import errno

    ns, config = _calibrated(tmp_path)
    try:
        plugin, client = ns.plugin, ns.client
        before, disk_before = plugin.store.current(), _on_disk(config)

        def full(*a, **kw):
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(plugin._settings.settings, "save", full)
        resp = client.post(
            PREFIX + "/settings",
            data=json.dumps({"decimals": 5, "params": {"scale_ppm": {"x": 0.0}}}),
            content_type="application/json",
        )
        assert resp.status_code == 507 and "disk is full" in resp.get_json()["error"]
        resp = client.post(
            PREFIX + "/apply", data=json.dumps({"params": {}}), content_type="application/json"
        )
        assert resp.status_code == 507
        assert plugin.store.current() == before and _on_disk(config) == disk_before
        assert plugin.queue.params.hash() == Params.from_dict(CALIBRATION).hash()
    finally:
        ns.stop()


def test_a_failed_write_on_octoprints_settings_path_leaves_nothing_in_force(tmp_path, monkeypatch):
    """Issue 37 row 8: POST /api/settings on a full disk answered 500 while the compensator
    already used the new parameters and config.yaml kept the old ones (the next unrelated
    save wrote them). Now the dialog's save writes first: nothing is in force that is not
    stored."""
    import errno

    ns, config = _calibrated(tmp_path)
    try:
        plugin = ns.plugin
        before, disk_before = plugin.store.current(), _on_disk(config)

        def full(*a, **kw):
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(plugin._settings.settings, "save", full)
        change = {"params": {"squareness_um_per_m": {"xy": 1234.0}}}
        with pytest.raises(OSError):  # (OctoPrint answers 500: its own write fails too)
            plugin.on_settings_save(change)
        assert plugin.store.current() == before and _on_disk(config) == disk_before
        assert plugin.queue.params.hash() == Params.from_dict(CALIBRATION).hash()
        monkeypatch.undo()
        plugin.on_settings_save({"decimals": 4})  # the next unrelated save
        assert plugin.store.current()["params"] == before["params"]
    finally:
        ns.stop()
