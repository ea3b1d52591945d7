"""The live ballbar sensor on the plugin side (issue 15) with the mocked plugin: settings,
the live preview, arming from the program route, the end of a capture, failed captures, the
demo's live path. The sensor is KinComp's virtual ballbar on a real pseudo-terminal, opened
through pyserial; everything it streams is SIMULATED."""

import json
import threading
import time
from unittest import mock

import pytest

from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.formats import load_any
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.sensor import parse_raw_stream, trace_from_stream
from octoprint_kincomp.sensor.virtual import VirtualSensor
from octoprint_kincomp.service.calibration.printed_programs import origin_kwargs
from tests.support import permissions
from tests.support.mocked_plugin import api_app, mocked_plugin, queue_lines, wait_for

SPEEDUP = 20.0
PROGRAM = {"plane": "XY", "centre": [100, 100, 5], "radius": 30, "feed": 3000, "print": True}
SPEC = TestSpec(plane="XY", centre=(100.0, 100.0, 5.0), radius_mm=30.0, feed_mm_min=3000.0)


@pytest.fixture
def plugin(tmp_path):
    p = mocked_plugin(str(tmp_path))
    p._printer.is_printing.return_value = False
    p._printer.is_operational.return_value = True
    p._printer.get_current_connection.return_value = (
        "Operational",
        "/dev/ttyPRINTER",
        115200,
        None,
    )
    yield p
    p.sensor._preview = False
    p.sensor._release()


@pytest.fixture
def bar():
    vs = VirtualSensor(speedup=SPEEDUP)
    vs.start()
    yield vs
    vs.stop()


@pytest.fixture
def call(plugin):
    """call(view, path, method, json) -> (status, body) inside a request, permissions given."""
    app = api_app()

    def do(view, path, method="GET", json=None, *args):
        with permissions.granted():
            with app.test_request_context(path, method=method, json=json):
                resp = view(*args)
                status = getattr(resp, "status_code", 200)
                resp.direct_passthrough = False
                body = resp.get_json(silent=True)
                return status, body if body is not None else resp.get_data()

    return do


def messages(plugin, kind=None):
    out = [c[0][1] for c in plugin._plugin_manager.send_plugin_message.call_args_list]
    return [m for m in out if kind is None or m.get("type") == kind]


def use_sensor(plugin, call, port):
    status, body = call(
        plugin.settings_api.save, "/settings", "POST", {"sensor": {"enabled": True, "port": port}}
    )
    assert status == 200, body


def finished_run(plugin, timeout=30.0):
    """The run of the live capture that just ended (waits for the UI message)."""
    wait_for(lambda: messages(plugin, "sensor_run"), timeout)
    return plugin.runs.get(messages(plugin, "sensor_run")[-1]["run"]["id"])


def test_sensor_settings_are_checked_and_the_printers_port_refused(plugin, call):
    status, body = call(
        plugin.settings_api.save,
        "/settings",
        "POST",
        {
            "sensor": {
                "port": "socket://127.0.0.1:9",
                "baudrate": 250000,
                "protocol": "plain",
                "units": "um",
                "positive": "shorter",
            }
        },
    )
    assert status == 200, body
    stored = plugin.store.current()["sensor"]
    assert stored["baudrate"] == 250000 and stored["units"] == "um" and not stored["enabled"]
    for bad, field in (
        ({"baudrate": "fast"}, "sensor.baudrate"),
        ({"protocol": "pattern", "pattern": "(\\d+)"}, "sensor.pattern"),
        ({"scale": 0}, "sensor.scale"),
        ({"range": "2,1"}, "sensor.range"),
        ({"enabled": True, "port": ""}, "sensor.port"),
        ({"port": "/dev/ttyPRINTER"}, "sensor.port"),
        ({"speed": 1}, "sensor.speed"),
    ):
        status, body = call(plugin.settings_api.save, "/settings", "POST", {"sensor": bad})
        assert status == 400 and body["error"].startswith(field), (bad, body)
        assert plugin.store.current()["sensor"] == stored  # the old values are kept
    # the printer's configured port counts too (not only the connected one)
    plugin._settings.global_set(["serial", "port"], "/dev/ttyACM7")
    status, body = call(
        plugin.settings_api.save, "/settings", "POST", {"sensor": {"port": "/dev/ttyACM7"}}
    )
    assert status == 400 and "printer's own port" in body["error"]
    status, body = call(plugin.sensor.ports, "/sensor/ports")
    assert status == 200 and "/dev/ttyACM7" in body["printer_ports"]
    assert isinstance(body["ports"], list)


