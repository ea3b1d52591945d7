"""Issue 26, cases 2, 3, 6 and 7: one schema for every way settings come in (API bodies,
OctoPrint's settings dialog, config.yaml at start-up). A wrong type or value anywhere is a
SettingsError naming the field (never a TypeError or an OverflowError: those were 500s);
stored, it shows as the settings problem with its field, turns compensation off with a
notification, and the API and the settings dialog can repair it; no endpoint answers 500
meanwhile."""

import copy
import json
import os

import pytest
import yaml

from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.export import equivalents
from octoprint_kincomp.service.settings.schema import (
    CHECKS,
    SettingsError,
    defaults,
    engine_config,
    repaired,
    validate_settings,
)
from tests.support.blueprint import PREFIX, blueprint_client

BAD = [
    None,
    True,
    "1",
    "x",
    "\u0661\u0662\u0663",
    [1],
    ["mm"],
    {"a": 1},
    [[[[]]]],
    -1,
    0,
    1e308,
    -1e308,
    1e-310,
    float("nan"),
    float("inf"),
    10**30,
    "",
    {},
]


def _paths(doc, prefix=()):
    for key, value in doc.items():
        yield prefix + (key,)
        if isinstance(value, dict):
            yield from _paths(value, prefix + (key,))


def _with(doc, path, value):
    out = copy.deepcopy(doc)
    at = out
    for key in path[:-1]:
        at = at[key]
    at[path[-1]] = value
    return out


def test_every_setting_has_its_check():
    assert set(CHECKS) == set(defaults())


def test_any_value_anywhere_is_checked_or_refused_naming_its_field():
    base = defaults()
    base["params"]["backlash"].update(x=45.0, smoothing_mm=2.0)
    base["sensor"]["protocol"] = "pattern"
    base["sensor"]["pattern"] = r"(?P<value>\S+)"
    tried = 0
    for path in _paths(base):
        for bad in BAD:
            doc = _with(base, path, bad)
            tried += 1
            try:
                s = validate_settings(doc, defaults())
            except SettingsError as exc:
                assert exc.field.split(".")[0].split("[")[0] == path[0], (path, bad, exc)
                view, problems = repaired(doc)  # the settings page's view of it
                assert problems and validate_settings(view, defaults()) == view
                continue
            # accepted: it is a valid value, and everything derived from it works
            params, _ = engine_config(s, None)
            equivalents(params)
            assert validate_settings(s, defaults()) == s
    assert tried > 800  # (44 fields x 19 values)


@pytest.mark.parametrize(
    "body, field",
    [
        ({"sensor": {"units": [1]}}, "sensor.units"),
        ({"sensor": {"units": ["mm"]}}, "sensor.units"),
        ({"sensor": {"positive": {"a": 1}}}, "sensor.positive"),
        ({"sensor": {"protocol": ["pattern"]}}, "sensor.protocol"),
        ({"sensor": {"scale": True}}, "sensor.scale"),
        ({"sensor": {"scale": "1"}}, "sensor.scale"),
        ({"sensor": {"scale": 1e308}}, "sensor.scale"),
        ({"sensor": {"baudrate": "9600"}}, "sensor.baudrate"),
        ({"params": "garbage"}, "params"),
        ({"params": {"backlash": {"fraction": 1.5}}}, "params.backlash.fraction"),
        ({"demo": []}, "demo"),
    ],
)
def test_wrong_types_are_refused_naming_the_field(body, field):
    with pytest.raises(SettingsError) as exc:
        validate_settings(body, defaults())
    assert exc.value.field == field


CALIBRATED = {
    "enabled": True,
    "params": {
        "squareness_um_per_m": {"xy": 250.0},
        "scale_ppm": {"x": 350.0},
        "backlash": {"x": 45.0},
    },
}


def _stored(config):
    with open(config) as f:
        return ((yaml.safe_load(f) or {}).get("plugins") or {}).get("kincomp")


GETS = [
    "/status",
    "/runs",
    "/files",
    "/sensor/status",
    "/sensor/ports",
    "/campaigns",
    "/demo/trace",
    "/dryrun?path=ok.gcode",
    "/compare?before=x&after=y",
]


