"""Issue 34: the sensor, the labels and the firmware are evidence too. Every fault the
independent lab found is produced by KinComp's own simulator here (``Truth``: sensor_gain,
sensor_sign, swap_labels, firmware_compensation; metadata edits for a wrong plane key or
radius), each against its clean twin, which must stay quiet. The printer is the lab's
as-built one (squareness 1200/-800/500 um/m, X play 25/30 um along X, belt teeth, a set-up
offset). Every trace here is SIMULATED; the traces are made once per module."""

import io
import json

import pytest

from octoprint_kincomp.calibration.ballbar.analysis import Provenance, analyse
from octoprint_kincomp.calibration.ballbar.formats import parse_csv_trace
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.calibration.ballbar.timing import SentWith
from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.file_loop import compensate_stream
from octoprint_kincomp.firmware.compensation import FirmwareCompensation
from octoprint_kincomp.firmware.planner import MotionSettings
from octoprint_kincomp.simulator.printer import Truth, simulate_angle_trace, simulate_program

XY = TestSpec(radius_mm=50.0, centre=(110.0, 110.0, 10.0))
XZ = TestSpec(plane="XZ", centre=(110.0, 110.0, 38.0), radius_mm=50.0)
FW = "M852 I0.00115 J-0.00078 K0.00048; M425 X0.028 Y0.020 Z0.010 F1"


def lab_printer(**kw) -> Truth:
    t = Truth(
        errors=Params.from_dict(
            {
                "squareness_um_per_m": {"xy": 1200.0, "xz": -800.0, "yz": 500.0},
                "scale_ppm": {"x": 200.0, "y": -200.0},
                "backlash": {
                    "x": [{"at_mm": 10.0, "um": 25.0}, {"at_mm": 210.0, "um": 30.0}],
                    "y": 20.0,
                    "z": 10.0,
                },
            }
        ),
        servo_lag_ms={"x": 1.0, "y": 1.3, "z": 0.8},
        cyclic={"x": (2.0, 2.0, 30.0), "y": (2.0, 2.0, 110.0)},
        noise_um=0.5,
        setup_offset_um=(200.0, -100.0, 50.0),
        seed=3,
    )
    for k, v in kw.items():
        setattr(t, k, v)
    return t


def trace(spec, truth, angle=False, program=None):
    text = program or generate(spec)
    fn = simulate_angle_trace if angle else simulate_program
    return parse_csv_trace(fn(text, truth, spec if program else None).to_text())


def loud(result):
    return sorted({f["code"] for f in result["findings"] if f["severity"] != "info"})


def codes(result):
    return {f["code"] for f in result["findings"]}


def finding(result, code):
    hits = [f for f in result["findings"] if f["code"] == code]
    assert hits, codes(result)
    return hits[0]


def within(d, sq, mism, tol_mm=None):
    assert abs(d["squareness_um_per_m"] - sq) <= max(0.02 * abs(sq), 5.0), d["squareness_um_per_m"]
    assert abs(d["scale_mismatch_ppm"] - mism) <= 5.0, d["scale_mismatch_ppm"]


CASES = {
    "clean": {},
    "sign": {"sensor_sign": -1.0},
    "gain": {"sensor_gain": 1.03},
    "swap": {"swap_labels": True},
    "fw": {"firmware_compensation": FW},
}


@pytest.fixture(scope="module")
def xy():
    """The XY traces of every case (native and angle), simulated once."""
    return {
        (name, angle): trace(XY, lab_printer(**kw), angle)
        for name, kw in CASES.items()
        for angle in (False, True)
    }


# ---------------------------------------------------------------------------------------
# clean twins


@pytest.mark.parametrize("angle", [False, True])
def test_the_clean_twin_is_quiet(xy, angle):
    out = analyse(xy["clean", angle])
    assert loud(out) == [] and out["trusted"] is True
    within(out["diagnostics"], 1200.0, 400.0)
    if angle:
        assert "sensor.not_checked" in codes(out)
        assert out["needs_confirmation"]["confirm"] == [
            "plane",
            "radius_mm",
            "feed_mm_min",
            "sensor",
            "firmware_compensation",
        ]
    else:
        gain = out["diagnostics"]["checks"]["sensor_gain"]
        assert abs(gain["value"] - 1.0) < 0.002
        assert out["needs_confirmation"]["confirm"] == ["plane", "firmware_compensation"]
    assert "firmware.unknown" in codes(out)


