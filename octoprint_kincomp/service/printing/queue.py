"""The compensator as OctoPrint's queuing hook sees it (no OctoPrint import here).

OctoPrint calls the hook once per outgoing command, comments already stripped, from the
thread that queues it (an API request or the file reader), so calls are serialised here.
Resends never come back through the hook, so nothing is ever compensated twice on resend.

* ``handle(cmd, tags)`` returns None (send unchanged), or the list of replacement commands
  (strings; the M114 after a G28 as OctoPrint's ``(command, type, tags)`` with a numbered tag).
* Lines of a print whose file was already compensated (it starts with KinComp's marker) are
  passed through untouched.
* If compensation fails on a line, the line is not sent: ``on_error`` is called (the plugin
  pauses the print and tells the user) and an empty list suppresses it - unless the user
  chose "pass through on error", then it is sent as written and reported. After such a
  failure during a print the adapter is *halted*: the print's own moves (``source:file``/
  ``source:job``) that OctoPrint still queues before the pause takes effect are held back
  too (counted in ``held_moves``), so none goes out uncompensated; scripts (pause parking)
  and manual commands are still compensated. ``resume()`` (the print resumed), the end of
  the print or a reset lifts it.
* A move sent as written is never silent: ``on_untouched(cmd, why)`` is called for a move
  whose start position is unknown (``"unknown"``) and for a malformed move (``"malformed"``:
  it passes through as the firmware may still execute it, and the tracked position is
  forgotten, so later moves are not computed from a wrong start).
* Where the printer homes may be unknown (the setting ``home_mm``: None, the default): a
  G28 then leaves the homed axes unknown and is followed by an ``M114``; the firmware's
  position report after it (``home_query_sent`` with the tags of the M114 being sent, then
  ``home_reported`` from the received hook) makes them known where the printer really is.
  Until then a move that needs them goes out as written, so no correction can move the
  head by more than itself. The M114 is
  queued right behind the G28, so its report gives the homed position even when the file
  reader queues more lines before the answer is read; a line queued meanwhile that moves or
  re-frames a homed axis (G0/G1 or G92 naming it) takes that axis out of the learning (the
  report is stale for it), a tool change, an arc or a probing move takes all of them out.
* New parameters, and switching compensation on or off, apply at the next print start
  (``apply_changes = next_print``) or at once: turning it on or off in the middle of a print
  would shift every later move by the correction (a seam). Either way the new model takes
  over the tracked state (positions do not depend on it).
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from typing import Callable, Dict, List, Optional, Tuple

from ...core.compensator import LimitError, Options
from ...core.gcode import parse_command
from ...core.gcode_table import (
    ARC,
    DROP_OFFSETS,
    HOME,
    LINEAR,
    LOSES,
    SET_POSITION,
    TOOL,
    VARIANT,
    classify,
)
from ...core.modal import g92_axes, homed_axes, named_axes
from ...core.params import Params
from ...engines.contract import line_route
from ...engines.select import make_compensator
from ..notify import N_

FILE_TAG = "source:file"
JOB_TAG = "source:job"
_MOTION = re.compile(r"\s*[Gg]0*[0-3](?![0-9.])")
HOME_QUERY = "M114"  # sent after a G28 whose home position is not known
HOME_QUERY_TAG = "kincomp:home_query:"  # + its number: which question is being sent
# the classes of lines that may move or re-frame any axis (for a pending home question)
_STALE_FOR_ALL = frozenset({ARC, DROP_OFFSETS, LOSES, TOOL, VARIANT})


_log = logging.getLogger(__name__)


def _call(callback, *args) -> None:
    """Run a notification callback; its failure must not escape the hook (OctoPrint would
    then send the original, uncompensated line)."""
    try:
        callback(*args)
    except Exception:
        _log.exception("KinComp: notification callback failed")


def command_of(entry) -> str:
    """The command of an entry of ``handle``'s result (a string, or the tagged M114)."""
    return entry if isinstance(entry, str) else entry[0]


def home_query_number(tags) -> Optional[int]:
    """The number of our M114 from its tags (None: not ours)."""
    for tag in tags or ():
        if tag.startswith(HOME_QUERY_TAG):
            try:
                return int(tag[len(HOME_QUERY_TAG) :])
            except ValueError:
                return None
    return None


class _Gated:
    """A QueueCompensator attribute whose every change re-decides the kernel route (reads
    find the value in the instance: no ``__get__``)."""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __set__(self, obj: QueueCompensator, value) -> None:
        obj.__dict__[self.name] = value
        obj._reroute()


