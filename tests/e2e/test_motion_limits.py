"""Issue 23 on the real server with the virtual printer: KinComp reads the printer's motion
limits from its answer to M503 (the virtual printer's EEPROM: Marlin units) when it
connects, shows them in /status combined with the profile's axis speeds, and asks again on
request."""

import pytest

from tests.support.serverutil import motion_limits, status

pytestmark = pytest.mark.slow
BASE = "/plugin/kincomp"


def test_the_virtual_printers_limits_are_read_on_connecting(server):
    ml = motion_limits(server, timeout=30.0)
    assert ml["stated"]["firmware"].startswith("Virtual Marlin")
    read = ml["read"]
    # the virtual EEPROM: M203 X500 Y500 Z5 (units/s), M201 X2000 Y2000 Z10, M204 P750 T300
    assert read["max_feed_mm_min"] == {"x": 30000.0, "y": 30000.0, "z": 300.0}
    assert read["max_accel_mm_s2"] == {"x": 2000.0, "y": 2000.0, "z": 10.0}
    assert (read["print_accel_mm_s2"], read["travel_accel_mm_s2"]) == (750.0, 300.0)
    assert read["sources"]["max_feed_mm_min.z"] == "M203 (mm/s)" and not read["notes"]
    # combined with the default profile's axis speeds (mm/min): the lower of each
    profile = status(server)["max_feeds"]
    eff = ml["effective"]["max_feed_mm_min"]
    assert eff == {a: min(read["max_feed_mm_min"][a], profile[a]) for a in "xyz"}
    # asked again on request (202), the same answer
    code, body = server.request("POST", f"{BASE}/limits/read", {})
    assert code == 202, body
    again = motion_limits(server, timeout=30.0)
    assert again["read"] == read
    for user in ("viewer", "settingsonly"):  # no KinComp admin permission
        code, _ = server.request("POST", f"{BASE}/limits/read", {}, key=user)
        assert code == 403