# ---------------------------------------------------------------------------------------
# the sensor


def test_a_reversed_sensor_is_an_error_and_read_the_right_way_up(xy):
    out = analyse(xy["sign", False])
    f = finding(out, "sensor.sign_reversed")
    assert f["severity"] == "error" and out["trusted"] is False
    within(out["diagnostics"], 1200.0, 400.0)  # inverted for the analysis
    # an angle export cannot show the step: every backlash side comes out negative
    out = analyse(xy["sign", True])
    f = finding(out, "backlash.impossible")
    assert f["severity"] == "error" and "extension as negative" in f["message"]
    assert len(f["evidence"]["negative_um"]) == 4


def test_a_gain_off_by_3_percent_is_taken_off_with_a_warning(xy):
    out = analyse(xy["gain", False])
    f = finding(out, "sensor.gain")
    assert f["severity"] == "warning"
    assert f["evidence"]["gain"] == pytest.approx(1.03, abs=0.001)
    within(out["diagnostics"], 1200.0, 400.0)
    # an angle export: said what could not be checked, the values as read
    out = analyse(xy["gain", True])
    assert "sensor.not_checked" in codes(out)
    assert out["diagnostics"]["squareness_um_per_m"] == pytest.approx(1236.0, abs=8.0)


def test_reversal_spikes_do_not_pass_for_a_gain():
    """Reversal spikes hold the still head 10-12 um off after the 1 mm feed-out: an info,
    the readings left as they are (issue 23's case stays within tolerance)."""
    from octoprint_kincomp.simulator.printer import paper_truth

    t = paper_truth(noise_um=0.5, spike_um=15.0, spike_decay_mm=3.0)
    out = analyse(trace(XY, t))
    assert "sensor.gain" not in codes(out)
    assert "sensor.gain_uncertain" in codes(out)


# ---------------------------------------------------------------------------------------
# the labels


def test_swapped_labels_are_an_error(xy):
    out = analyse(xy["swap", False])
    f = finding(out, "labels.direction")
    assert f["severity"] == "error"
    assert f["evidence"] == {"found": ["cw", "ccw"], "expected": ["ccw", "cw"]}
    out = analyse(xy["swap", True])  # the rows run against their labels
    assert finding(out, "labels.direction")["severity"] == "error"


def test_rows_sorted_by_angle_cannot_tell_the_labels(xy):
    tr = xy["clean", True]
    sorted_rows = sorted(tr.rows, key=lambda r: (r[0], r[1]))
    out = analyse(type(tr)(meta=dict(tr.meta), rows=sorted_rows))
    assert "labels.not_checked" in codes(out) and loud(out) == []


@pytest.mark.parametrize("angle", [False, True])
def test_a_plane_key_changed_does_not_match_the_program(xy, angle):
    tr = xy["clean", angle]
    edited = type(tr)(meta=dict(tr.meta, plane="XZ"), rows=tr.rows)
    out = analyse(edited)
    f = finding(out, "program.mismatch")
    assert f["severity"] == "error" and f["evidence"]["recorded"] == tr.meta["program_hash"]


def test_an_angle_trace_of_another_arc_is_an_error(xy):
    tr = xy["clean", True]
    meta = dict(tr.meta, capture_deg="220", start_deg="-20")
    meta.pop("program_hash")
    out = analyse(type(tr)(meta=meta, rows=tr.rows))
    assert finding(out, "labels.arc")["severity"] == "error"


@pytest.fixture(scope="module")
def r50_as_r100():
    """R50 F925 printed (the same angular speed as R100 F1850), labelled R100 F1850."""
    small = TestSpec(plane="XY", centre=(110.0, 110.0, 10.0), radius_mm=50.0, feed_mm_min=925.0)
    big = TestSpec(plane="XY", centre=(110.0, 110.0, 10.0), radius_mm=100.0)
    big_meta = parse_csv_trace(simulate_program(generate(big), lab_printer(noise_um=0.0)).to_text())
    out = {}
    for angle in (False, True):
        tr = trace(small, lab_printer(), angle)
        keep = {k: v for k, v in tr.meta.items() if k not in big_meta.meta}
        out[angle] = type(tr)(meta=dict(big_meta.meta, **keep), rows=tr.rows)
    return out


