"""The connection and the print on it, as KinComp follows them.

* A new connection (OctoPrint makes a new comm object per connect) or a disconnect: nothing
  about the printer's position or firmware is known any more. The print's state belongs to
  the connection it was made for: a connection replaced or closed is retired, and what its
  threads still hand the hooks afterwards (an old monitor thread ends up to 30 s after the
  disconnect, with one last empty line) changes nothing: it is not taken for a new
  connection, which would forget the new print's position. The DISCONNECTED event itself
  reaches KinComp on OctoPrint's event thread, which on a busy machine can be after the
  next connection's first commands: when the connection in force is open then, the event
  was the old one's (retired already) and changes nothing. Taken as it came, it retired the
  new connection, whose every line then passed untouched: no compensation, no test
  program's pause, no demo trace until the next connect.
* A print begins when its first file line reaches the queuing hook (file reader thread) or
  when PRINT_STARTED arrives (event thread), whichever comes first; both are counted under
  one lock, so that one print begins once and an end event of the previous print that
  arrives after the next print's first line is recognised as late. At the beginning the
  file's KinComp marker decides whether its lines are passed through (pre-compensated); a
  file compensated with other parameters (another printer profile's) is said, not refused.
* After a compensation error the print is paused and its moves are held back until the user
  resumes; PRINT_RESUMED comes only after OctoPrint has started sending again, so the hook
  follows the printer state (paused once, then printing again means resumed).
* Moves sent as written (position unknown, malformed) are logged and notified at most once
  a minute, with how many went out since (never a log line per move: that halved the
  print's line rate); so are prints from, and transfers to, the printer's SD card (KinComp
  never sees their lines). During a KinComp test program (its ``; ballbar plane:`` header)
  the advice never says to home: the ballbar is mounted.
* A test program's pauses (to mount and unmount the bar): ``M0``/``M1`` when OctoPrint would
  pause at them and not send them anyway (its serial settings ``pausingCommands`` and
  ``blockedCommands``): KinComp pauses the print itself and drops the line, so that
  OctoPrint raises no "Suppressed command" warning for each of them. The pauses of a program
  for Klipper (``PAUSE``) and RepRapFirmware (``M291 S2``, ``M226``) are always taken here
  the same way and never sent: OctoPrint does not know them as pauses, Klipper's ``PAUSE``
  would pause the print once (``action:paused``) and then answer the unmount pause with
  "Print already paused" (only its ``RESUME`` clears it, which OctoPrint does not send), and
  RepRapFirmware's message box does not hold a USB stream (its ``M226`` is refused off its own
  SD card).
"""

from __future__ import annotations

import threading
import time
import weakref
from typing import Any, Callable, Dict, List, Optional

from octoprint.events import Events
from octoprint.filemanager import FileDestinations

from ...calibration.ballbar.program import ProgramError, is_pause, spec_from_program
from ...core.marker import file_marker
from ...service.notify import N_, Notifier
from ...service.printing.firmware_watch import FirmwareWatcher
from ...service.printing.queue import QueueCompensator, notify_edge

# handled under the print lock, against the queuing hook's view of the print
PRINT_EVENTS = frozenset(
    {
        Events.DISCONNECTED,
        Events.PRINT_STARTED,
        Events.PRINT_DONE,
        Events.PRINT_FAILED,
        Events.PRINT_CANCELLED,
    }
)
UNTOUCHED_NOTICE_S = 60.0  # at most one "sent as written" notification per this many s
PROGRAM_HEAD_LINES = 60  # a test program's ``; ballbar key: value`` header is within these
PROGRAM_PAUSE_TAGS = frozenset({"source:plugin", "plugin:kincomp", "trigger:kincomp.program_pause"})
RETIRED_KEPT = 8  # connections remembered as retired (OctoPrint makes one per connect)


class _Retired:
    """The connections (comm objects) that were replaced or closed: weakly held where the
    object allows it, the last RETIRED_KEPT of them."""

    def __init__(self):
        self._refs: List[Any] = []

    def add(self, comm) -> None:
        if comm is None or comm in self:
            return
        try:
            ref = weakref.ref(comm)
        except TypeError:  # (a plain object() in tests)
            ref = lambda comm=comm: comm  # noqa: E731
        self._refs = [r for r in self._refs if r() is not None][-(RETIRED_KEPT - 1) :] + [ref]

    def __contains__(self, comm) -> bool:
        return comm is not None and any(r() is comm for r in self._refs)