class QueueCompensator:
    def __init__(
        self,
        params: Params,
        options: Options,
        enabled: bool = False,
        pass_through_on_error: bool = False,
        on_error: Optional[Callable[[str, Exception], None]] = None,
        on_untouched: Optional[Callable[[str, str], None]] = None,
    ):
        self._lock = threading.RLock()
        # (the gated attributes, set before the route is first decided in _use)
        vars(self).update(enabled=enabled, skip_file=False, halted=False, awaiting_home=())
        self.pass_through_on_error = pass_through_on_error
        self.on_error = on_error
        self.on_untouched = on_untouched
        self._use(make_compensator(params, options))
        self.pending: Optional[Tuple[Params, Options, bool]] = None  # waits for a print end
        self.printing = False
        self.errors = 0
        self.last_error: Optional[Dict[str, object]] = None
        self.passed_on_error = 0
        self.held_moves = 0
        self.home_query_out = False  # the last M114 asking for it has been sent
        self.home_query_number = 0  # of the last M114 asked (its tag)

    enabled = _Gated()  # compensation is on
    skip_file = _Gated()  # the print's file was compensated already: its lines pass through
    halted = _Gated()  # after a failure in a print: its moves are held back
    awaiting_home = _Gated()  # homed axes (0 X, 1 Y, 2 Z) whose position is asked for

    def _use(self, comp) -> None:
        """Compensate with ``comp`` from now on (and offer its engine each line first)."""
        self.comp = comp
        self._reroute()

    def _reroute(self) -> None:
        """``_route``: the engine's line function while lines go to it first, as the engine
        contract decides (not while compensation is off, a file is passed through, the
        print is halted or a home question is open), else None; the hook then tests this
        one attribute for most lines."""
        bypass = not self.enabled or self.skip_file or self.halted or bool(self.awaiting_home)
        self._route = line_route(self.comp, bypass)

    @property
    def params(self) -> Params:
        """The stored parameters (whether compensation is on or not)."""
        return self.comp.params

    @property
    def in_force(self) -> Params:
        """The parameters moves go out with: none while compensation is off. A test printed
        now is measured with these, so an analysis takes them as its ``current``."""
        return self.comp.params if self.enabled else Params()

    # -- the hook ------------------------------------------------------------------------
    def handle(self, cmd: str, tags=None) -> Optional[List[str]]:
        if not self.enabled:
            return None  # (without waiting for the lock, which a settings change may hold)
        lock = self._lock
        lock.acquire()  # (not ``with``: this runs for every line, and that costs twice as much)
        try:
            route = self._route
            offered = route is not None and cmd != ""  # (an empty command is not counted)
            if offered:
                # most moves: the compiled kernel, as Compensator.process would offer them
                try:
                    out = route(cmd)
                except Exception as exc:
                    return self._failed(cmd, exc)
                if out is not None:
                    return None if out is cmd else out
            out, why = self._reference(cmd, tags, offered)
        finally:
            lock.release()
        if why is not None and self.on_untouched is not None:
            _call(self.on_untouched, cmd, why)
        if out is cmd:
            return None
        # the replacement lines as a list of strings (fresh from the compensator): OctoPrint
        # normalises each string exactly as a 1-tuple (same command type and tags)
        return out

    def _reference(self, cmd: str, tags, offered: bool):
        """``handle`` for a line the kernel did not take (under the lock): ``(out, why)``,
        out the line itself (send it), a list of lines, or None (send it unchanged);
        why: "malformed" or "unknown" for a move sent as written, else None."""
        if not self.enabled or not cmd:
            return None, None
        if tags and (self.skip_file or self.halted):
            if self.skip_file and FILE_TAG in tags:
                return None, None
            if self.halted and (FILE_TAG in tags or JOB_TAG in tags) and _MOTION.match(cmd):
                self.held_moves += 1
                return [], None
        comp = self.comp
        rep = comp.state.report
        unknown, malformed = rep.untouched_unknown, rep.malformed
        home = self._homing(cmd)
        try:
            # (a line the kernel declined is not offered to it twice)
            out = comp.process_declined(cmd) if offered else comp.process(cmd)
        except Exception as exc:
            return self._failed(cmd, exc), None
        if home:
            self.awaiting_home, self.home_query_out = home, False
            self.home_query_number += 1
            tag = f"{HOME_QUERY_TAG}{self.home_query_number}"
            return [cmd if out is cmd else out[0], (HOME_QUERY, None, {tag})], None
        if rep.malformed != malformed and _MOTION.match(cmd):
            comp.invalidate()
            return out, "malformed"
        if rep.untouched_unknown != unknown:
            return out, "unknown"
        return out, None

    # -- learning where the printer homes ----------------------------------------------------
    def _homing(self, cmd: str) -> Tuple[int, ...]:
        """For a G28: the axes whose home position is to be asked for (those it homes
        whose home is not known, and those still awaiting an earlier answer). Any other
        line takes the axes it moves or re-frames out of a pending question."""
        if not self.awaiting_home and ("28" not in cmd or None not in self.comp.options.home_mm):
            return ()  # (the common case, cheaply)
        parsed = parse_command(cmd) if cmd.lstrip()[:1] in "GgTtMm" else None
        if parsed is None:
            return ()
        if classify(parsed.kind, parsed.number, parsed.sub).cls == HOME:
            home_mm = self.comp.options.home_mm
            new = {k for k in homed_axes(parsed.body) if home_mm[k] is None}
            # (an axis still awaiting an answer is asked for again: homing others may move
            # it, e.g. Marlin's safe Z homing parks X and Y first)
            return tuple(sorted(new | set(self.awaiting_home)))
        if self.awaiting_home:
            stale = self._moved_axes(parsed)
            if stale:
                self.awaiting_home = tuple(k for k in self.awaiting_home if k not in stale)
        return ()

    @staticmethod
    def _moved_axes(parsed) -> Tuple[int, ...]:
        """The axes (0 X, 1 Y, 2 Z) whose position or frame a line changes as the printer
        runs it (by its class in the G-code table): a position report read after it is stale
        for them. A move that names none of them leaves their drives alone (no line the
        compensator writes carries a word for an axis whose position it does not know)."""
        cls = classify(parsed.kind, parsed.number, parsed.sub).cls
        if cls == LINEAR:
            return tuple(named_axes(parsed.body))
        if cls == SET_POSITION:
            return tuple(g92_axes(parsed.body))
        if cls in _STALE_FOR_ALL:
            return (0, 1, 2)
        return ()

    def home_query_sent(self, tags) -> None:
        """One of our M114s is being sent (OctoPrint's "sending" phase, before the write;
        ``tags``: its tags). When it is the last one asked, the next position report answers
        the question: an earlier one (two G28s queued at once) is answered before the later
        homing, and one OctoPrint dropped (a cancelled print clears its queue) is never sent."""
        number = home_query_number(tags)
        with self._lock:
            self.home_query_out = bool(self.awaiting_home) and number == self.home_query_number

    def home_reported(self, position: Dict[str, float]) -> bool:
        """The firmware's position report (x, y, z in mm) after our M114: the homed axes
        are known there. Returns whether it was taken."""
        with self._lock:
            if not (self.home_query_out and self.awaiting_home):
                return False
            axes, self.awaiting_home, self.home_query_out = self.awaiting_home, (), False
            st = self.comp.state
            at = [position.get(a) for a in "xyz"]
            axes = [
                k
                for k in axes
                if st.m[k] is None and isinstance(at[k], float) and math.isfinite(at[k])
            ]
            if st.inches or not axes:
                return False
            self.comp.homed_at(axes, at)
            return True

    def _failed(self, cmd: str, exc: Exception):
        self.errors += 1
        self.last_error = {"command": cmd, "error": str(exc), "time": time.time()}
        if not isinstance(exc, LimitError) or self.pass_through_on_error:
            # an unexpected failure may leave the state half-updated, and a line sent as
            # written moves the head where the compensator did not put it: forget positions
            # so nothing builds on them (a refused LimitError line that is not sent leaves the
            # state as it was)
            self.comp.invalidate()
        if self.pass_through_on_error:
            self.passed_on_error += 1
            if self.on_error is not None:
                _call(self.on_error, cmd, exc)
            return None
        self.halted = self.printing
        if self.on_error is not None:
            _call(self.on_error, cmd, exc)
        return []

    def resume(self) -> None:
        """The user resumed after a failure: moves are compensated (or reported) again."""
        with self._lock:
            self.halted = False

    # -- life cycle ----------------------------------------------------------------------
    def reset(self) -> None:
        """Back to 'nothing known' (connect, disconnect, print start/cancel)."""
        with self._lock:
            self.comp.reset()
            self.halted = False
            self.awaiting_home, self.home_query_out = (), False

    def set_enabled(self, enabled: bool) -> None:
        with self._lock:
            if enabled and not self.enabled:
                self.comp.reset()  # whatever happened meanwhile was not tracked
            self.enabled = enabled

    def configure(self, params: Params, options: Options, enabled: bool, immediately: bool) -> bool:
        """New parameters and on/off switch. Returns True if they apply now, False if they
        wait for the next print (a print is running and the user did not ask for
        'immediately'); a later call replaces what waits."""
        with self._lock:
            same = (
                params.hash() == self.comp.params.hash()
                and options == self.comp.options
                and enabled == self.enabled
            )
            if same:
                self.pending = None
                return True
            if self.printing and not immediately:
                self.pending = (params, options, enabled)
                return False
            self._swap(params, options)
            self.set_enabled(enabled)
            return True

    def _swap(self, params: Params, options: Options) -> None:
        new = make_compensator(params, options)
        new.adopt_state(self.comp)
        self._use(new)
        self.pending = None

    def _apply_pending(self) -> None:
        if self.pending is not None:
            params, options, enabled = self.pending
            self._swap(params, options)
            self.set_enabled(enabled)

    def print_started(self, precompensated: bool) -> None:
        with self._lock:
            self.printing = True
            self.halted = False
            self._apply_pending()
            self.comp.reset()
            self.awaiting_home, self.home_query_out = (), False
            self.skip_file = precompensated
            rep = self.comp.report
            self._edge_hits = rep.limit_hits
            rep.limit_worst_um, rep.limit_worst_axis = 0.0, None

    def print_ended(self) -> Optional[Dict[str, object]]:
        """The print is over. Returns what it lost at the travel's edge since it started
        (``edge_summary``), None when nothing."""
        with self._lock:
            rep = self.comp.report
            hits = rep.limit_hits - getattr(self, "_edge_hits", 0)
            edge = edge_summary(hits, rep, self.comp.options.policy)
            self.printing = False
            self.halted = False
            self.skip_file = False
            self._apply_pending()
            self.comp.reset()
            self.awaiting_home, self.home_query_out = (), False
            return edge

    # -- reporting -----------------------------------------------------------------------
    def status(self) -> Dict[str, object]:
        with self._lock:
            rep = self.comp.report.to_dict()
            return {
                "enabled": self.enabled,
                "params_hash": self.comp.params.hash(),
                "pending_params_hash": self.pending[0].hash() if self.pending else None,
                "pending_enabled": self.pending[2] if self.pending else None,
                "positions_known": list(self.comp.known),
                "printing": self.printing,
                "skipping_precompensated_file": self.skip_file,
                "errors": self.errors,
                "last_error": self.last_error,
                "passed_on_error": self.passed_on_error,
                "halted": self.halted,
                "held_moves": self.held_moves,
                "report": rep,
            }


