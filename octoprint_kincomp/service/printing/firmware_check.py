"""What KinComp does about the firmware's own compensation (double compensation).

The lines sent to and received from the printer feed the :class:`FirmwareWatcher`; a
Marlin firmware is asked for its settings (``M503``) after its ``M115`` reply, as its
``M852``/``M425`` lines tell whether it corrects skew or backlash itself. With compensation
on, each conflict (skew, backlash, axis scale) is logged and notified once per finding, with
advice that depends on how the parameters in force were measured (their ``meta.firmware``):
on top of the firmware's compensation (both stay), without it (the firmware's goes), or not
recorded.
"""

from __future__ import annotations

from typing import Any, Dict

from ...firmware.motion_limits import settings_query
from ..notify import Notifier
from .firmware_watch import FirmwareWatcher
from .queue import QueueCompensator


class FirmwareCheck:
    def __init__(
        self, watch: FirmwareWatcher, queue: QueueCompensator, printer, notifier: Notifier, logger
    ):
        self.watch = watch
        self._queue = queue
        self._printer = printer
        self._notifier = notifier
        self._logger = logger
        self._warned: Dict[str, str] = {}  # conflict kind -> where, as last notified

    def sent(self, cmd: str) -> None:
        """A command the watcher reads (``FirmwareWatcher.relevant``) goes to the printer."""
        self.watch.sent(cmd)
        self.check()

    def received(self, line: str) -> None:
        """A line from the printer."""
        if FirmwareWatcher.relevant(line):
            self.watch.received(line)
            self.check()

    def check(self) -> None:
        """Reports where the firmware's compensation and the parameters in force do not fit
        together (:meth:`FirmwareWatcher.advice`: corrected twice, the firmware's changed or
        gone since the parameters were measured on top of it), if compensation is on."""
        if not self._queue.enabled:
            return
        for item in self.watch.advice(self._queue.params):
            kind, where, msg = item["kind"], str(item["where"]), item["message"]
            key = f"{item['case']}:{where}"
            if self._warned.get(kind) != key:
                self._warned[kind] = key
                self._logger.warning("KinComp and the firmware: %s", msg)
                self._notifier.notify("warning", msg.template, **msg.params)

    def query(self, payload: Dict[str, Any]) -> None:
        """After the M115 reply (FIRMWARE_DATA): a Marlin firmware is asked for its soft
        endstops and its settings (M211, M503)."""
        name = str(payload.get("name") or "")
        if "marlin" not in name.lower():
            return
        try:
            # (M211 first: Marlin's soft endstops, which its M503 leaves out; the limits
            # capture keeps its answer for the M503 answer's)
            self._printer.commands(
                settings_query(name), tags={"plugin:kincomp", "kincomp:firmware-check"}
            )
        except Exception:
            self._logger.exception("KinComp: could not ask the firmware for its settings")
