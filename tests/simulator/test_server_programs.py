"""The plugin's own test programs on KinComp's own clean simulator come out clean (issues 34,
36: never cry wolf on a clean printer). The programs are written by the plugin's endpoints
(the calibration tab's single test, a campaign's tests) for OctoPrint's virtual printer,
whose M115 names "Virtual Marlin" and whose M503 states M204 T300 and classic jerk: their
headers record that planner. A simulated printer without motion of its own is that printer
(simulator/printer.py). It once moved with the simulator's defaults (1500 mm/s^2, junction
deviation) whatever the header said: the analysis, planning with the header, found the feed-ins
0.54 times as long as planned (motion.ramp) and the XY runs 66 ms short (motion.timing on a
campaign's R50 circle): "Do not apply" on the demo's own printer."""

import pytest

from octoprint_kincomp.calibration.ballbar.program import spec_from_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.service.calibration.demo_mode import lines_as_sent
from octoprint_kincomp.service.calibration.measurement import analyse_measurement
from octoprint_kincomp.simulator.demo import DemoBallbar, demo_truth
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth
from tests.support import permissions
from tests.support.mocked_plugin import api_app, mocked_plugin, wait_for

PROFILE = {
    "id": "_default",
    "name": "Virtual",
    "volume": {"width": 220, "depth": 220, "height": 200, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 200}},
}
# OctoPrint's virtual printer's answer to M503 (its default virtual EEPROM)
VIRTUAL_M503 = [
    "echo:; Steps per unit:",
    "echo: M92 X80.0 Y80.0 Z800.0 E90.0",
    "echo:; Maximum feedrates (units/s):",
    "echo: M203 X500.0 Y500.0 Z5.0 E25.0",
    "echo:; Maximum Acceleration (units/s2):",
    "echo: M201 E74.0 X2000.0 Y2000.0 Z10.0",
    "echo:; Acceleration (units/s2): P<print_accel> R<retract_accel> T<travel_accel>",
    "echo: M204 P750.0 R1000.0 T300.0 S300.0",
    "echo:; Advanced: B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> "
    "X<max_x_jerk> Y<max_y_jerk> Z<max_z_jerk> E<max_e_jerk>",
    "echo: M205 B20000.0 S0.0 T0.0 X10.0 Y10.0 Z0.3 E5.0 J0.0",
    "ok",
]


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    from octoprint_kincomp.service.files.worker import InProcessWorker

    p = mocked_plugin(str(tmp_path_factory.mktemp("plugin")), profile=PROFILE)
    p.jobs.worker = InProcessWorker()
    p._printer_profile_manager.get_current_or_default.return_value = PROFILE
    p._printer.is_printing.return_value = False
    p._printer.is_operational.return_value = True
    p.on_event("FirmwareData", {"name": "Virtual Marlin 1.0", "data": {}})
    for line in VIRTUAL_M503:
        p.received_hook(None, line)
    wait_for(lambda: p.store.current()["motion_limits"]["source"] == "m503")
    return p


def _call(plugin, view, *args, json=None):
    with api_app().test_request_context("/", method="POST", json=json):
        with permissions.granted():
            resp = view(*args)
    assert resp.status_code == 200, resp.get_json()
    return resp.get_json()


def _written(plugin) -> str:
    args = plugin._file_manager.add_file.call_args[0]
    return args[2].stream().read().decode()


def _single(plugin, plane):
    body = {"plane": plane, "radius": 100 if plane == "XY" else 50}
    body["centre"] = [110, 110, 10] if plane == "XY" else [110, 110, 70]
    _call(plugin, plugin.calibration.program, json=body)
    return _written(plugin)


def _campaign(plugin, n):
    doc = _call(plugin, plugin.campaign.plan, json={"radius_xy": 50})
    _call(plugin, plugin.campaign.program, doc["id"], n)
    return _written(plugin)


def _bad(result):
    return [
        (f["code"], f["message"][:160])
        for f in result["findings"]
        if f["severity"] in ("warning", "error")
    ]


def _analysed(trace):
    return analyse_measurement(trace.to_text().encode(), "trace.csv", Params().to_dict())


@pytest.mark.parametrize(
    "source, plane",
    [("single", "XY"), ("single", "XZ"), ("campaign", "XY"), ("campaign", "XZ")],
)
def test_a_server_written_program_simulated_clean_is_trusted(plugin, source, plane):
    n = {"XY": 1, "XZ": 2}[plane]
    text = _single(plugin, plane) if source == "single" else _campaign(plugin, n)
    spec, prog_hash = spec_from_program(text)
    assert spec.plane == plane and spec.motion["planner"] == "marlin"
    assert spec.motion["accel_mm_s2"] == "300"  # the virtual printer's M204 T
    result = _analysed(simulate_program(text, volume_truth(noise_um=0.5), spec, prog_hash))
    assert result["trusted"] and not _bad(result), _bad(result)
    fit = result["diagnostics"]["fit"]
    for d in ("cw", "ccw"):
        assert abs(fit["sync_mismatch_ms"][d]) < 10.0, fit["sync_mismatch_ms"]  # of 11-94 s
        assert all(abs(r - 1) < 0.05 for r in fit["ramp_time_ratio"][d])


def test_the_demo_printer_runs_a_campaign_test_as_the_virtual_printer_stated(plugin):
    """Demo mode: the commands as sent, simulated on the demo's hidden-error printer."""
    text = _campaign(plugin, 1)
    spec, prog_hash = spec_from_program(text)
    demo = DemoBallbar(demo_truth())
    demo.start(spec, prog_hash)
    for line in lines_as_sent(plugin.queue, text):
        demo.record(line)
    result = _analysed(demo.finish())
    assert result["trusted"] and not _bad(result), _bad(result)


def test_a_truth_with_motion_of_its_own_still_differs_from_the_plan(plugin):
    """A printer that moves otherwise than the header states is still caught."""
    from octoprint_kincomp.firmware.planner import MotionSettings

    text = _single(plugin, "XY")
    spec, prog_hash = spec_from_program(text)
    truth = volume_truth(noise_um=0.5, motion=MotionSettings())
    result = _analysed(simulate_program(text, truth, spec, prog_hash))
    assert "motion.ramp" in [c for c, _ in _bad(result)] and not result["trusted"]
