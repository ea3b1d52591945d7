"""KinComp's file marker: the first line of a compensated file names the parameter hash,

    ; kincomp: compensated params=<hash> kincomp=<version>

so that a file is never compensated twice (the queuing hook passes a marked file's lines
through, uploads and the command line refuse to compensate it again). The marker counts
when it stands among the first ``MARKER_SCAN_LINES`` lines (other tools may put lines
before it). One definition for every reader: files, uploads, the plugin's checks.
"""

from __future__ import annotations

import re
from typing import Iterable, Optional

MARKER_PREFIX = "; kincomp: compensated"
MARKER_SCAN_LINES = 100
_MARKER_RE = re.compile(r"^; kincomp: compensated params=([0-9a-f]+)")
ENCODING = "utf-8"
ERRORS = "surrogateescape"  # reading G-code as text round-trips any byte


# A ballbar test program (its ``; ballbar plane:`` header line) that is compensated also says
# how: these ``; ballbar`` keys go into its trace's metadata (a logger copies the header), so
# that the analysis regenerates exactly the program the printer received (its reversal dead
# band decides where a slowly reversing axis gets its take-up move: calibration/ballbar/
# timing.py, SentWith).
BALLBAR_HEADER = "; ballbar plane:"
BALLBAR_RECORD_KEYS = ("compensation_decimals", "compensation_deadband_mm")


def ballbar_record(head: str, decimals: int, deadband_mm: float) -> str:
    """The ``; ballbar`` lines that record the compensator's decimals and dead band (mm) when
    ``head`` (the first lines of a file) is a ballbar test program, else ""."""
    if BALLBAR_HEADER not in head:
        return ""
    return (
        f"; ballbar {BALLBAR_RECORD_KEYS[0]}: {int(decimals)}\n"
        f"; ballbar {BALLBAR_RECORD_KEYS[1]}: {float(deadband_mm):.10g}"
    )


def marker_line(params_hash: str, version: str) -> str:
    """The marker line (without a line ending) for parameters of hash ``params_hash``."""
    return f"{MARKER_PREFIX} params={params_hash} kincomp={version}"


def marker_hash(line: str) -> Optional[str]:
    """The parameter hash if ``line`` (without its ending) is a marker, else None."""
    if not line.startswith(MARKER_PREFIX):
        return None
    m = _MARKER_RE.match(line)
    return m.group(1) if m else None


def find_marker(lines: Iterable[str]) -> Optional[str]:
    """Parameter hash from a marker among the first ``MARKER_SCAN_LINES`` lines, or None."""
    for i, line in enumerate(lines):
        if i >= MARKER_SCAN_LINES:
            break
        found = marker_hash(line)
        if found is not None:
            return found
    return None


def file_marker(path: str) -> Optional[str]:
    """Parameter hash of the marker of the file at ``path``, or None."""
    with open(path, encoding=ENCODING, errors=ERRORS, newline="") as f:
        return find_marker(f)
