"""Whole-file compensation on top of the streaming engine (CLI and upload preprocessing).

A compensated file starts with a marker line naming the parameter hash::

    ; kincomp: compensated params=<hash> kincomp=<version>

and compensating a marked file again is refused (:class:`AlreadyCompensated`). Line endings
and any bytes that are not UTF-8 are preserved; memory use does not grow with file size.
"""

from __future__ import annotations

import os
import re
import tempfile
from typing import IO, Iterable, Iterator, Optional

from .. import __version__
from ..core.compensator import MARKER_PREFIX, Compensator, Options, Report
from ..core.lines import join_output, split_ending
from ..core.params import Params

MARKER_SCAN_LINES = 100
_MARKER_RE = re.compile(r"^; kincomp: compensated params=([0-9a-f]+)")
ENCODING = "utf-8"
ERRORS = "surrogateescape"  # round-trips any byte


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
    return f"{MARKER_PREFIX} params={params.hash()} kincomp={__version__}"


def find_marker(lines: Iterable[str]) -> Optional[str]:
    """Parameter hash from a KinComp marker among the first lines, or None."""
    for i, line in enumerate(lines):
        if i >= MARKER_SCAN_LINES:
            break
        m = _MARKER_RE.match(line)
        if m:
            return m.group(1)
    return None


def file_marker(path: str) -> Optional[str]:
    with open(path, encoding=ENCODING, errors=ERRORS, newline="") as f:
        return find_marker(f)


def compensate_lines(lines: Iterable[str], comp: Compensator,
                     header: Optional[str] = None) -> Iterator[str]:
    """Yield output lines (with endings) for input lines (with endings)."""
    process = comp.process
    for raw in lines:
        body, ending = split_ending(raw)
        if header is not None:
            yield header + (ending or "\n")
            header = None
        if comp.lineno < MARKER_SCAN_LINES and body.startswith(MARKER_PREFIX):
            m = _MARKER_RE.match(body)
            if m:
                raise AlreadyCompensated(m.group(1))
        out = process(body)
        if out is body:
            yield raw
        else:
            yield join_output(out, ending)


def compensate_stream(src: IO[str], dst: IO[str], params: Params,
                      options: Optional[Options] = None) -> Report:
    comp = Compensator(params, options)
    write = dst.write
    for out in compensate_lines(src, comp, marker_line(params)):
        write(out)
    return comp.report


def _check_head(text: str) -> None:
    found = find_marker(text.splitlines())
    if found is not None:
        raise AlreadyCompensated(found)


def compensate_binary(src: IO[bytes], dst: IO[bytes], params: Params,
                      options: Optional[Options] = None, progress=None) -> Report:
    """Compensate a binary stream with the vectorised engine (same output as the line path).

    ``progress(bytes_read)`` is called as the input is consumed."""
    from .vectorised import FileEngine

    comp = Compensator(params, options)
    FileEngine(comp).run(src.read, dst.write, marker_line(params), _check_head, progress)
    return comp.report


def compensate_file(in_path: str, out_path: Optional[str], params: Params,
                    options: Optional[Options] = None, dry_run: bool = False,
                    progress=None) -> Report:
    """Compensate ``in_path`` into ``out_path`` (or in place when None). Atomic on success."""
    existing = file_marker(in_path)
    if existing is not None:
        raise AlreadyCompensated(existing)
    target = out_path or in_path
    if dry_run:
        with open(in_path, "rb") as src:
            return compensate_binary(src, _NullSink(), params, options, progress)
    directory = os.path.dirname(os.path.abspath(target)) or "."
    fd, tmp = tempfile.mkstemp(prefix=".kincomp-", suffix=".gcode", dir=directory)
    try:
        with open(in_path, "rb") as src, os.fdopen(fd, "wb") as dst:
            report = compensate_binary(src, dst, params, options, progress)
        if os.path.exists(target):
            try:
                os.chmod(tmp, os.stat(target).st_mode & 0o777)
            except OSError:
                pass
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return report
