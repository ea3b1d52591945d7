"""The checks of the live view before a test (sensor/live.py bar_check): data arriving, the
bar steady, the reading inside the sensor's range, converted to mm, positive = longer."""

import pytest

from octoprint_kincomp.sensor.live import STEADY_UM, bar_check, range_mm
from octoprint_kincomp.sensor.virtual import VirtualSensor


def status(**kw):
    st = {
        "port_open": True,
        "last_data_age_s": 0.05,
        "reading_mm": 0.4,
        "noise_um": 0.6,
        "sensor": {"sensor_range": "-2,2", "sensor_units": "mm", "sensor_positive": "longer"},
    }
    st.update(kw)
    return st


def test_a_quiet_bar_inside_its_range_passes():
    c = bar_check(status())
    assert c == {
        "data": True,
        "steady": True,
        "in_range": True,
        "range_mm": [-2.0, 2.0],
        "margin_mm": 1.6,
        "steady_max_um": STEADY_UM,
    }


def test_each_check_can_fail_or_be_unknown():
    assert bar_check(status(noise_um=12.0))["steady"] is False  # rattles: not seated
    assert bar_check(status(reading_mm=2.3))["in_range"] is False
    stale = bar_check(status(last_data_age_s=5.0))
    assert stale["data"] is False and stale["steady"] is None and stale["in_range"] is None
    assert bar_check(status(port_open=False))["data"] is False
    unknown = bar_check(status(sensor={}))
    assert unknown["in_range"] is None and unknown["range_mm"] is None
    assert bar_check(status(noise_um=None))["steady"] is None


def test_the_range_follows_the_sensors_units_and_sign():
    assert range_mm(
        {"sensor_range": "-500,1500", "sensor_units": "um", "sensor_positive": "shorter"}
    ) == pytest.approx((-1.5, 0.5))
    assert range_mm({"sensor_range": "0,0.5", "sensor_units": "inch"}) == pytest.approx((0.0, 12.7))
    assert range_mm({"sensor_range": "garbage"}) is None


def test_the_virtual_bar_declares_its_range_in_its_own_units_and_sign():
    vs = VirtualSensor(units="um", longer_positive=False, range_mm=(-1.5, 2.5))
    assert "# range: -2500,1500" in vs.header()
    assert not any(line.startswith("# range") for line in VirtualSensor().header())