# what the user is told about the travel's edge (``what``: a file's name, or EDGE_PRINT)
EDGE_KEPT = N_(
    "KinComp kept %(count)d compensated coordinates of %(what)s inside the printer's travel: "
    "there up to %(worst_um)s µm of correction could not be applied (axis %(axis)s)."
)
EDGE_SENT = N_(
    "KinComp sent %(count)d compensated coordinates of %(what)s past the printer's travel (up "
    "to %(worst_um)s µm, axis %(axis)s) because the limits policy is 'warn': the firmware may "
    "refuse or clamp these moves."
)
EDGE_PRINT = N_("this print")


def edge_summary(hits: int, rep, policy: str) -> Optional[Dict[str, object]]:
    """``hits`` compensated coordinates at the travel's edge under the limits ``policy``,
    with the report ``rep``'s worst shortfall: {"count", "worst_um" (um, 1 decimal),
    "axis" ("X"/"Y"/"Z"), "sent" (True: sent past it, policy ``warn``)}; None for none."""
    if hits <= 0:
        return None
    return {
        "count": hits,
        "worst_um": round(rep.limit_worst_um, 1),
        "axis": rep.limit_worst_axis,
        "sent": policy == "warn",
    }


def edge_of(report: Optional[Dict[str, object]], policy: str) -> Optional[Dict[str, object]]:
    """:func:`edge_summary` of a file's report (``Report.to_dict``), None for none."""
    if not report or not report.get("limit_hits"):
        return None
    return {
        "count": report["limit_hits"],
        "worst_um": round(float(report.get("limit_worst_um") or 0.0), 1),
        "axis": report.get("limit_worst_axis"),
        "sent": policy == "warn",
    }


def notify_edge(notifier, edge: Optional[Dict[str, object]], what: Optional[str]) -> None:
    """Tell the user what ``edge`` (:func:`edge_summary`) says, for the file ``what`` (its
    name; None: the print that just ended). Nothing for None."""
    if not edge:
        return
    msgid = EDGE_SENT if edge["sent"] else EDGE_KEPT
    params = {k: edge[k] for k in ("count", "worst_um", "axis")}
    if what is None:
        notifier.notify("warning", msgid, tr_params=("what",), what=EDGE_PRINT, **params)
    else:
        notifier.notify("warning", msgid, what=what, **params)
