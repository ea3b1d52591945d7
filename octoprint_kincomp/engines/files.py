"""Whole-file compensation on top of the streaming engine (CLI and upload preprocessing).

A compensated file starts with a marker line naming the parameter hash::

    ; kincomp: compensated params=<hash> kincomp=<version>

and compensating a marked file again is refused (:class:`AlreadyCompensated`). Line endings
and any bytes that are not UTF-8 are preserved; memory use does not grow with file size.
"""

from __future__ import annotations

from typing import IO, Iterable, Iterator, Optional

from ..core.atomic import replacing
from ..core.compensator import Compensator, Options, Report
from ..core.lines import join_output, split_ending
from ..core.marker import MARKER_SCAN_LINES, file_marker, find_marker, marker_hash
from ..core.marker import marker_line as make_marker_line
from ..core.params import Params
from ..core.version import VERSION
from .select import make_compensator


class AlreadyCompensated(ValueError):
    def __init__(self, params_hash: str):
        self.params_hash = params_hash
        super().__init__(
            f"this file is already compensated by KinComp (params {params_hash}); "
            "compensating it again would apply the corrections twice"
        )


class _NullSink:
    def write(self, data) -> int:
        return len(data)


def marker_line(params: Params) -> str:
    return make_marker_line(params.hash(), VERSION)


def compensate_lines(
    lines: Iterable[str], comp: Compensator, header: Optional[str] = None
) -> Iterator[str]:
    """Yield output lines (with endings) for input lines (with endings)."""
    process = comp.process
    for raw in lines:
        body, ending = split_ending(raw)
        if header is not None:
            yield header + (ending or "\n")
            header = None
        if comp.lineno < MARKER_SCAN_LINES:
            found = marker_hash(body)
            if found is not None:
                raise AlreadyCompensated(found)
        out = process(body)
        if out is body:
            yield raw
        else:
            yield join_output(out, ending)


def compensate_stream(
    src: IO[str], dst: IO[str], params: Params, options: Optional[Options] = None
) -> Report:
    comp = make_compensator(params, options)
    write = dst.write
    for out in compensate_lines(src, comp, marker_line(params)):
        write(out)
    return comp.report


def _check_head(text: str) -> None:
    found = find_marker(text.splitlines())
    if found is not None:
        raise AlreadyCompensated(found)


def compensate_binary(
    src: IO[bytes], dst: IO[bytes], params: Params, options: Optional[Options] = None, progress=None
) -> Report:
    """Compensate a binary stream with the vectorised engine (same output as the line path).

    ``progress(bytes_read)`` is called as the input is consumed."""
    from .vectorised import FileEngine

    comp = make_compensator(params, options)
    FileEngine(comp).run(src.read, dst.write, marker_line(params), _check_head, progress)
    return comp.report


def compensate_file(
    in_path: str,
    out_path: Optional[str],
    params: Params,
    options: Optional[Options] = None,
    dry_run: bool = False,
    progress=None,
) -> Report:
    """Compensate ``in_path`` into ``out_path`` (or in place when None). Atomic on success."""
    existing = file_marker(in_path)
    if existing is not None:
        raise AlreadyCompensated(existing)
    target = out_path or in_path
    if dry_run:
        with open(in_path, "rb") as src:
            return compensate_binary(src, _NullSink(), params, options, progress)
    with open(in_path, "rb") as src, replacing(target, ".gcode") as dst:
        report = compensate_binary(src, dst, params, options, progress)
    return report