def test_a_trace_of_half_the_feed_shows_in_its_ramps(r50_as_r100):
    out = analyse(r50_as_r100[False])
    f = finding(out, "motion.ramp")
    assert f["severity"] == "error"
    assert f["evidence"]["ramp_time_ratio"] == pytest.approx(1.95, abs=0.1)
    assert f["evidence"]["implied_radius_mm"] == pytest.approx(50.0, abs=5.0)
    # not timed: nothing in the data; the user confirms radius, feed and plane (and the
    # sensor, which an angle trace cannot check either; the firmware's state is recorded)
    recorded = r50_as_r100[True]
    recorded = type(recorded)(
        meta=dict(recorded.meta, firmware_compensation="none"), rows=recorded.rows
    )
    out = analyse(recorded)
    need = out["needs_confirmation"]
    assert need["confirm"] == ["plane", "radius_mm", "feed_mm_min", "sensor"]
    assert need["stated"] == {
        "plane": "XY",
        "radius_mm": 100.0,
        "feed_mm_min": 1850.0,
        "sensor": "checked",
    }
    # a trace tied to its print needs nothing confirmed
    tied = analyse(r50_as_r100[True], origin=Provenance(confirmed="printed"))
    assert tied["needs_confirmation"] is None and "program.unconfirmed" not in codes(tied)
    # a trace that states no feed: stated as none (the result document is strict JSON)
    bare = dict(recorded.meta)
    bare.pop("feed_mm_min")
    out = analyse(type(recorded)(meta=bare, rows=recorded.rows))
    assert out["needs_confirmation"]["stated"]["feed_mm_min"] is None
    assert "F?" in finding(out, "program.unconfirmed")["message"]
    json.dumps(out, allow_nan=False)


# ---------------------------------------------------------------------------------------
# the firmware's own compensation


def test_firmware_compensation_not_recorded_shows_in_negative_backlash(xy):
    out = analyse(xy["fw", False])
    f = finding(out, "backlash.negative")
    assert f["severity"] == "warning" and "M425" in f["message"]
    assert out["diagnostics"]["squareness_um_per_m"] == pytest.approx(50.0, abs=3.0)


def test_firmware_compensation_that_matches_the_play_is_asked_for():
    """A YZ test with M425 Y0.020 Z0.010 on a printer whose play is just that leaves no
    negative side (the XY and XZ tests show one only because X's play grows along X): the
    data cannot see it, so an unrecorded firmware state is confirmed before Apply."""
    spec = TestSpec(plane="YZ", centre=(110.0, 110.0, 38.0), radius_mm=50.0)
    tr = trace(spec, lab_printer(firmware_compensation=FW))
    out = analyse(tr)
    assert loud(out) == []  # nothing in the data
    assert out["diagnostics"]["squareness_um_per_m"] == pytest.approx(20.0, abs=5.0)
    need = out["needs_confirmation"]
    assert need["confirm"] == ["plane", "firmware_compensation"]
    assert need["stated"]["firmware_compensation"] == "none"
    assert "firmware" in finding(out, "program.unconfirmed")["advice"]
    # recorded (the plugin's M503, or --firmware): nothing to confirm about it
    fw = analyse(tr, origin=Provenance(firmware=FirmwareCompensation.from_text(FW)))
    assert fw["needs_confirmation"]["confirm"] == ["plane"]
    assert "firmware.in_force" in codes(fw)


def test_firmware_compensation_recorded_gives_the_residual_and_says_keep_it(xy):
    tr = xy["fw", False]
    recorded = type(tr)(meta=dict(tr.meta, firmware_compensation=FW), rows=tr.rows)
    for out in (
        analyse(recorded),
        analyse(tr, origin=Provenance(firmware=FirmwareCompensation.from_text(FW))),
    ):
        d = out["diagnostics"]
        f = finding(out, "firmware.in_force")
        assert "Keep the firmware's compensation" in f["advice"]
        assert d["with_firmware"]["squareness_um_per_m"] == pytest.approx(1200.0, abs=5.0)
        # X play 26.25 um at x = 60 (25 at x = 10, 30 at x = 210)
        assert d["with_firmware"]["backlash_um"]["a_minus"] == pytest.approx(26.25, abs=1.0)
        assert finding(out, "backlash.over_compensated")["severity"] == "warning"
        # the proposal is the residual, on top of the firmware's (its record says so)
        assert out["parameters"]["squareness_um_per_m"]["xy"] == pytest.approx(50.0, abs=3.0)
        assert out["parameters"]["meta"]["firmware"]["skew"].startswith("M852")


