"""What KinComp does about the firmware's own compensation (double compensation).

The lines sent to and received from the printer feed the :class:`FirmwareWatcher`; a
Marlin firmware is asked for its settings (``M503``) after its ``M115`` reply, as its
``M852``/``M425`` lines tell whether it corrects skew or backlash itself. With compensation
on, each conflict (skew, backlash, axis scale) is logged and notified once per finding.
"""

from __future__ import annotations

from typing import Any, Dict

from ..notify import N_, Notifier
from .firmware_watch import FirmwareWatcher
from .queue import QueueCompensator

# what the firmware may compensate too, as words in a notification (translated by the UI)
CONFLICT_NAMES = {"skew": N_("skew"), "backlash": N_("backlash"), "scale": N_("axis scale")}


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
        """Reports conflicts with the compensation as it is now (if it is on)."""
        if not self._queue.enabled:
            return
        conflicts = self.watch.conflicts(self._queue.params)
        for kind, where in conflicts.items():
            if self._warned.get(kind) != where:
                self._warned[kind] = where
                self._logger.warning("Double compensation: firmware %s active (%s)", kind, where)
                self._notifier.notify(
                    "warning",
                    N_(
                        "The firmware compensates %(kind)s too (%(where)s): with KinComp on, it is "
                        "corrected twice. Turn one of them off."
                    ),
                    tr_params=("kind",),
                    kind=CONFLICT_NAMES[kind],
                    where=where,
                )

    def query(self, payload: Dict[str, Any]) -> None:
        """After the M115 reply (FIRMWARE_DATA): a Marlin firmware is asked for its
        settings (M503)."""
        name = str(payload.get("name") or "")
        if "marlin" not in name.lower():
            return
        try:
            self._printer.commands(["M503"], tags={"plugin:kincomp", "kincomp:firmware-check"})
        except Exception:
            self._logger.exception("KinComp: could not ask the firmware for its settings")
