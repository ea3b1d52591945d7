"""PrintState on its own (a real queue, mocked printer and file manager): a print begins
and ends once whatever order the hook and the events come in, the pause after a
compensation error is followed from the printer state, and moves sent as written are
notified at most once a minute."""

from types import SimpleNamespace
from unittest import mock

import pytest

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.plugin.printing.print_state import PrintState
from octoprint_kincomp.service.notify import Notifier
from octoprint_kincomp.service.printing.firmware_watch import FirmwareWatcher
from octoprint_kincomp.service.printing.queue import QueueCompensator

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}})
FIRST = {"source:file", "fileline:1"}
JOB = {"origin": "local", "path": "a.gcode"}


class Comm:
    """What PrintState asks of OctoPrint's MachineCom."""

    def __init__(self):
        self.state = "printing"

    def isPausing(self):
        return self.state == "pausing"

    def isPaused(self):
        return self.state == "paused"

    def isPrinting(self):
        return self.state == "printing"

    def isResuming(self):
        return self.state == "resuming"


@pytest.fixture
def t():
    queue = QueueCompensator(
        SKEW, Options(limits=(0, 200, 0, 200, 0, 200), policy="error"), enabled=True
    )
    printer, files, plugin_manager = mock.MagicMock(), mock.MagicMock(), mock.MagicMock()
    printer.is_printing.return_value = True
    printer.is_pausing.return_value = printer.is_paused.return_value = False
    printer.get_current_job.return_value = {"file": dict(JOB)}
    files.path_on_disk.side_effect = OSError("not on disk")  # never marked
    begun, ended = [], []
    watch = FirmwareWatcher()
    state = PrintState(
        queue,
        watch,
        printer,
        files,
        Notifier(plugin_manager, None, "kincomp"),
        mock.MagicMock(),
        on_begin=begun.append,
        on_end=ended.append,
    )
    queue.on_error = state.compensation_failed
    queue.on_untouched = state.sent_as_written
    return SimpleNamespace(
        queue=queue,
        printer=printer,
        state=state,
        begun=begun,
        ended=ended,
        watch=watch,
        plugin_manager=plugin_manager,
    )


def texts(t):
    return [c[0][1]["text"] for c in t.plugin_manager.send_plugin_message.call_args_list]


def test_the_first_line_or_the_start_event_begins_a_print_once(t):
    t.state.file_line(FIRST)
    t.state.file_line({"source:file", "fileline:2"})
    t.state.on_event("PrintStarted", dict(JOB))  # late: the hook saw the print begin
    assert t.begun == [JOB] and t.queue.printing and t.state.begun == t.state.start_events == 1
    t.state.on_event("PrintDone", dict(JOB))
    assert t.ended == [True] and not t.queue.printing
    # the event first this time, then the first line: still one beginning
    t.state.on_event("PrintStarted", dict(JOB))
    t.state.file_line(FIRST)
    assert t.begun == [JOB, JOB]
    t.state.on_event("PrintCancelled", dict(JOB))
    assert t.ended == [True, False]


def test_an_end_event_after_the_next_prints_first_line_is_ignored(t):
    t.state.on_event("PrintStarted", dict(JOB))
    t.state.file_line(FIRST)
    t.state.file_line(FIRST)  # the next print's first line, before the end event
    t.state.on_event("PrintDone", dict(JOB))  # late
    assert t.ended == [] and t.queue.printing
    t.state.on_event("PrintStarted", dict(JOB))
    t.state.on_event("PrintDone", dict(JOB))
    assert t.ended == [True] and not t.queue.printing


def test_a_new_connection_or_a_disconnect_forgets_the_printer(t):
    def homed_and_skewed():
        t.queue.handle("G28")
        t.watch.received("echo:  M852 I0.0010 J0.0000 K0.0000")
        assert t.queue.comp.known == (True, True, True) and t.watch.skew

    first = Comm()
    t.state.connection_changed(first)
    homed_and_skewed()
    t.state.connection_changed(Comm())
    assert t.state.comm is not first and t.queue.comp.known == (False, False, False)
    assert t.watch.skew is None
    t.state.file_line(FIRST)
    homed_and_skewed()
    t.state.on_event("Disconnected", {})
    assert t.state.comm is None and t.queue.comp.known == (False, False, False)
    assert t.watch.skew is None and not t.queue.printing


def test_a_resume_after_an_error_is_seen_in_the_printer_state(t):
    comm = Comm()
    t.state.file_line(FIRST)
    t.queue.handle("G28", FIRST)
    assert t.queue.handle("G1 X0 Y100 Z1", {"source:file"}) == []  # outside: refused
    t.printer.pause_print.assert_called_once()
    assert t.queue.halted and "print is paused" in texts(t)[-1]
    t.state.follow_pause(comm)  # still printing: OctoPrint has not paused yet
    assert t.queue.halted
    comm.state = "paused"
    t.state.follow_pause(comm)
    comm.state = "resuming"
    t.state.follow_pause(comm)
    assert not t.queue.halted and not t.state.pause_seen


def test_a_resume_event_lifts_the_hold_too(t):
    t.state.file_line(FIRST)
    t.queue.handle("G28", FIRST)
    t.queue.handle("G1 X0 Y100 Z1", {"source:file"})
    t.state.paused()
    assert t.state.pause_seen
    t.state.resumed()
    assert not t.queue.halted


def test_errors_outside_a_print_or_passed_through_do_not_pause(t):
    t.printer.is_printing.return_value = False
    t.queue.handle("G28")
    t.queue.handle("G1 X0 Y100 Z1")
    assert not t.printer.pause_print.called and texts(t)[-1].endswith("was not sent.")
    t.queue.pass_through_on_error = True
    t.queue.handle("G28")
    assert t.queue.handle("G1 X0 Y100 Z1") is None
    assert not t.printer.pause_print.called and texts(t)[-1].endswith("sent as written.")


def test_moves_sent_as_written_are_notified_at_most_once_a_minute(t):
    with mock.patch("octoprint_kincomp.plugin.printing.print_state.time.monotonic") as clock:
        clock.return_value = 1000.0
        t.state.sent_as_written("G1 X5", "unknown")
        clock.return_value = 1059.0
        t.state.sent_as_written("G1 X6 Q", "malformed")
        assert len(texts(t)) == 1 and "position is unknown" in texts(t)[0]
        clock.return_value = 1061.0
        t.state.sent_as_written("G1 X6 Q", "malformed")
        assert len(texts(t)) == 2 and "could not read the move 'G1 X6 Q'" in texts(t)[1]
        t.state.on_event("PrintStarted", dict(JOB))  # a new print: said again at once
        t.state.sent_as_written("G1 X7", "unknown")
        assert len(texts(t)) == 3


def test_sd_card_prints_and_transfers_are_said_to_be_uncompensated(t):
    t.state.transfer_started()
    t.state.on_event("PrintStarted", {"origin": "sdcard", "path": "a.gco"})
    assert len(texts(t)) == 2 and all("SD card" in text for text in texts(t))
    t.queue.set_enabled(False)
    t.state.transfer_started()
    assert len(texts(t)) == 2
