"""Demo mode: a virtual ballbar on OctoPrint's virtual printer (everything SIMULATED).

The virtual printer itself moves without errors, so the demo gives it hidden "true" errors
here: while a KinComp ballbar program prints, the commands going out to the printer
(compensated or not, as they leave KinComp's queuing hook, which runs last; resends are
not repeated there) are recorded, and when the print is done the KinComp simulator runs
them on a printer with the hidden errors and samples the virtual ballbar. The resulting
trace is labelled SIMULATED wherever it is shown. Re-testing with compensation active
records the compensated commands, so the calibrate -> analyse -> apply -> re-test loop
behaves as it would on a real printer.
"""

from __future__ import annotations

import threading
from typing import List, Optional

from ..calibration.ballbar.formats import NativeTrace
from ..calibration.ballbar.program import TestSpec
from .printer import Truth, simulate_program, volume_truth

MAX_RECORDED_LINES = 200_000


def demo_truth() -> Truth:
    """The hidden errors of the demo printer: the paper's Ultimaker (Table 1) extended to the
    whole volume (squareness XZ/YZ, scale and backlash of Z, Z servo lag: a campaign over XY,
    XZ and YZ has something to find), 0.5 um noise."""
    return volume_truth(noise_um=0.5)


class DemoBallbar:
    def __init__(self, truth: Optional[Truth] = None):
        self.truth = truth or demo_truth()
        self._lock = threading.Lock()
        self._spec: Optional[TestSpec] = None
        self._hash = ""
        self._lines: List[str] = []
        self.last_trace: Optional[NativeTrace] = None
        self.recording = False

    def start(self, spec: TestSpec, program_hash: str) -> None:
        with self._lock:
            self._spec = spec
            self._hash = program_hash
            self._lines = []
            self.recording = True
            self.last_trace = None  # the previous run's trace must not pass for this one

    def record(self, cmd: str) -> None:
        if not self.recording:
            return
        with self._lock:
            if len(self._lines) < MAX_RECORDED_LINES:
                self._lines.append(cmd)

    def cancel(self) -> None:
        with self._lock:
            self.recording = False
            self._lines = []

    def finish(self) -> Optional[NativeTrace]:
        """Simulate the recorded print; None if nothing was being recorded."""
        with self._lock:
            if not self.recording or self._spec is None:
                return None
            self.recording = False
            text = "\n".join(self._lines) + "\n"
            spec, prog_hash = self._spec, self._hash
            self._lines = []
        trace = simulate_program(text, self.truth, spec, prog_hash)
        trace.meta["source"] = (
            "SIMULATED by KinComp demo mode: virtual ballbar on a virtual "
            "printer with hidden errors"
        )
        self.last_trace = trace
        return trace