def test_nothing_to_capture_without_a_sensor(plugin, call):
    status, body = call(plugin.calibration.program, "/program", "POST", PROGRAM)
    assert status == 200 and body["printing"] and body["capture"] is None
    assert not plugin.sensor.waiting
    status, body = call(plugin.sensor.open, "/sensor/open", "POST")
    assert status == 400 and "no live sensor is set" in body["error"]
    assert call(plugin.sensor.stop, "/sensor/stop", "POST")[0] == 409
    status, body = call(plugin.sensor.status, "/sensor/status")
    assert status == 200 and body["state"] == "idle" and not body["configured"]


def test_live_preview_shows_the_reading_noise_and_chart(plugin, call, bar):
    use_sensor(plugin, call, bar.url)
    status, body = call(plugin.sensor.open, "/sensor/open", "POST")
    assert status == 200, body
    wait_for(
        lambda: (
            plugin.sensor._cap.state == "preview"
            and plugin.sensor._cap.status()["noise_um"] is not None
        ),
        10,
    )
    time.sleep(0.6)
    status, live = call(plugin.sensor.live, "/sensor/live?seconds=5")
    assert status == 200 and live["state"] == "preview" and live["port_open"]
    assert live["reading_mm"] == pytest.approx(1.0, abs=0.01)  # the idle bar
    assert 0.2 < live["noise_um"] < 1.0  # the virtual bar's 0.5 um
    assert live["check"]["data"] and live["check"]["steady"]
    assert len(live["chart"]["t"]) > 20 and all(t <= 0 for t in live["chart"]["t"])
    # pushed to the UI too, with a short chart
    wait_for(lambda: any(m["chart"]["mm"] for m in messages(plugin, "sensor")), 5)
    pushed = [m for m in messages(plugin, "sensor") if m["chart"]["mm"]][-1]
    assert pushed["status"]["preview"] and len(pushed["chart"]["mm"]) <= 150
    status, body = call(plugin.sensor.close, "/sensor/close", "POST")
    assert status == 200 and body["state"] == "idle" and not body["port_open"]
    assert plugin.sensor._cap is None


def test_a_printed_program_is_captured_analysed_and_stored(plugin, call, bar):
    use_sensor(plugin, call, bar.url)
    params_before = plugin.store.current()["params"]
    threads = []
    real = analyse

    def spy(*args, **kw):
        threads.append(threading.current_thread().name)
        return real(*args, **kw)

    status, prog = call(plugin.calibration.program, "/program", "POST", PROGRAM)
    assert status == 200 and prog["capture"]["armed"] and prog["capture"]["port"] == bar.url
    assert plugin.sensor.waiting
    plugin._printer.select_file.assert_called_once()
    with mock.patch("octoprint_kincomp.service.calibration.measurement.analyse", spy):
        bar.play(
            generate(SPEC).splitlines(),
            time.monotonic(),
            spec=SPEC,
            program_hash=prog["program_hash"],
        )
        run = finished_run(plugin)
    bar.stop()  # the test's own analysis below need not share the CPU with it
    # analysed as every measurement (issue 37): a job in the worker process, not in the
    # capture's thread, not in the comm thread, nor in the sensor's own
    assert "kincomp-sensor-ui" not in threads
    assert any(j.kind == "analyse" and j.state == "done" for j in plugin.jobs.jobs.values())
    assert run["status"] == "ok" and run["source"] == "live" and run["simulated"]
    assert run["capture"]["sensor"]["sensor_name"].startswith("KinComp virtual ballbar")
    assert run["capture"]["sensor"]["timing"] == "device clock"
    assert [r["direction"] for r in run["capture"]["runs"]] == ["ccw", "cw"]
    assert run["capture"]["program"] == prog["path"]
    # the stored raw stream gives the same result offline, exactly
    status, raw = call(plugin.sensor.raw, "/runs/x/raw", "GET", None, run["id"])
    assert status == 200
    trace, _ = trace_from_stream(parse_raw_stream(raw.decode()), SPEC, prog["program_hash"])
    status, stored = call(plugin.calibration.run_trace, "/runs/x/trace", "GET", None, run["id"])
    # the stored trace also says what the test ran with (issue 34): the firmware's own
    # compensation, here not reported (no M503 answer)
    origin = plugin.calibration.origin_for(trace.meta, captured=True)
    trace.meta["firmware_compensation"] = "unknown"
    assert stored.decode() == trace.to_text()
    offline = analyse(
        load_any(trace.to_text().encode(), "offline.csv"),
        current=Params.from_dict(run["params_before"]),
        **origin_kwargs(origin),
    )
    assert json.loads(json.dumps(offline["diagnostics"], default=float)) == run["diagnostics"]
    assert run["diagnostics"]["squareness_um_per_m"] == pytest.approx(-3638, abs=60)
    assert plugin.store.current()["params"] == params_before  # nothing applied
    assert run["proposed"] and not run["applied"]
    summary = plugin.runs.list()[0]
    assert summary["status"] == "ok" and summary["has_raw"] and summary["has_trace"]
    assert not plugin.sensor.waiting and plugin.sensor._cap is None  # no preview: closed
    plugin._printer.cancel_print.assert_not_called()


