"""The sensor commands of the CLI: a live capture from the virtual sensor through a pty, the
same trace again offline from the saved raw stream, and clear errors. SIMULATED data."""

import threading

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.cli import main
from octoprint_kincomp.sensor.virtual import VirtualSensor


def test_sensor_capture_and_the_same_trace_offline(tmp_path, capsys):
    prog = tmp_path / "prog.gcode"
    prog.write_text(generate(TestSpec()))
    vs = VirtualSensor(speedup=20.0)
    url = vs.start()
    player = threading.Timer(0.8, lambda: vs.play(prog.read_text().splitlines()))
    player.start()
    try:
        trace, raw, again = tmp_path / "t.csv", tmp_path / "raw.csv", tmp_path / "t2.csv"
        assert (
            main(
                [
                    "sensor-capture",
                    url,
                    str(prog),
                    "--preview-s",
                    "0.5",
                    "-o",
                    str(trace),
                    "--raw",
                    str(raw),
                ]
            )
            == 0
        )
    finally:
        player.join()
        vs.stop()
    assert "captured" in capsys.readouterr().err
    assert main(["sensor-trace", str(raw), str(prog), "-o", str(again)]) == 0
    assert trace.read_text() == again.read_text()  # live and offline: the same trace
    assert "source: SIMULATED live capture" in trace.read_text()
    assert main(["analyze", str(trace)]) == 0
    assert "squareness_um_per_m" in capsys.readouterr().out


def test_sensor_command_errors(tmp_path, capsys):
    prog = tmp_path / "prog.gcode"
    prog.write_text(generate(TestSpec()))
    assert main(["sensor-capture", "/dev/ttyKINCOMP-none", str(prog), "--preview-s", "0"]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert main(["sensor-capture", "loop://", str(prog), "--rate", "0.5"]) == 1
    assert "--rate: sample_rate_hz must be 0" in capsys.readouterr().err
    bad = tmp_path / "raw.csv"
    bad.write_text("# kind: ballbar raw stream\ntime_s,reading_mm,line\n0.1,abc,3\n")
    assert main(["sensor-trace", str(bad), str(prog)]) == 1
    assert "line 3: expected time_s,reading_mm,line" in capsys.readouterr().err
    assert main(["sensor-trace", str(bad), str(tmp_path / "nope.gcode")]) == 1
    assert "No such file" in capsys.readouterr().err
    assert main(["sensor-ports"]) == 0
