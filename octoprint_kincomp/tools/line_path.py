"""The line path: a G-code text stream through ``Compensator.process`` one line at a time,
without the file loop (``engines/file_loop.py``). It is the oracle the benchmark's check and the
tests hold the file loop (and so the compiled kernel's blocks) to; nothing that compensates
for a user runs it."""

from __future__ import annotations

from typing import Iterable, Iterator, Optional

from ..core.compensator import Compensator
from ..core.line_endings import join_output, split_ending
from ..core.marker import MARKER_SCAN_LINES, find_marker
from ..engines.file_loop import AlreadyCompensated


def compensate_lines(
    lines: Iterable[str], comp: Compensator, header: Optional[str] = None
) -> Iterator[str]:
    """Yield output lines (with endings) for input lines (with endings)."""
    process = comp.process
    for i, raw in enumerate(lines):
        body, ending = split_ending(raw)
        if header is not None:
            yield header + (ending or "\n")
            header = None
        if i < MARKER_SCAN_LINES:
            found = find_marker((body,))
            if found is not None:
                raise AlreadyCompensated(found)
        out = process(body)
        if out is body:
            yield raw
        else:
            yield join_output(out, ending)
