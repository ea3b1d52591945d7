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
