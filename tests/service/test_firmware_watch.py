"""What the firmware compensates itself, from the lines sent to and received from it."""

from octoprint_kincomp.core.params import Params
from octoprint_kincomp.service.printing.firmware_watch import FirmwareWatcher

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}, "backlash": {"x": 20.0}})


def test_firmware_watch():
    w = FirmwareWatcher()
    w.received("echo:  M852 I0.0010 J0.0000 K0.0000")
    w.received("echo:  M425 F1.00 X0.05 Y0.00 Z0.00")
    assert w.skew and w.backlash
    assert set(w.conflicts(SKEW)) == {"skew", "backlash"}
    w.sent("M852 I0 J0 K0")
    w.sent("M425 X0 Y0 Z0")
    assert w.skew is None and w.backlash is None
    w.sent("SET_SKEW XY=141.6,141.2,100")
    assert w.skew
    w.sent("SET_SKEW CLEAR=1")
    assert w.skew is None
    assert w.conflicts(Params()) == {}
    # lower case, RepRapFirmware scale factors
    w.sent("m852 i0.002")
    assert w.skew
    w.received("M579 X1.0020 Y1.0000")
    scaled = Params.from_dict({"scale_ppm": {"x": 100.0}})
    assert set(w.conflicts(scaled)) == {"scale"}
    w.sent("M579 X1 Y1")
    assert w.scale is None
    assert FirmwareWatcher.relevant("m425 x0.1") and not FirmwareWatcher.relevant("G1 X5")
