"""The printer's motion limits as the plugin learns them: the firmware's answer to ``M503``
captured from the serial line, the text a Klipper user pasted, and the printer profile's
axis speeds. Reading and feasibility are ``firmware/motion_limits.py``; this piece only listens,
stores (settings key ``motion_limits``) and combines.

Capture: every answer to ``M503`` is read, whoever asked (KinComp's firmware check asks a
Marlin firmware after its ``M115`` reply; a RepRapFirmware one is asked here; the user may
type it in the terminal; ``POST /limits/read`` asks on request). Lines stating M201, M203,
M204 or M205 (and the unit headers above them) and the steps per mm (M92: the reversal dead
band follows them, see ``settings.steps_for_deadband``) are collected until the firmware's
``ok``; then, off the serial thread, they are stored unless the user pasted limits of their
own (an explicit request replaces those too), through the settings store's one save. A
Klipper printer does not answer M503 with limits: its users paste their ``printer.cfg``
``[printer]`` section on the settings page.

The limits a test must respect (:func:`effective_limits`) are the lower of the stated
limits and the printer profile's axis speeds (mm/min).
"""

from __future__ import annotations

import datetime as _dt
import re
import threading
from typing import Any, Dict, List, Optional

import flask
from flask_babel import gettext

from ...core.messages import as_dict
from ...firmware.motion_limits import LimitsError, MotionLimits, parse_limits, settings_query
from ...service.notify import N_
from ...service.settings.schema import SettingsError
from .. import http

# the lines of M503's answer kept: the limits (M201, M203-M205, RepRapFirmware's M566), the
# travel (RepRapFirmware's M208, Marlin's M211 answer "Min: X.. Max: ..") and the steps per
# mm (M92)
_LIMIT_LINE = re.compile(r"(?:^|[\s:])(?:M20[1345]|M208|M92|M566)\s+[A-Za-z]|Min:\s+X")
_TRAVEL_ONLY = re.compile(r"Min:\s+X")  # Marlin's M211 answer: kept for the next M503 answer
_HEADER = re.compile(r"feedrate|maximum speed|accelerat|advanced", re.IGNORECASE)
MAX_LINES = 200  # lines kept of one answer (Marlin's whole M503 is ~60)
TAGS = {"plugin:kincomp", "kincomp:motion-limits"}


def effective_limits(
    settings: Dict[str, Any], profile_feeds: Optional[Dict[str, float]]
) -> MotionLimits:
    """The limits a test must respect: the stated ones (settings ``motion_limits``; an
    unreadable stored text counts as none) and the profile's axis speeds, the lower of each."""
    stated = settings.get("motion_limits") or {}
    limits = MotionLimits()
    if (stated.get("text") or "").strip():
        try:
            limits = parse_limits(stated["text"], stated.get("firmware") or None)
        except LimitsError:
            limits = MotionLimits()
    return limits.combined(MotionLimits.from_feeds(profile_feeds, "printer profile"))


def status(settings: Dict[str, Any], profile_feeds: Optional[Dict[str, float]]) -> Dict[str, Any]:
    """What the settings page shows: the stated limits (source, firmware, when), what was
    read from them and the combined limits a test respects."""
    stated = dict(settings.get("motion_limits") or {})
    out: Dict[str, Any] = {
        "stated": stated,
        "read": None,
        "error": None,
        "profile_feeds": profile_feeds,
    }
    if (stated.get("text") or "").strip():
        try:
            read = parse_limits(stated["text"], stated.get("firmware") or None)
            out["read"] = read.to_dict()
            out["read"]["notes_i18n"] = [as_dict(n) for n in read.notes]
        except LimitsError as exc:
            out["error"] = as_dict(exc.args[0])
    out["effective"] = effective_limits(settings, profile_feeds).to_dict()
    return out


class _Kept(Exception):
    """The stored limits stay (pasted by the user, or the same answer again)."""


