"""End-to-end: a real OctoPrint (virtual printer) with KinComp, checked on serial.log."""

import json
import os
import time

import pytest
from octoprint.util.comm import strip_comment

from tests.support.serverutil import (
    AUTOMATIC,
    DATA,
    MOTION,
    marker,
    offline,
    sent,
    settings,
    status,
)

pytestmark = pytest.mark.slow

PARAMS = {
    "squareness_um_per_m": {"xy": 800.0, "xz": -300.0, "yz": 200.0},
    "scale_ppm": {"x": 500.0, "y": -400.0, "z": 0.0},
    "backlash": {"x": 30.0, "y": 25.0},
}


def _visible(cmds):
    return [c for c in cmds if c.split(" ", 1)[0] not in AUTOMATIC]


def _is_move(cmd):
    return cmd.split(" ", 1)[0].upper() in MOTION


def _file_commands(path):
    with open(path, encoding="utf-8") as f:
        lines = [strip_comment(l).strip() for l in f]
    return [l for l in lines if l]


def _print_file(server, name, data):
    """Upload and print; returns the marker sent just before (the print's Send: lines
    follow it)."""
    # the virtual printer sleeps 10% of each move's time; M220 (feed rate override, a
    # printer-side knob: it is not in the file and passes KinComp unchanged) speeds it up
    code, _ = server.request("POST", "/api/printer/command", {"commands": ["M220 S5000"]})
    assert code == 204
    start = marker(server)
    code, body = server.upload("/api/files/local", name, data, {"select": "true", "print": "true"})
    assert code == 201, body
    server.wait_print_done(timeout=1800)
    return start


def test_api_commands_and_jog_go_out_compensated_once(server):
    # commands queued at once: the M114 after G28 is answered only after all are queued, so
    # the home is given (the virtual printer homes at 0,0,0; the answer is tested in
    # test_reliability.py)
    settings(server, enabled=True, mode="on_the_fly", params=PARAMS, home_mm=[0.0, 0.0, 0.0])
    start = marker(server)
    commands = [
        "G90",
        "G21",
        "M82",
        "G28",
        "G1 Z5 F600",
        "G1 X50 Y60 F3000",
        "G0 X120 Y30",
        "g1 x80 y90",
        "G01 X60.5 Y70.25 E1.5",
        "G2 X80.5 Y70.25 I10 J0 F1200",
        "G91",
        "G1 X-5 Y5",
        "G1 Z-1",
        "G90",
        "M104 S0",
        "G92 X0",
        "G1 X10 F3000",
        "G92 X70.5",
        "M18",
    ]
    code, _ = server.request("POST", "/api/printer/command", {"commands": commands})
    assert code == 204
    code, _ = server.request("POST", "/api/printer/printhead", {"command": "jog", "x": 10, "y": -5})
    assert code == 204
    end = marker(server)
    _, profile = server.request("GET", "/api/printerprofiles/_default")
    speed = min(profile["axes"]["x"]["speed"], profile["axes"]["y"]["speed"])
    jog = ["G91", f"G0 X10 Y-5 F{speed}", "G90"]

    got = sent(server, after=start, until=end)
    want = offline(server, commands + jog)
    assert got == want
    # compensated exactly once: every XY move differs from its source line, and the
    # compensated values are those of one pass (offline == sent); non-motion lines unchanged
    moves = [c for c in commands + jog if _is_move(c)]
    assert len([c for c in got if _is_move(c)]) > len(moves)  # take-ups, arc pieces
    for c in commands + jog:
        if not _is_move(c):
            assert c in got
    assert "G1 X50 Y60 F3000" not in got
    # a Z-only move moves X and Y too under XZ/YZ skew, in a move of their own before it:
    # the Z move stays a Z move (issue 36)
    # (the first lift after G28 at the homed corner has its X/Y kept on the edge: clamped)
    zs = [i for i, c in enumerate(got) if c.startswith("G1 Z")]
    assert any(got[i - 1].startswith("G1 X") and "Z" not in got[i - 1] for i in zs), got
    assert not any(c.startswith("G1 X") and "Z" in c and c.endswith(" F600") for c in got)
    rep = status(server)["compensation"]["report"]
    assert rep["moves_compensated"] >= len(moves) - 1 and rep["malformed"] == 0
    settings(server, home_mm=None)