def test_an_unplugged_sensor_is_a_failed_run_with_its_data(plugin, call, bar):
    use_sensor(plugin, call, bar.url)
    status, prog = call(plugin.calibration.program, "/program", "POST", PROGRAM)
    assert prog["capture"]["armed"]
    bar.play(generate(SPEC).splitlines(), time.monotonic(), spec=SPEC)
    wait_for(lambda: plugin.sensor._cap.state == "capturing", 15)
    bar.unplug()
    run = finished_run(plugin)
    assert run["status"] == "failed" and "disconnected" in run["message"]
    assert run["message_i18n"]["template"].startswith("the sensor was disconnected")
    assert run["proposed"] is None and run["capture"]["samples"] > 100
    assert len(parse_raw_stream(open(plugin.runs.raw_path(run["id"])).read())) > 100
    note = [m for m in messages(plugin, "notify") if "capture failed" in m["text"]]
    assert note and note[-1]["severity"] == "error"
    for method in ("cancel_print", "pause_print"):  # the print is not affected
        getattr(plugin._printer, method).assert_not_called()
    # a failed run cannot be applied
    status, body = call(plugin.calibration.apply, "/apply", "POST", {"run": run["id"]})
    assert status == 400 and "no proposed parameters" in body["error"]
    assert plugin.runs.list()[0]["status"] == "failed"


def test_a_cancelled_print_stops_the_capture(plugin, call, bar):
    use_sensor(plugin, call, bar.url)
    call(plugin.sensor.open, "/sensor/open", "POST")
    status, prog = call(plugin.calibration.program, "/program", "POST", PROGRAM)
    wait_for(lambda: plugin.sensor._cap.state == "armed", 5)
    plugin.on_event("PrintStarted", {"origin": "local", "path": prog["path"]})
    plugin._printer.is_printing.return_value = False
    plugin.on_event("PrintCancelled", {"origin": "local", "path": prog["path"]})
    run = finished_run(plugin)
    assert run["status"] == "failed" and "stopped before the end" in run["message"]
    assert plugin.sensor._cap.state == "failed" and plugin.sensor._cap.status()["port_open"]


def test_the_end_marker_gives_the_data_a_grace_time(plugin, call, bar):
    """The program ended (its M117 marker was queued) but the data never shows its end."""
    use_sensor(plugin, call, bar.url)
    call(plugin.calibration.program, "/program", "POST", PROGRAM)
    plugin.sensor._grace = lambda: 0.5
    plugin.queuing_hook(object(), "queuing", "M117 Ballbar run ccw", None, "M117")
    time.sleep(0.8)
    assert plugin.sensor.waiting  # a run marker is not the end
    t0 = time.monotonic()
    plugin.queuing_hook(object(), "queuing", "M117 Ballbar test done", None, "M117")
    run = finished_run(plugin)
    assert 0.4 < time.monotonic() - t0 < 5.0
    assert run["status"] == "failed" and "stopped before the end" in run["message"]