@pytest.mark.parametrize(
    "bad, field",
    [
        ({"sensor": {"units": ["mm"]}}, "sensor.units"),
        ({"params": "garbage"}, "params"),
        (
            {"params": {"backlash": {"x": 45.0, "fraction": "1", "smoothing_mm": 2.0}}},
            "params.backlash.fraction",
        ),
        ({"sensor": {"scale": True}}, "sensor.scale"),
        ({"decimals": [4]}, "decimals"),
        ({"software_update": "x"}, "software_update"),
    ],
)
def test_a_wrong_stored_value_is_reported_and_can_be_repaired(tmp_path, bad, field):
    stored = dict(copy.deepcopy(CALIBRATED), **bad)
    if "params" not in bad:
        pass
    elif isinstance(bad["params"], dict):
        stored["params"] = dict(CALIBRATED["params"], **bad["params"])
    ns = blueprint_client(str(tmp_path), stored=stored)
    config = os.path.join(str(tmp_path), "base", "config.yaml")
    with open(os.path.join(ns.uploads, "ok.gcode"), "w") as f:
        f.write("G28\nG1 X10 Y10 Z1 F3000\n")
    try:
        plugin, client = ns.plugin, ns.client
        for path in GETS:  # nothing stored makes an endpoint fail
            assert client.get(PREFIX + path).status_code < 500, path
        st = client.get(PREFIX + "/status").get_json()
        assert st["settings_problem_field"] == field, st["settings_problem"]
        assert st["compensation"]["enabled"] is False and not plugin.queue.enabled
        texts = [
            c[0][1].get("text", "")
            for c in plugin._plugin_manager.send_plugin_message.call_args_list
        ]
        assert any("compensation is off" in t for t in texts)  # loudly, not silently
        assert _stored(config) == stored  # nothing rewritten behind the user's back
        # a save that does not fix it is refused, naming the field; nothing changes
        resp = client.post(
            PREFIX + "/settings",
            data=json.dumps({"chord_tol_mm": 0.02}),
            content_type="application/json",
        )
        assert resp.status_code == 400 and field in resp.get_json()["error"]
        assert _stored(config) == stored
        # the settings page sends the field fixed (as the form shows it: its default)
        fix = {field.split(".")[0]: copy.deepcopy(defaults()[field.split(".")[0]])}
        if field.startswith("params"):
            fix["params"] = (
                {"backlash": {"fraction": 1.0}}
                if "fraction" in field
                else dict(CALIBRATED["params"])
            )
        plugin.on_settings_save(fix)
        st = client.get(PREFIX + "/status").get_json()
        assert st["settings_problem"] is None, st["settings_problem"]
        assert st["compensation"]["enabled"] is True
        if "garbage" not in json.dumps(bad):
            assert Params.from_dict(st["settings"]["params"]).backlash["x"].points[0][1] == 45.0
    finally:
        ns.stop()


def test_the_api_repairs_a_wrong_stored_value(tmp_path):
    stored = dict(copy.deepcopy(CALIBRATED), sensor={"units": ["mm"], "port": "/dev/ttyX"})
    ns = blueprint_client(str(tmp_path), stored=stored)
    try:
        resp = ns.client.post(
            PREFIX + "/settings",
            data=json.dumps({"sensor": {"units": "um"}}),
            content_type="application/json",
        )
        assert resp.status_code == 200, resp.get_json()
        s = resp.get_json()["settings"]
        assert s["sensor"]["units"] == "um" and s["sensor"]["port"] == "/dev/ttyX"
        assert s["params"]["scale_ppm"]["x"] == 350.0 and s["enabled"] is True
        assert ns.plugin.queue.enabled
    finally:
        ns.stop()


def test_a_tiny_stored_value_breaks_nothing(tmp_path):
    """``backlash.fraction: 1e-310`` (accepted: finite, within 0..1) made every /status a
    500 (OverflowError in the firmware equivalents), restart included."""
    stored = {
        "enabled": True,
        "params": {"backlash": {"x": 45.0, "fraction": 1e-310, "smoothing_mm": 2.0}},
    }
    ns = blueprint_client(str(tmp_path), stored=stored)
    try:
        for path in GETS:
            assert ns.client.get(PREFIX + path).status_code < 500, path
        st = ns.client.get(PREFIX + "/status").get_json()
        assert st["settings_problem"] is None and st["compensation"]["enabled"] is True
        assert "M425" in " ".join(st["equivalents"]["reprapfirmware"])
    finally:
        ns.stop()


def test_a_lone_surrogate_is_refused_and_the_next_save_still_works(tmp_path):
    """JSON's "\\ud800" makes a text no config.yaml can hold: its write failed (500) and
    left the value in memory, so every later save failed too."""
    ns = blueprint_client(str(tmp_path), stored=CALIBRATED)
    config = os.path.join(str(tmp_path), "base", "config.yaml")
    try:
        before = _stored(config)
        for body in ('{"sensor": {"port": "\\ud800"}}', '{"sensor": {"\\ud800": 1}}'):
            resp = ns.client.post(PREFIX + "/settings", data=body, content_type="application/json")
            assert resp.status_code == 400 and "surrogate" in resp.get_json()["error"]
        assert _stored(config) == before
        resp = ns.client.post(
            PREFIX + "/settings", data=json.dumps({"decimals": 5}), content_type="application/json"
        )
        assert resp.status_code == 200 and _stored(config)["decimals"] == 5
    finally:
        ns.stop()
