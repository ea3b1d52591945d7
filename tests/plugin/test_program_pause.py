"""A KinComp test program printed through the plugin's queuing hook (mocked OctoPrint, the
real hook, a real program file; issue 25): its mount and unmount pauses (M0) pause the
print without OctoPrint's "Suppressed command" warning, and a move sent as written during
it never advises homing (the ballbar is mounted)."""

import os
from unittest import mock

import pytest
from octoprint.util.comm import _normalize_command_handler_result

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.core.params import Params
from tests.support.mocked_plugin import mocked_plugin

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}})


class Comm:
    """What the hook asks of OctoPrint's MachineCom; records its pause requests."""

    def __init__(self):
        self.pauses = []

    def isPrinting(self):
        return not self.pauses

    def isPausing(self):
        return False

    def isPaused(self):
        return bool(self.pauses)

    def isResuming(self):
        return False

    def setPause(self, pause, local_handling=True, user=None, tags=None):
        self.pauses.append((pause, frozenset(tags or ())))


def _printing(plugin, tmp_path, text):
    path = os.path.join(str(tmp_path), "printed.gcode")
    with open(path, "w") as f:
        f.write(text)
    plugin._file_manager.path_on_disk.return_value = path
    plugin._printer.get_current_job.return_value = {
        "file": {"origin": "local", "path": "printed.gcode"}
    }
    return path


def _lines(text):
    """The lines as OctoPrint's reader hands them to the hooks (comments stripped)."""
    out = []
    for line in text.splitlines():
        line = line.split(";", 1)[0].strip()
        if line:
            out.append(line)
    return out


def _gcode(cmd):
    return cmd.split()[0].upper()


def _play(plugin, comm, lines):
    """Each line through the queuing hook as a printed file's: what the comm layer would
    send for each (after OctoPrint's normalisation of the hook's result)."""
    sent = {}
    for n, cmd in enumerate(lines, 1):
        tags = {"source:file", f"fileline:{n}"}
        res = plugin.queuing_hook(comm, "queuing", cmd, None, _gcode(cmd), tags=tags)
        sent[n] = _normalize_command_handler_result(cmd, None, _gcode(cmd), None, tags, res)
    return sent


@pytest.fixture
def plugin(tmp_path):
    p = mocked_plugin(str(tmp_path))
    p.on_settings_save({"enabled": True, "params": SKEW.to_dict()})
    return p


def _program():
    spec = TestSpec(
        plane="XY", centre=(100.0, 100.0, 5.0), radius_mm=50.0, feed_mm_min=1000.0, mount_pause=True
    )
    return generate(spec, volume=(0, 200, 0, 200, 0, 200))


def _notices(plugin):
    calls = plugin._plugin_manager.send_plugin_message.call_args_list
    return [c[0][1].get("text", "") for c in calls if isinstance(c[0][1], dict)]


def test_a_test_programs_pauses_pause_the_print_without_the_blocked_warning(plugin, tmp_path):
    text = _program()
    _printing(plugin, tmp_path, text)
    lines = _lines(text)
    pauses = [n for n, line in enumerate(lines, 1) if _gcode(line) == "M0"]
    assert len(pauses) == 2  # mount and unmount
    comm = Comm()
    sent = _play(plugin, comm, lines)
    for n in pauses:
        # dropped here: OctoPrint's own handler (which blocks it with the warning) never runs
        assert sent[n] == [], lines[n - 1]
    # the print was paused at the first (mount) pause, by KinComp, tagged as such; the
    # second came while paused in this replay (no second pause request)
    assert comm.pauses and comm.pauses[0][0] is True
    assert "plugin:kincomp" in comm.pauses[0][1] and "source:plugin" in comm.pauses[0][1]
    # every other line still goes out
    assert all(sent[n] for n in sent if n not in pauses)


def test_pauses_of_other_files_and_of_a_firmware_that_pauses_itself_are_left_to_octoprint(
    plugin, tmp_path
):
    # not a KinComp program: OctoPrint handles its M0 as before
    _printing(plugin, tmp_path, "G28\nG1 X10 Y10 F3000\nM0 change the filament\nG1 X20\n")
    comm = Comm()
    sent = _play(plugin, comm, ["G28", "G1 X10 Y10 F3000", "M0 change the filament"])
    assert sent[3] == [("M0 change the filament", None, "M0", None, {"source:file", "fileline:3"})]
    assert comm.pauses == []
    # a KinComp program, but the user took M0 out of OctoPrint's blocked commands (the
    # firmware pauses with its own button): sent to the printer, OctoPrint decides
    plugin._settings.global_set(["serial", "blockedCommands"], ["M1"])
    text = _program()
    _printing(plugin, tmp_path, text)
    comm = Comm()
    lines = _lines(text)
    sent = _play(plugin, comm, lines)
    first_m0 = next(n for n, line in enumerate(lines, 1) if _gcode(line) == "M0")
    assert sent[first_m0] and sent[first_m0][0][0].startswith("M0")
    assert comm.pauses == []


def test_a_move_sent_as_written_during_a_test_program_never_advises_homing(plugin, tmp_path):
    text = _program()
    _printing(plugin, tmp_path, text)
    _play(plugin, Comm(), _lines(text)[:8])  # the lift goes out before the position is known
    said = [t for t in _notices(plugin) if "as written" in t or "uncompensated" in t]
    assert said, _notices(plugin)
    assert not any("G28" in t or "Home the printer" in t for t in said), said
    assert "Do not home the printer while the ballbar is mounted" in said[-1]
    assert "'G1 Z10 F600'" in said[-1]


def test_outside_a_test_program_the_advice_still_says_to_home(plugin, tmp_path):
    _printing(plugin, tmp_path, "G91\nG1 Z10 F600\n")
    with mock.patch(
        "octoprint_kincomp.plugin.printing.print_state.time.monotonic", return_value=5e3
    ):
        _play(plugin, Comm(), ["G91", "G1 Z10 F600"])
    said = [t for t in _notices(plugin) if "uncompensated" in t]
    assert said and "Home the printer (G28)" in said[-1]
