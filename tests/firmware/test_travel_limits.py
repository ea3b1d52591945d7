"""The printer's travel as its firmware states it, and what the user is told at the travel's
edge (issue 36, item 1): Klipper's position_min/max, RepRapFirmware's M208, Marlin's M211
answer narrow the printer profile's volume; a file's and a print's shortfall are reported."""

from unittest import mock

import pytest

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.motion_limits import narrowed_travel, travel_limits
from octoprint_kincomp.service.printing.queue import (
    EDGE_KEPT,
    EDGE_PRINT,
    EDGE_SENT,
    QueueCompensator,
    edge_of,
    notify_edge,
)
from octoprint_kincomp.service.settings.schema import defaults, engine_config

KLIPPER = """
[stepper_x]
position_endstop: -10
position_min: -15
position_max: 235
[stepper_y]
position_endstop: 0
position_max: 230   # a comment
[stepper_z]
position_min: -4
position_max: 270
"""


def test_klippers_position_min_and_max():
    assert travel_limits(KLIPPER) == {"x": (-15.0, 235.0), "y": (0.0, 230.0), "z": (-4.0, 270.0)}


@pytest.mark.parametrize(
    "text,want",
    [
        (
            "M208 X-5:230 Y0:210 Z0:200 ; axis limits",
            {"x": (-5, 230), "y": (0, 210), "z": (0, 200)},
        ),
        ("M208 S1 X-5 Y-2\nM208 X230 Y210", {"x": (-5, 230), "y": (-2, 210)}),
        (
            "Axis limits (mm) X-5.0:230.0, Y0.0:210.0, Z0.0:200.0",
            {"x": (-5, 230), "y": (0, 210), "z": (0, 200)},
        ),
        (
            "  M211 S1 ; ON\n  Min:  X-2.00 Y-3.00 Z0.00   Max:  X180.00 Y180.00 Z185.00",
            {"x": (-2, 180), "y": (-3, 180), "z": (0, 185)},
        ),
        (
            "echo:  M211 S1 ; ON\necho:  Min:  X0.00 Y0.00 Z0.00   Max:  X235.00 Y235.00 Z250.00",
            {"x": (0, 235), "y": (0, 235), "z": (0, 250)},
        ),
        ("M203 X500 Y500\nM92 X80 Y80", {}),
    ],
)
def test_reprapfirmwares_m208_and_marlins_m211(text, want):
    assert travel_limits(text) == {a: tuple(float(v) for v in ends) for a, ends in want.items()}


def test_the_profile_is_narrowed_by_what_the_firmware_states():
    profile = (0.0, 250.0, 0.0, 250.0, 0.0, 250.0)
    assert narrowed_travel(profile, KLIPPER) == (0.0, 235.0, 0.0, 230.0, 0.0, 250.0)
    assert narrowed_travel(None, KLIPPER) == (-15.0, 235.0, 0.0, 230.0, -4.0, 270.0)
    assert narrowed_travel(profile, "M92 X80") == profile
    assert narrowed_travel(None, "M208 X0:200") is None  # (no complete box)
    s = defaults()
    s["motion_limits"] = dict(s["motion_limits"], text=KLIPPER)
    _, opts = engine_config(s, profile)
    assert opts.limits == (0.0, 235.0, 0.0, 230.0, 0.0, 250.0) and opts.policy == "clamp"


def test_a_print_at_the_travels_edge_is_reported_when_it_ends():
    params = Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}})
    q = QueueCompensator(
        params, Options(limits=(0, 200, 0, 200, 0, 200), home_mm=(0, 0, 0)), enabled=True
    )
    q.print_started(False)
    for line in ("G28", "G1 X10 Y100 Z1", "G1 X0 Y100", "G1 X0 Y150"):
        q.handle(line, {"source:file"})
    edge = q.print_ended()
    assert edge == {"count": 2, "worst_um": 300.0, "axis": "X", "sent": False}
    q.print_started(False)  # the next print starts from nothing
    assert q.print_ended() is None
    notifier = mock.Mock()
    notify_edge(notifier, edge, None)
    notifier.notify.assert_called_once_with(
        "warning",
        EDGE_KEPT,
        tr_params=("what",),
        what=EDGE_PRINT,
        count=2,
        worst_um=300.0,
        axis="X",
    )


def test_a_files_edge_report():
    rep = {"limit_hits": 3, "limit_worst_um": 42.0931, "limit_worst_axis": "Y"}
    assert edge_of(rep, "warn") == {"count": 3, "worst_um": 42.1, "axis": "Y", "sent": True}
    assert edge_of({"limit_hits": 0}, "clamp") is None
    notifier = mock.Mock()
    notify_edge(notifier, edge_of(rep, "warn"), "a.gcode")
    notifier.notify.assert_called_once_with(
        "warning", EDGE_SENT, what="a.gcode", count=3, worst_um=42.1, axis="Y"
    )
    notify_edge(notifier, None, "a.gcode")
    assert notifier.notify.call_count == 1
