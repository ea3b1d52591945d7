"""End-to-end (issue 27): KinComp's printed artifact goes through the real OctoPrint like any
print - written and printed by POST /artifact/program on the virtual printer with compensation
on, every line sent as the compensator makes it (serial.log) - and the artifact endpoints
refuse anyone but an admin."""

import os

import pytest
from octoprint.util.comm import strip_comment

from tests.support.serverutil import home_reports, marker, offline, sent, settings, status

pytestmark = pytest.mark.slow

PARAMS = {
    "squareness_um_per_m": {"xy": 800.0, "xz": -300.0, "yz": 200.0},
    "scale_ppm": {"x": 500.0, "y": -400.0, "z": 0.0},
}
AUTOMATIC_FREE = ("M105", "M27", "M114")


def test_artifact_is_printed_through_octoprint_compensated(server):
    settings(server, enabled=True, mode="on_the_fly", params=PARAMS)
    try:
        code, _ = server.request("POST", "/api/printer/command", {"commands": ["M220 S5000"]})
        assert code == 204
        start = marker(server)
        code, out = server.request(
            "POST",
            "/plugin/kincomp/artifact/program",
            {"planes": ["XY"], "temps": [200, 50], "print": True},
        )
        assert code == 200, out
        assert out["printing"] is True and len(out["measurements"]) == 28
        server.wait_print_done(timeout=1800)
        with open(os.path.join(server.basedir, "uploads", out["path"]), encoding="utf-8") as f:
            cmds = [c for c in (strip_comment(line).strip() for line in f) if c]
        got = sent(server, after=start)
        want = [
            c
            for c in offline(server, cmds, home_reports(server, start))
            if c.split(" ", 1)[0] not in AUTOMATIC_FREE
        ]
        got = [c for c in got if c.split(" ", 1)[0] not in AUTOMATIC_FREE]
        assert len(want) > 2000
        if got != want:
            i = next(
                (i for i, (a, b) in enumerate(zip(got, want)) if a != b), min(len(got), len(want))
            )
            pytest.fail(
                f"line {i}: sent {got[i : i + 1]}, expected {want[i : i + 1]} "
                f"(sent {len(got)}, expected {len(want)})"
            )
        # compensated: the printed wall lines are not the file's
        assert any(
            a != b
            for a, b in zip(
                [c for c in got if c.startswith("G1 X")], [c for c in cmds if c.startswith("G1 X")]
            )
        )
    finally:
        settings(server, enabled=False)


def test_artifact_endpoints_are_for_admins(server):
    from tests.support.serverutil import BrowserSession

    before = status(server)["settings"]
    anon = BrowserSession(server)
    assert anon.csrf()
    for path, body in (
        ("/plugin/kincomp/artifact/program", {"planes": ["XY"]}),
        ("/plugin/kincomp/artifact/analyze", {"path": "x.gcode", "readings": {}}),
    ):
        code, _ = anon.open("POST", path, body)
        assert code in (401, 403), (path, code)
        for user in ("viewer", "settingsonly"):
            code, _ = server.request("POST", path, body, key=user)
            assert code == 403, (path, user, code)
    code, _ = anon.open("GET", "/plugin/kincomp/artifact/sheet?path=x.gcode")
    assert code in (401, 403)
    assert status(server)["settings"] == before