class PrintState:
    """Print begins and ends for ``queue``; ``on_begin(payload)`` and ``on_end(done)`` run
    after the queue has taken a print's beginning or end (``done``: it completed)."""

    def __init__(
        self,
        queue: QueueCompensator,
        watch: FirmwareWatcher,
        printer,
        file_manager,
        notifier: Notifier,
        logger,
        on_begin: Callable[[Dict[str, Any]], None],
        on_end: Callable[[bool], None],
    ):
        self._queue = queue
        self._watch = watch
        self._printer = printer
        self._file_manager = file_manager
        self._notifier = notifier
        self._logger = logger
        self._on_begin = on_begin
        self._on_end = on_end
        # The print's start is seen by the queuing hook (file reader thread) and by
        # PRINT_STARTED (event thread), in either order: decisions and their effects on the
        # print state are made under this lock, or both threads could begin one print and
        # every later end event would look like a late one.
        self.lock = threading.RLock()
        self.begun = 0  # prints whose first line (or start event) was handled
        self.start_events = 0  # PRINT_STARTED events received
        # a line of the current print went through the hook (never while the queue is not
        # printing: cleared where a print ends)
        self.file_lines_seen = False
        self.comm = None  # the MachineCom of the current connection
        self.pause_seen = False
        self.warned_unknown_at = 0.0  # time.monotonic() of the last such notification
        self.untouched_unsaid = 0  # moves sent as written since the last such notification
        self._retired = _Retired()  # connections replaced or closed
        self.test_program = False  # the current print is a KinComp ballbar test program
        # OctoPrint's serial settings: the commands it pauses at and does not send
        self.pausing_commands: frozenset = frozenset()
        self.blocked_commands: frozenset = frozenset()
        # (params hash) -> names of the printer profiles with those parameters (None: unknown)
        self.compensated_for: Optional[Callable[[str], List[str]]] = None

    # ~~ the connection ------------------------------------------------------------------------
    def current(self, comm_instance) -> bool:
        """A hook call from ``comm_instance``: True if it belongs to the connection in force
        (a new connection becomes it: ``connection_changed``), False for a retired one (its
        line must change nothing)."""
        if comm_instance is self.comm:
            return True
        if comm_instance in self._retired:
            return False
        self.connection_changed(comm_instance)
        return True

    def connection_changed(self, comm_instance) -> None:
        """A new connection: nothing about the printer's position or firmware is known any
        more, and the previous connection is retired. Called by the hooks, synchronously, as
        CONNECTED reaches ``on_event`` only after the first commands may have gone out."""
        self._retired.add(self.comm)
        self.comm = comm_instance
        self._queue.reset()
        self._watch.reset()

    # ~~ from the queuing hook -----------------------------------------------------------------
    def file_line(self, tags) -> None:
        """A line of a printed file (tags hold ``source:file``) is about to be handled."""
        if self.file_lines_seen and "fileline:1" not in tags:
            return  # a line of a print under way: under the lock it changes nothing either
        with self.lock:
            if not self._queue.printing or ("fileline:1" in tags and self.file_lines_seen):
                # the first line of a print: PRINT_STARTED may be delivered later, on the
                # event thread, so the print's state is set up here, before its first line
                # is handled (also when the previous print's end event is still pending)
                self._print_begins(self._current_job())
            self.file_lines_seen = True

    def follow_pause(self, comm_instance) -> None:
        """While the queue is halted after a compensation error: paused (or pausing) once,
        then printing again means the user resumed."""
        try:
            if comm_instance.isPausing() or comm_instance.isPaused():
                self.pause_seen = True
            elif self.pause_seen and (comm_instance.isPrinting() or comm_instance.isResuming()):
                self.resumed()
        except AttributeError:  # not a MachineCom (tests): the event does it
            pass

    def program_pause(self, comm_instance, cmd: str, gcode, tags) -> bool:
        """A line of the print (``cmd``, ``gcode`` as OctoPrint parsed it, ``tags``) is a test
        program's pause that OctoPrint would pause at and block anyway (M0/M1), or one of
        another firmware's that OctoPrint does not know (Klipper's PAUSE, RepRapFirmware's
        M291 S2 or M226; see the module docstring): the print is paused here (as OctoPrint
        would) and True says to drop the line, without OctoPrint's "Suppressed command"
        warning. False: leave the line to OctoPrint."""
        if not (self.test_program and tags and "source:file" in tags):
            return False
        if gcode in ("M0", "M1"):
            if gcode not in self.pausing_commands or gcode not in self.blocked_commands:
                return False  # the user lets the firmware pause (or OctoPrint ignores it)
        elif not is_pause(cmd or ""):
            return False
        gcode = gcode or (cmd or "").split(None, 1)[0]
        if "trigger:cancel" in tags or "trigger:pause" in tags:
            return False
        try:
            if comm_instance.isPrinting():
                comm_instance.setPause(True, tags=set(PROGRAM_PAUSE_TAGS))
        except AttributeError:  # not a MachineCom: leave it to OctoPrint
            return False
        self._logger.info("KinComp: the test program pauses at %s (the line is not sent)", gcode)
        return True

    # ~~ from OctoPrint's events ---------------------------------------------------------------
    def on_event(self, event, payload: Dict[str, Any]) -> None:
        """One of PRINT_EVENTS."""
        with self.lock:  # against the queuing hook's view of the print
            if event == Events.DISCONNECTED:
                if self._comm_open():  # late: a new connection took over (the docstring)
                    self._logger.info("KinComp: an earlier connection's disconnect, seen late")
                    return
                self._retired.add(self.comm)
                self.comm = None
                self._queue.reset()
                self._watch.reset()
                self.file_lines_seen = False  # (first: the hook reads it without the lock)
                if self._queue.printing:
                    self._queue.print_ended()
            elif event == Events.PRINT_STARTED:
                self.start_events += 1
                if payload.get("origin") == FileDestinations.SDCARD and self._queue.enabled:
                    self._notifier.notify(
                        "warning",
                        N_(
                            "This print runs from the printer's SD card: KinComp cannot "
                            "compensate it."
                        ),
                    )
                if self.begun < self.start_events:  # not seen by the queuing hook
                    self._print_begins(payload)
            else:  # the print is done, failed or cancelled
                if self.begun > self.start_events and self._printing_now():
                    return  # late: the next print's first line was already handled
                # (if the counts ever drifted apart, an end with nothing printing resyncs them)
                self.start_events = self.begun
                self.file_lines_seen = False  # (first: the hook reads it without the lock)
                edge = self._queue.print_ended()
                if edge:
                    self._logger.warning("KinComp: at the travel's edge in this print: %s", edge)
                notify_edge(self._notifier, edge, None)
                self._on_end(event == Events.PRINT_DONE)

    def transfer_started(self) -> None:
        """TRANSFER_STARTED: a file is streamed to the printer's SD card."""
        if self._queue.enabled:
            self._notifier.notify(
                "warning",
                N_(
                    "Files streamed to the printer's SD card are not compensated; compensate "
                    "them on upload first."
                ),
            )

    def paused(self) -> None:
        """PRINT_PAUSED."""
        if self._queue.halted:
            self.pause_seen = True

    def resumed(self) -> None:
        """The print resumed (PRINT_RESUMED, or seen by the hook): after a compensation
        error, moves are compensated again."""
        q = self._queue
        if not q.halted:
            return
        self._logger.warning(
            "KinComp: print resumed after a compensation error; %d moves were held back",
            q.held_moves,
        )
        q.resume()
        self.pause_seen = False
        self.warned_unknown_at = 0.0  # the position is unknown now: say so again

    # ~~ the queue's reports -------------------------------------------------------------------
    def compensation_failed(self, cmd: str, exc: Exception) -> None:
        """The queue could not compensate ``cmd``: sent as written if the user chose so,
        else not sent, and a running print is paused."""
        passed = self._queue.pass_through_on_error
        self._logger.error(
            "KinComp could not compensate %r: %s (%s)",
            cmd,
            exc,
            "sent as written" if passed else "not sent",
        )
        if passed:
            self._notifier.notify(
                "warning",
                N_("KinComp could not compensate '%(cmd)s' (%(err)s); it was sent as written."),
                cmd=cmd,
                err=str(exc),
            )
            return
        if self._printer.is_printing():
            self._printer.pause_print(tags={"plugin:kincomp"})
            self._notifier.notify(
                "error",
                N_(
                    "KinComp could not compensate '%(cmd)s': %(err)s. The command was not sent "
                    "and the print is paused; moves queued until the pause are held back too. "
                    "Cancel the print, or resume to continue without them."
                ),
                cmd=cmd,
                err=str(exc),
            )
        else:
            self._notifier.notify(
                "error",
                N_("KinComp could not compensate '%(cmd)s': %(err)s. The command was not sent."),
                cmd=cmd,
                err=str(exc),
            )

    def sent_as_written(self, cmd: str, why: str) -> None:
        """A move went out as written: its start position is not known (no G28 since
        connecting, probing, a compensation error), or it is malformed. Never silent, never
        a log line per move (a print of unknown position would log every line, at half its
        rate): logged and notified at most once a minute, with how many went out since."""
        self.untouched_unsaid += 1
        now = time.monotonic()
        if now - self.warned_unknown_at < UNTOUCHED_NOTICE_S:
            return
        self.warned_unknown_at = now
        count, self.untouched_unsaid = self.untouched_unsaid, 0
        if why == "malformed":
            self._logger.warning(
                "KinComp: malformed move %r sent as written; position forgotten until the next "
                "G28 or absolute move (%d moves sent as written since the last report)",
                cmd,
                count,
            )
        else:
            self._logger.warning(
                "KinComp: %r sent uncompensated: position unknown (%d moves sent as written "
                "since the last report; said at most once a minute)",
                cmd,
                count,
            )
        if why == "malformed":
            self._notifier.notify(
                "warning",
                N_(
                    "KinComp could not read the move '%(cmd)s' and sent it as written; moves are "
                    "compensated again once the position is known (G28 or an absolute move)."
                ),
                cmd=cmd,
            )
        elif self.test_program:  # the ballbar is mounted: homing now would break it
            # a line in the tab, no pop-up: nothing for the user to do (each test's first
            # move does this while the position is not known yet)
            self._notifier.notify(
                "status",
                N_(
                    "KinComp sent the test program's '%(cmd)s' as written because the printer's "
                    "position was not known yet; the program's moves to absolute positions that "
                    "follow are compensated. Do not home the printer while the ballbar is "
                    "mounted."
                ),
                cmd=cmd,
            )
        else:
            self._notifier.notify(
                "warning",
                N_(
                    "KinComp sent '%(cmd)s' uncompensated because the printer's position is "
                    "unknown. Home the printer (G28) so that moves can be compensated."
                ),
                cmd=cmd,
            )

    # ~~ inside ----------------------------------------------------------------------------------
    def _comm_open(self) -> bool:
        """The connection in force is open: a DISCONNECTED now is an earlier connection's."""
        try:
            return self.comm is not None and not self.comm.isClosedOrError()
        except AttributeError:  # not a MachineCom (tests): the event is taken as it comes
            return False

    def _print_begins(self, payload: Dict[str, Any]) -> None:
        """A print starts: fresh state, its marker checked. Counted, so that a PrintDone of
        the previous print that arrives after this print's first line is recognised."""
        self.begun += 1
        self.file_lines_seen = False
        marked = self._is_precompensated(payload)
        self.test_program = self._is_test_program(payload)
        self._queue.print_started(marked)
        self.warned_unknown_at = 0.0
        self.pause_seen = False
        self._on_begin(payload)

    def _current_job(self) -> Dict[str, Any]:
        try:
            f = (self._printer.get_current_job() or {}).get("file") or {}
        except Exception:
            f = {}
        return {"origin": f.get("origin"), "path": f.get("path")}

    def _printing_now(self) -> bool:
        """A print is under way (printing, pausing or paused)."""
        try:
            p = self._printer
            return bool(p.is_printing() or p.is_pausing() or p.is_paused())
        except Exception:
            return True

    def _is_test_program(self, payload: Dict[str, Any]) -> bool:
        """The printed file is a KinComp ballbar test program (its header says so)."""
        if payload.get("origin") != FileDestinations.LOCAL or not payload.get("path"):
            return False
        try:
            disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, payload["path"])
            with open(disk, encoding="utf-8", errors="replace") as f:
                head = "".join(line for _, line in zip(range(PROGRAM_HEAD_LINES), f))
            spec_from_program(head)
        except (OSError, TypeError, ValueError, KeyError, ProgramError):
            return False
        return True

    def _is_precompensated(self, payload: Dict[str, Any]) -> bool:
        if payload.get("origin") != FileDestinations.LOCAL or not payload.get("path"):
            return False
        try:
            disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, payload["path"])
            h = file_marker(disk)
        except Exception:
            return False
        now = self._queue.params.hash()
        if h is not None and h != now:
            self._other_parameters(payload["path"], h, now)
        return h is not None

    def _other_parameters(self, path: str, old: str, now: str) -> None:
        """A marked file compensated with other parameters than those in force: said (a
        warning in the UI and the log), naming the printer profile it was compensated for
        when one has those parameters. It prints as it is (never compensated twice)."""
        printers = self.compensated_for(old) if self.compensated_for is not None else []
        if printers:
            self._logger.warning(
                "KinComp: %s was compensated for printer profile %s (parameters %s), not "
                "for the one in force (%s): it prints with that printer's corrections",
                path,
                ", ".join(printers),
                old,
                now,
            )
            self._notifier.notify(
                "warning",
                N_(
                    "This file was compensated for printer profile %(printer)s (parameters "
                    "%(old)s), not for the printer in force (%(new)s): it prints as it is, "
                    "with that printer's corrections and without this one's. Compensate "
                    "the original file for this printer instead."
                ),
                printer=", ".join(printers),
                old=old,
                new=now,
            )
            return
        self._logger.warning(
            "KinComp: %s was compensated with other parameters (%s, now %s); it prints as "
            "compensated then",
            path,
            old,
            now,
        )
        self._notifier.notify(
            "warning",
            N_(
                "This file was compensated with other KinComp parameters (%(old)s, now "
                "%(new)s); it prints as compensated then."
            ),
            old=old,
            new=now,
        )