def test_upload_compensated_file_is_not_compensated_again_when_printed(server):
    from octoprint_kincomp.core.compensator import Compensator
    from octoprint_kincomp.core.marker import file_marker
    from octoprint_kincomp.engines.file_loop import marker_line
    from octoprint_kincomp.tools.line_path import compensate_lines

    settings(server, enabled=True, mode="on_upload", params=PARAMS)
    try:
        src = os.path.join(DATA, "bambustudio-square-ring.gcode")
        with open(src, "rb") as f:
            data = f.read()
        start = _print_file(server, "ring.gcode", data)
        stored = os.path.join(server.basedir, "uploads", "ring.gcode")
        assert file_marker(stored) == status(server)["params_hash"]
        # the stored file is the offline compensation of the upload ...
        st = status(server)
        from octoprint_kincomp.service.settings.schema import engine_config

        params, options = engine_config(st["settings"], tuple(st["limits"]))
        with open(src, encoding="utf-8", newline="") as f:
            reference = "".join(
                compensate_lines(
                    f.read().splitlines(keepends=True),
                    Compensator(params, options),
                    marker_line(params),
                )
            )
        with open(stored, encoding="utf-8", newline="") as f:
            assert f.read() == reference
        # ... and printing it sends exactly its lines: not compensated a second time
        got = sent(server, after=start)
        assert got == _visible(_file_commands(stored))
        _, files = server.request("GET", "/plugin/kincomp/files")
        ring = next(f for f in files["files"] if f["path"] == "ring.gcode")
        assert ring["params_hash"] == st["params_hash"] and not ring["outdated"]
        # new parameters: the file is flagged as compensated with older ones
        settings(server, params=dict(PARAMS, scale_ppm={"x": 100.0}))
        _, files = server.request("GET", "/plugin/kincomp/files")
        assert next(f for f in files["files"] if f["path"] == "ring.gcode")["outdated"]
    finally:
        settings(server, mode="on_the_fly", params=PARAMS)


def _users_settings(s):
    """The stored settings without what the printer itself updates at any time (its M503
    answers, read as they arrive on the serial line, with the profile they belong to): a
    refused save must leave everything else as it was."""
    out = json.loads(json.dumps(s))
    out.pop("motion_limits", None)
    for profile in (out.get("profiles") or {}).values():
        if isinstance(profile, dict):
            profile.pop("motion_limits", None)
    return out


def test_bad_settings_are_refused_and_the_old_values_kept(server):
    before = _users_settings(settings(server, enabled=True, params=PARAMS, chord_tol_mm=0.01))
    bad = [
        {"params": {"squareness_um_per_m": {"xy": 1e9}}},
        {"params": {"backlash": {"x": -5}}},
        {"params": {"scale_ppm": {"q": 1}}},
        {"chord_tol_mm": -1},
        {"mode": "sometimes"},
        {"enabled": "yes please"},
    ]
    for body in bad:
        code, resp = server.request("POST", "/plugin/kincomp/settings", body)
        assert code == 400, (body, resp)
        assert resp["error"]
        assert _users_settings(status(server)["settings"]) == before
    code, resp = server.request(
        "POST", "/plugin/kincomp/settings", {"params": {"squareness_um_per_m": {"xy": "abc"}}}
    )
    assert "params.squareness_um_per_m.xy" in resp["error"]
    # OctoPrint's own settings endpoint (the settings dialog) answers 400 too
    code, resp = server.request(
        "POST", "/api/settings", {"plugins": {"kincomp": {"limits_policy": "explode"}}}
    )
    assert code == 400 and "limits_policy" in json.dumps(resp)
    assert _users_settings(status(server)["settings"]) == before
    code, _ = server.request(
        "POST", "/api/settings", {"plugins": {"kincomp": {"limits_policy": "clamp"}}}
    )
    assert code == 200 and status(server)["settings"]["limits_policy"] == "clamp"
    settings(server, limits_policy="warn")
    # OctoPrint's SETTINGS permission alone may not change the machine model
    code, resp = server.request(
        "POST",
        "/api/settings",
        {"plugins": {"kincomp": {"params": {"scale_ppm": {"x": 5}}}}},
        key="settingsonly",
    )
    assert code == 403, resp
    assert status(server)["settings"]["params"] == before["params"]
    code, _ = server.request(
        "POST", "/api/settings", {"appearance": {"name": "kc"}}, key="settingsonly"
    )
    assert code == 200  # their other settings are theirs to change


