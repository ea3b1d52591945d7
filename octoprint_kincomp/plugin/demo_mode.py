"""Demo mode on the OctoPrint side: the virtual ballbar (:mod:`..ballbar.demo`) while the
``demo.enabled`` setting is on (everything it measures is SIMULATED).

The last ballbar program KinComp wrote is remembered; when a print of it begins, the
commands leaving KinComp's queuing hook are recorded; when that print is done the simulator
runs on its own thread (seconds, never on OctoPrint's event thread) and the UI is told that
the simulated trace is ready. A print that fails or is cancelled drops the recording.
"""

from __future__ import annotations

import threading
from typing import Any, Dict, List, Optional

from ..ballbar.demo import DemoBallbar
from ..ballbar.formats import NativeTrace
from ..ballbar.program import TestSpec
from .notify import N_, Notifier


class DemoMode:
    def __init__(self, notifier: Notifier, logger):
        self._notifier = notifier
        self._logger = logger
        self.ballbar: Optional[DemoBallbar] = None  # None: demo mode is off
        self._lock = threading.RLock()
        self._program_path: Optional[str] = None
        self._program_spec: Optional[TestSpec] = None
        self._program_hash = ""

    def set_enabled(self, enabled: bool) -> None:
        """Turns demo mode on (a fresh virtual ballbar, unless one is there) or off."""
        if enabled and self.ballbar is None:
            self.ballbar = DemoBallbar()
        elif not enabled:
            self.ballbar = None

    def program_written(self, path: str, spec: TestSpec, program_hash: str) -> None:
        """KinComp wrote the ballbar program ``spec`` to ``path`` (in OctoPrint's storage)."""
        with self._lock:
            self._program_path = path
            self._program_spec = spec
            self._program_hash = program_hash

    def print_begins(self, payload: Dict[str, Any]) -> None:
        """A print begins (``payload``: origin and path): recorded if it is the program."""
        demo = self.ballbar
        if demo is None:
            return
        with self._lock:
            if payload.get("path") != self._program_path or self._program_spec is None:
                return
            demo.start(self._program_spec, self._program_hash)

    def record(self, cmd: str, result: Optional[List[str]]) -> None:
        """What the queuing hook sends for ``cmd``: ``result`` (None: ``cmd`` as it is).
        Recorded once here: in the sent phase resends would repeat lines."""
        demo = self.ballbar
        if demo is None or not demo.recording:
            return
        if result is None:
            demo.record(cmd)
        else:
            for line in result:
                demo.record(line)

    def print_ends(self, done: bool) -> None:
        """The print ended; ``done``: it completed (then the trace is simulated)."""
        demo = self.ballbar
        if demo is None or not demo.recording:
            return
        if not done:
            demo.cancel()
            return
        threading.Thread(target=self._simulate, args=(demo,), name="kincomp-demo",
                         daemon=True).start()

    def last_trace(self) -> Optional[NativeTrace]:
        """The last simulated trace, if demo mode is on and one was made."""
        demo = self.ballbar
        return None if demo is None else demo.last_trace

    def _simulate(self, demo: DemoBallbar) -> None:
        """Runs the simulator (seconds) on its own thread, not on OctoPrint's event thread."""
        try:
            trace = demo.finish()
        except Exception:  # noqa: BLE001 - a demo failure must not disturb anything else
            self._logger.exception("KinComp demo: simulation failed")
            return
        if trace is not None:
            self._notifier.notify("success", N_(
                "SIMULATED ballbar trace ready (demo mode): load it in the calibration tab."))
            # a campaign's test is collected by the campaign's wizard
            meta = getattr(trace, "meta", None) or {}
            self._notifier.message({"type": "demo_trace", "campaign": meta.get("campaign"),
                                    "campaign_step": meta.get("campaign_step")})