def test_firmware_commands_read_in_kincomp_conventions():
    fw = FirmwareCompensation.from_text(FW)
    assert fw.skew_um_per_m() == pytest.approx({"xy": 1150.0, "xz": -780.0, "yz": 480.0})
    assert fw.backlash_um() == pytest.approx({"x": 28.0, "y": 20.0, "z": 10.0})
    rrf = FirmwareCompensation.from_text("M556 S100 X-0.12 Y0.05 Z0.08; M579 X0.9998")
    assert rrf.skew_um_per_m() == pytest.approx({"xy": 1200.0, "yz": -500.0, "xz": -800.0})
    assert rrf.scale_ppm()["x"] == pytest.approx(200.04, abs=0.01)
    assert FirmwareCompensation.from_text("none").text() == "none"
    assert FirmwareCompensation.from_text("").text() == "unknown"
    off = FirmwareCompensation.from_text("M425 F1 X0 Y0 Z0; M852 I0 J0 K0")
    assert off.known and not off.active


# ---------------------------------------------------------------------------------------
# no false alarms on clean printers


def _compensated(spec, params, options):
    dst = io.StringIO()
    compensate_stream(io.StringIO(generate(spec, params_hash=params.hash())), dst, params, options)
    return dst.getvalue()


@pytest.fixture(scope="module")
def retest_params():
    """What a clean XZ test proposes, with the yz squareness and Y play a campaign's XY and
    YZ tests add: the re-test runs with it in force (Y then moves with Z and reverses slowly
    at the top of the arc, where the dead band decides its take-up)."""
    first = analyse(trace(XZ, lab_printer()))
    d = first["parameters"]
    d["squareness_um_per_m"]["yz"] = 500.0
    d["backlash"]["y"] = 20.0
    return Params.from_dict(d)


def test_a_vertical_re_test_with_the_plugins_dead_band_is_quiet(retest_params):
    """The demo's false alarm: compensated with the compensator's defaults (3 decimals, a
    0.625 um dead band), the re-test was modelled with 1e-6 mm and 4 decimals (misfit 1.7x,
    model.unstable). Its header records how; without the record the defaults are assumed."""
    sent = _compensated(XZ, retest_params, Options())
    assert "; ballbar compensation_deadband_mm: 0.000625" in sent
    tr = trace(XZ, lab_printer(seed=4), program=sent)
    assert tr.meta["compensation_decimals"] == "3"
    for t in (
        tr,
        type(tr)(meta={k: v for k, v in tr.meta.items() if "compensation" not in k}, rows=tr.rows),
    ):
        out = analyse(t, current=retest_params)
        assert loud(out) == []
        assert out["diagnostics"]["checks"]["adequacy"]["ratio"] < 1.2
        assert abs(out["diagnostics"]["scale_mismatch_ppm"]) < 5.0


def test_a_re_test_sent_with_the_stepless_dead_band_is_read_as_recorded(retest_params):
    """compensate --steps-per-mm 50000 (a 1e-6 mm dead band): the header says so, the trace
    carries it and the analysis regenerates the program with it."""
    sent = _compensated(XZ, retest_params, Options(steps_per_mm=50000))
    tr = trace(XZ, lab_printer(seed=5), program=sent)
    assert SentWith.from_meta(tr.meta).deadband_mm == pytest.approx(1e-6)
    out = analyse(tr, current=retest_params)
    assert loud(out) == []
    assert out["diagnostics"]["fit"]["compensated_as"]["source"] == "trace"
    assert float(out["diagnostics"]["fit"]["compensated_as"]["compensation_deadband_mm"]) == 1e-6


def test_low_acceleration_does_not_make_the_fit_unstable():
    """300 mm/s^2 with 25 um of X play and a 0.2 mm set-up offset: the ramps' take-up had
    bent the time mapping (model.unstable on 6 of 8 seeds); seed 6 warned before."""
    t = lab_printer(seed=6, cyclic={})
    t.motion = MotionSettings(accel_mm_s2=300.0)
    out = analyse(trace(XZ, t))
    assert loud(out) == []
    within(out["diagnostics"], -800.0, 200.0)


