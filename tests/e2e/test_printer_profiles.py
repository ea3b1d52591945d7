"""Issue 28 on the real server: a calibration belongs to one printer profile. A second
profile made through OctoPrint's API has no calibration: connected with it, KinComp says so
and sends moves as written; connected with the default profile again, its calibration is
in force again and the same move goes out compensated."""

import time

import pytest

from tests.support.serverutil import marker, offline, sent, settings, status

pytestmark = pytest.mark.slow
SECOND = {"id": "kincomp_e2e_second", "name": "KinComp e2e second printer"}
LINES = ["G28", "G1 X100 Y100 F3000"]


def _connect(server, profile_id):
    code, _ = server.request("POST", "/api/connection", {"command": "disconnect"})
    assert code == 204
    server.wait_state("Closed")
    code, _ = server.request(
        "POST",
        "/api/connection",
        {"command": "connect", "port": "VIRTUAL", "baudrate": 115200, "printerProfile": profile_id},
    )
    assert code == 204
    server.wait_state("Operational")
    deadline = time.monotonic() + 30
    while status(server)["profile"]["id"] != profile_id:
        assert time.monotonic() < deadline, status(server)["profile"]
        time.sleep(0.2)
    return status(server)


def _send(server, lines):
    start = marker(server)
    code, _ = server.request("POST", "/api/printer/command", {"commands": lines})
    assert code == 204
    end = marker(server)
    return [c for c in sent(server, after=start, until=end) if not c.startswith("M117")]


def test_a_second_printer_profile_has_its_own_calibration(server):
    settings(
        server, enabled=True, home_mm=[0, 0, 0], params={"squareness_um_per_m": {"xy": 1000.0}}
    )
    st = _connect(server, "_default")
    assert st["profile"]["calibrated"] is True and st["compensation"]["enabled"] is True
    calibrated = _send(server, LINES)
    assert calibrated == offline(server, LINES)
    assert "G1 X100 Y100 F3000" not in calibrated  # the skew moved the point

    code, body = server.request(
        "POST", "/api/printerprofiles", {"profile": dict(SECOND), "basedOn": "_default"}
    )
    assert code == 200, body
    try:
        st = _connect(server, SECOND["id"])
        # (its motion limits, read from the printer on connecting, are its own: known)
        assert {k: st["profile"][k] for k in ("id", "name", "calibrated")} == {
            "id": SECOND["id"],
            "name": SECOND["name"],
            "calibrated": False,
        }
        assert st["compensation"]["enabled"] is False
        assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
        assert _send(server, LINES) == LINES  # the second printer: as written

        st = _connect(server, "_default")
        assert st["profile"]["calibrated"] is True and st["compensation"]["enabled"] is True
        assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 1000.0
        assert _send(server, LINES) == calibrated
    finally:
        _connect(server, "_default")
        settings(server, enabled=False, home_mm=None, params={"squareness_um_per_m": {"xy": 0.0}})
        server.request("DELETE", f"/api/printerprofiles/{SECOND['id']}")
