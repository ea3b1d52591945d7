"""Issue 37 (reliability round 4) on real OctoPrint servers (virtual printer):

* a disconnect and connect, then a print: the old connection's monitor thread ends about
  30 s later with one last line through the received hook, which was taken for a new
  connection and cost the print its position (``[true, true, false]``, every move then sent
  uncompensated with a log line each); now the print keeps its position throughout;
* the print's line rate under KinComp's load (the starvation row, its fast and steady part:
  four clients reading /status in a tight loop, each loaded phase against its quiet
  neighbours; every kind of load, with OctoPrint's own for comparison, is
  ``scripts/load_probe.py``, its figures in docs/reliability.md):
  ``test_tight_loop_reads_do_not_starve_a_print``.
"""

import os
import time

import pytest

from tests.support import line_rate as lr
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


def test_tight_loop_reads_do_not_starve_a_print(server):
    """Row 6: four clients reading KinComp's status as fast as they get answers (17 % of the
    print's quiet line rate before; OctoPrint's own /api/version read so: 38 %) are rationed
    while the print runs (service/request_gate.py): the print keeps 80 % of its rate; every
    answer is a 200 or a 429 with Retry-After, which the clients wait for."""
    name = "kc-rationed-print.gcode"
    path = os.path.join(server.basedir, "uploads", name)
    lr.fast_print(path, 400_000)  # (minutes of printing: the measurement takes about 30 s)
    settings(server, enabled=True, params=SKEW)

    def step(load, client, k):
        code, _, headers = client.request("GET", "/plugin/kincomp/status")
        load.count(code)
        return lr.retry_after(code, headers)

    load = lr.Load("read /status", step, clients=4)
    try:
        log = lr.SendLog(server)
        lr.start_print(server, name)
        time.sleep(3.0)  # past the start
        rates, ratios, median = lr.alternate(server, load, log, rounds=4, phase_s=3.0)
        print(
            f"\nSend: rate with 4 clients reading /status in a tight loop, quiet and loaded "
            f"alternating: {[round(r) for r in rates]}; ratios {[round(r, 2) for r in ratios]}, "
            f"median {median:.0%}; answers {load.codes}"
        )
        assert _job_state(server) == "Printing", "the print ended before the measurement"
        assert set(load.codes) <= {200, 429}, load.codes
        assert load.codes.get(429), "the ration did not act"
        assert median >= 0.8, (rates, ratios)
    finally:
        lr.cancel_print(server)
        settings(server, enabled=False)
        os.unlink(path)