def test_an_angle_trace_without_a_planner_uses_the_capture_arc():
    """At 500 mm/s^2 the overshoot arcs taken at the feed put XZ 16-19 ppm off (issue 34);
    the capture arc alone reads what the planned mapping reads."""
    t = lab_printer(noise_um=0.0, cyclic={})
    t.motion = MotionSettings(accel_mm_s2=500.0)
    tr = trace(XZ, t, angle=True)
    planned = analyse(tr)["diagnostics"]["scale_mismatch_ppm"]
    for k in MotionSettings.KEYS:
        tr.meta.pop(k, None)
    out = analyse(tr)
    assert out["diagnostics"]["fit"]["capture_only"] is True
    within(out["diagnostics"], -800.0, 200.0)
    assert abs(out["diagnostics"]["scale_mismatch_ppm"] - planned) < 5.0


@pytest.fixture(scope="module")
def servo_retest():
    """An XY re-test with servo pre-compensation in force (the printer's own lags): the
    compensator leads each move's end by T v, so the head stands 31-32 um beyond the point
    meant in the dwells after the feed-outs; the dwell after a run's first line (a move of
    no length, which takes the lead back into the play) depends on the play."""
    first = analyse(trace(XY, lab_printer()))
    d = dict(first["parameters"], servo_precomp=True, servo_lag_ms={"x": 1.0, "y": 1.3, "z": 0.8})
    params = Params.from_dict(d)
    sent = _compensated(XY, params, Options())
    return params, {
        gain: trace(XY, lab_printer(seed=4, sensor_gain=gain), program=sent) for gain in (1.0, 1.03)
    }


def test_a_re_test_with_servo_precompensation_reads_its_sensor_right(servo_retest):
    """The still levels taken back by the lead: 0.9992 (1.031 and a sensor.gain warning, the
    readings scaled by 3 %, when the lead was read as sensor gain)."""
    params, traces = servo_retest
    out = analyse(traces[1.0], current=params)
    assert loud(out) == []
    gain = out["diagnostics"]["checks"]["sensor_gain"]
    assert abs(gain["value"] - 1.0) < 0.002 and gain["dwells"] == 2
    off = analyse(traces[1.03], current=params)
    assert "sensor.gain" in loud(off)
    assert off["diagnostics"]["checks"]["sensor_gain"]["value"] == pytest.approx(1.03, abs=0.003)


# the demo campaign's proposal (rounded): the parameters of its re-test, servo pre-compensation on
DEMO_PROPOSAL = {
    "squareness_um_per_m": {"xy": -3638.1, "xz": 799.9, "yz": -499.9},
    "scale_ppm": {"x": -447.0, "y": 291.8, "z": 155.2},
    "backlash": {
        "x": [{"at_mm": 50.0, "um": 30.8}, {"at_mm": 150.0, "um": 14.3}],
        "y": [{"at_mm": 50.0, "um": 6.5}, {"at_mm": 150.0, "um": 9.5}],
        "z": 8.0,
    },
    "servo_lag_ms": {"x": 0.62, "y": 0.0, "z": 0.3},
    "servo_precomp": True,
}


def test_a_compensated_re_test_without_planner_settings_is_timed_right():
    """A live capture of a printer whose planner settings KinComp does not know records
    none: the motion is estimated from the trace. A re-test at F3700 with the demo's
    proposal in force (take-ups and servo leads bend the ramps) was estimated at 2,624
    mm/s^2 and 0.06 mm on the demo's 1,500 mm/s^2, 0.013 mm printer: its runs planned 155 ms
    short, "do not apply" (motion.timing, motion.ramp, a misfit). The estimate now keeps to
    the timing valley; the clean twin is the same trace with the planner settings it was
    planned with."""
    from octoprint_kincomp.simulator.demo import demo_truth

    spec = TestSpec(radius_mm=50.0, feed_mm_min=3700.0, centre=(100.0, 100.0, 10.0))
    params = Params.from_dict(DEMO_PROPOSAL)
    sent = _compensated(spec, params, Options())
    known = trace(spec, demo_truth(), program=sent)
    unknown = parse_csv_trace(known.to_text())
    for key in MotionSettings.KEYS + ("motion",):
        unknown.meta.pop(key, None)
    twin = analyse(known, current=params)
    out = analyse(unknown, current=params)
    assert loud(twin) == [] and loud(out) == [], (loud(twin), loud(out))
    assert out["diagnostics"]["fit"]["motion"]["estimated"] and "motion.estimated" in codes(out)
    d = twin["diagnostics"]
    within(out["diagnostics"], d["squareness_um_per_m"], d["scale_mismatch_ppm"])