def test_arm_and_stop_by_hand(plugin, call, bar, tmp_path):
    use_sensor(plugin, call, bar.url)
    program = tmp_path / "ballbar.gcode"
    program.write_text(generate(SPEC))
    plugin._file_manager.file_exists.return_value = True
    plugin._file_manager.path_on_disk.return_value = str(program)
    status, body = call(plugin.sensor.arm, "/sensor/arm", "POST", {"path": "ballbar.gcode"})
    assert status == 200 and body["armed"]["radius_mm"] == 30.0, body
    status, body = call(plugin.sensor.arm, "/sensor/arm", "POST", {"path": "ballbar.gcode"})
    assert status == 400 and "already running" in body["error"]
    wait_for(lambda: plugin.sensor._cap.state == "armed", 5)
    assert call(plugin.sensor.stop, "/sensor/stop", "POST")[0] == 200
    run = finished_run(plugin)
    assert run["status"] == "failed" and run["capture"]["program"] == "ballbar.gcode"
    program.write_text("G28\n")
    status, body = call(plugin.sensor.arm, "/sensor/arm", "POST", {"path": "ballbar.gcode"})
    assert status == 400 and "not a KinComp ballbar program" in body["error"]
    assert call(plugin.sensor.arm, "/sensor/arm", "POST", {})[0] == 400


def print_program(plugin, call, program, spec):
    """Write ``program`` through the program route and send it as OctoPrint would (comments
    stripped, through the queuing hook); returns the route's answer."""
    status, prog = call(plugin.calibration.program, "/program", "POST", program)
    assert status == 200, prog
    plugin.on_event("PrintStarted", {"origin": "local", "path": prog["path"]})
    queue_lines(plugin, generate(spec).splitlines(), plugin.prints.comm)
    return prog


def test_demo_mode_streams_the_virtual_bar_live(plugin, call):
    status, _ = call(plugin.settings_api.save, "/settings", "POST", {"demo": {"enabled": True}})
    assert status == 200 and plugin.demo.live
    prog = print_program(plugin, call, PROGRAM, SPEC)
    assert prog["capture"]["armed"] and prog["capture"]["source"] == "demo"
    assert prog["capture"]["port"].startswith("/dev/")  # a pseudo-terminal, through pyserial
    run = finished_run(plugin, timeout=60)
    assert run["status"] == "ok" and run["simulated"], run.get("message")
    assert run["capture"]["source"] == "demo"
    assert run["diagnostics"]["squareness_um_per_m"] == pytest.approx(-3638, abs=60)
    # the recorded fallback still works, without telling the UI a second time
    plugin._printer.is_printing.return_value = False
    plugin.on_event("PrintDone", {"origin": "local", "path": prog["path"]})
    wait_for(lambda: plugin.demo.last_trace() is not None, 30)
    time.sleep(0.2)
    assert not messages(plugin, "demo_trace")
    assert plugin.demo._sensor is None  # nobody reads it: the virtual bar stopped
    # live off: the fallback path as before
    call(plugin.settings_api.save, "/settings", "POST", {"demo": {"live": False}})
    assert plugin.store.current()["demo"] == {"enabled": True, "live": False}
    status, prog = call(plugin.calibration.program, "/program", "POST", PROGRAM)
    assert prog["capture"] is None


@pytest.mark.slow
def test_demo_captures_a_slow_vertical_test_live(plugin, call):
    """A vertical test at F200 takes the virtual bar seconds to simulate and its 1 s dwells
    are shorter than the step windows: the capture waits for the simulated stream's end
    (not for a guess made before it was known) and finds both runs."""
    call(plugin.settings_api.save, "/settings", "POST", {"demo": {"enabled": True}})
    program = {"plane": "XZ", "radius": 40, "centre": [110, 110, 60], "feed": 200, "print": True}
    spec = TestSpec(plane="XZ", centre=(110.0, 110.0, 60.0), radius_mm=40.0, feed_mm_min=200.0)
    prog = print_program(plugin, call, program, spec)
    assert prog["capture"]["source"] == "demo"
    run = finished_run(plugin, timeout=120)
    assert run["status"] == "ok", run.get("message")
    assert run["diagnostics"]["plane"] == "XZ" and run["capture"]["source"] == "demo"