WRITE_ENDPOINTS = [
    ("/plugin/kincomp/settings", {"enabled": False}),
    ("/plugin/kincomp/program", {"plane": "XY", "centre": [100, 100, 10], "radius": 40}),
    ("/plugin/kincomp/analyze", {"summary": {"plane": "XY", "squareness_um_per_m": 10}}),
    ("/plugin/kincomp/apply", {"params": {}}),
    ("/plugin/kincomp/compensate", {"path": "ring.gcode"}),
    ("/plugin/kincomp/trace", None),
]


def test_write_endpoints_refuse_anonymous_viewer_and_missing_csrf(server):
    from tests.support.serverutil import BrowserSession

    before = _users_settings(status(server)["settings"])
    anon = BrowserSession(server)
    assert anon.csrf()
    for path, body in WRITE_ENDPOINTS:
        raw = None if body is not None else b"direction,angle_deg,deviation_um\n"
        # anonymous, with a valid CSRF pair: refused by permission
        code, _ = anon.open("POST", path, body, raw=raw, content_type="text/csv")
        assert code in (401, 403), (path, code)
        # non-admin API keys: a plain user, and one with OctoPrint's SETTINGS permission
        for user in ("viewer", "settingsonly"):
            code, _ = server.request("POST", path, body, key=user, raw=raw, content_type="text/csv")
            assert code == 403, (path, user, code)
        # no credentials at all and no CSRF token
        code, _ = server.request("POST", path, body, key=None, raw=raw, content_type="text/csv")
        assert code in (400, 401, 403), (path, code)
    code, _ = anon.open("GET", "/plugin/kincomp/status")
    assert code in (401, 403)
    # a logged-in admin browser session still needs the CSRF header
    admin = BrowserSession(server).login("admin", server.logins["admin"]["password"])
    code, text = admin.open("POST", "/plugin/kincomp/settings", {"enabled": False}, csrf=False)
    assert code == 400 and "CSRF" in text
    assert _users_settings(status(server)["settings"]) == before
    code, _ = admin.open("POST", "/plugin/kincomp/settings", {"enabled": before["enabled"]})
    assert code == 200


def test_background_mode_writes_a_compensated_copy_with_progress(server):
    from octoprint_kincomp.core.compensator import Compensator
    from octoprint_kincomp.core.marker import file_marker
    from octoprint_kincomp.engines.file_loop import marker_line
    from octoprint_kincomp.service.settings.schema import engine_config
    from octoprint_kincomp.tools.line_path import compensate_lines

    settings(server, enabled=True, mode="background", params=PARAMS)
    try:
        src = os.path.join(DATA, "bambustudio-a1-hook.gcode")
        with open(src, "rb") as f:
            data = f.read()
        code, _ = server.upload("/api/files/local", "bg.gcode", data)
        assert code == 201
        deadline = time.time() + 300
        while True:
            jobs = status(server)["jobs"]
            job = next((j for j in jobs if j["path"] == "bg.gcode"), None)
            if job and job["state"] in ("done", "failed"):
                break
            assert time.time() < deadline, jobs
            time.sleep(0.5)
        assert job["state"] == "done", job
        assert job["result"] == "bg.kincomp.gcode" and job["progress"] == 1.0
        # the upload itself is untouched, the copy is the offline compensation
        assert open(os.path.join(server.basedir, "uploads", "bg.gcode"), "rb").read() == data
        copy = os.path.join(server.basedir, "uploads", "bg.kincomp.gcode")
        st = status(server)
        assert file_marker(copy) == st["params_hash"]
        params, options = engine_config(st["settings"], tuple(st["limits"]))
        with open(src, encoding="utf-8", newline="") as f:
            reference = "".join(
                compensate_lines(
                    f.read().splitlines(keepends=True),
                    Compensator(params, options),
                    marker_line(params),
                )
            )
        with open(copy, encoding="utf-8", newline="") as f:
            assert f.read() == reference
    finally:
        settings(server, mode="on_the_fly", enabled=False)