class LimitsCapture:
    """Listens to the printer for M503's limit lines and stores them (see the module)."""

    def __init__(self, store, settings, printer, notifier, logger):
        self._store = store
        self._settings = settings  # OctoPrint's PluginSettings of KinComp
        self._printer = printer
        self._notifier = notifier
        self._logger = logger
        self._lock = threading.Lock()
        self._lines: List[str] = []
        self._states_limit = False  # a line collected states a limit (not only the travel)
        self._replace = False  # the next answer replaces pasted limits (asked explicitly)
        self.firmware = ""

    # ~~ asking --------------------------------------------------------------------------------
    def firmware_data(self, payload: Dict[str, Any]) -> None:
        """After the M115 reply: remember the firmware (M203's unit); ask a RepRapFirmware
        printer for M503 (Marlin is asked by the firmware check, Klipper has no answer)."""
        self.firmware = str(payload.get("name") or "")
        if "reprapfirmware" in self.firmware.lower():
            self.ask(replace=False)

    def ask(self, replace: bool = True) -> bool:
        """Sends M503 (a Marlin firmware M211 first: its soft endstops, which its M503 does
        not state); ``replace``: the answer replaces pasted limits. False when the printer
        is not connected or is printing (nothing sent)."""
        if not self._printer.is_operational() or self._printer.is_printing():
            return False
        with self._lock:
            self._replace = replace
            self._lines = []
            self._states_limit = False
        self._printer.commands(settings_query(self.firmware), tags=set(TAGS))
        return True

    # ~~ listening (the serial thread: no I/O here) -------------------------------------------
    def received(self, line: str) -> None:
        if (
            "M20" in line or "M92" in line or "M566" in line or "Min:" in line
        ) and _LIMIT_LINE.search(line):
            with self._lock:
                if len(self._lines) < MAX_LINES:
                    self._lines.append(line.strip())
                    self._states_limit = self._states_limit or not _TRAVEL_ONLY.search(line)
        elif self._lines and line.startswith("ok") and not self._states_limit:
            # an answer without limits (M211's travel): its last travel line waits for the
            # M503 answer, headers go
            with self._lock:
                self._lines = [ln for ln in self._lines if _TRAVEL_ONLY.search(ln)][-1:]
        elif self._lines and line.startswith("ok"):
            with self._lock:
                lines, self._lines = self._lines, []
                self._states_limit = False
                replace, self._replace = self._replace, False
            threading.Thread(
                target=self.store,
                args=("\n".join(lines), replace),
                name="kincomp-limits",
                daemon=True,
            ).start()
        elif _HEADER.search(line) and ("echo:" in line or line.startswith(";")):
            with self._lock:
                if len(self._lines) < MAX_LINES:
                    self._lines.append(line.strip())

    def store(self, text: str, replace: bool) -> bool:
        """Stores the answer ``text`` as the stated limits; False (nothing stored) when it
        states none or the user's pasted limits stay."""
        try:
            parse_limits(text, self.firmware or None)
        except LimitsError:
            return False
        doc = {
            "text": text,
            "source": "m503",
            "firmware": self.firmware,
            "captured": _dt.datetime.now().isoformat(timespec="seconds"),
        }

        def vet(stored, new):  # under the settings lock: the stored limits as they are now
            old = stored.get("motion_limits") or {}
            if old.get("source") == "pasted" and not replace:
                raise _Kept()
            if old.get("text") == text and old.get("firmware") == self.firmware and not replace:
                raise _Kept()  # the same answer as last time: nothing to write

        # through the settings store's one save (read, merge, validate, write under its
        # lock), so a settings save at the same moment loses nothing
        try:
            self._store.update({"motion_limits": doc}, vet=vet)
        except _Kept:
            return False
        except SettingsError as exc:
            self._logger.warning("KinComp: motion limits read but not stored: %s", exc)
            return False
        except OSError as exc:
            self._logger.warning("KinComp: motion limits read but not written: %s", exc)
            return False
        self._logger.info("KinComp: the printer's motion limits read from M503")
        self._notifier.message({"type": "motion_limits"})
        self._notifier.notify(
            "status",  # for the record: a line in the tab, no pop-up
            N_("KinComp read the printer's motion limits (M503); test programs keep within them."),
        )
        return True

    # ~~ the endpoint ----------------------------------------------------------------------------
    @http.route("/limits/read", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def read_request(self):
        """``POST /limits/read``: ask the printer for M503 now (its answer replaces pasted
        limits); 202 when asked, 409 when the printer is not connected or is printing."""
        if not self.ask(replace=True):
            return http.error(
                gettext("The printer must be connected and not printing to read its motion limits"),
                409,
            )
        return flask.make_response(flask.jsonify(asked=True), 202)
