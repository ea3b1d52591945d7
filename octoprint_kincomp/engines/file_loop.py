"""The one file loop: whole-file compensation (the command line, background jobs) and
upload preprocessing (``plugin/files/upload.py``) run :class:`FileEngine`.

A compensated file starts with a marker line naming the parameter hash::

    ; kincomp: compensated params=<hash> kincomp=<version>

and compensating a marked file again is refused (:class:`AlreadyCompensated`; an upload
passes it through). Line endings and any bytes that are not UTF-8 are preserved; memory use
does not grow with file size.
"""

from __future__ import annotations

import functools
import io
import types
from typing import IO, Callable, Optional

from ..core.atomic import replacing
from ..core.compensator import Compensator, Options, Report
from ..core.line_endings import UNIVERSAL, join_output, split_ending
from ..core.marker import ENCODING, ERRORS, ballbar_record, file_marker, find_marker
from ..core.marker import marker_line as make_marker_line
from ..core.params import Params
from ..core.version import VERSION
from .contract import block_route
from .select import make_compensator

CHUNK_BYTES = 1 << 19  # a block of the file loop (512 KB of complete lines)
_NULL_SINK = types.SimpleNamespace(write=len)  # (a dry run's output)


class AlreadyCompensated(ValueError):
    def __init__(self, params_hash: str):
        self.params_hash = params_hash
        super().__init__(
            f"this file is already compensated by KinComp (params {params_hash}); "
            "compensating it again would apply the corrections twice"
        )


def marker_line(params: Params) -> str:
    return make_marker_line(params.hash(), VERSION)


def compensate_stream(
    src: IO[str], dst: IO[str], params: Params, options: Optional[Options] = None
) -> Report:
    """Compensate a text stream (a program in memory: the closed loop, the timing check)
    through the same file loop as :func:`compensate_binary`."""
    out = io.BytesIO()
    report = compensate_binary(
        io.BytesIO(src.read().encode(ENCODING, ERRORS)), out, params, options
    )
    dst.write(out.getvalue().decode(ENCODING, ERRORS))
    return report


def head_marker(text: str, refuse: bool = False) -> Optional[str]:
    """The parameter hash of a marker among the first lines of ``text``, or None (``refuse``:
    raise :class:`AlreadyCompensated` if there is one)."""
    found = find_marker(UNIVERSAL.findall(text))
    if found is not None and refuse:
        raise AlreadyCompensated(found)
    return found


class _Unterminated(bytes):
    """The last block of a file that did not end with a newline (one was added)."""


class FileEngine:
    """Feeds a file's bytes through one Compensator, a block of complete lines at a time:
    with the compiled kernel, ``Kernel.feed`` takes the lines it takes and every other line
    goes through ``Compensator.process`` in order (the state handed over between them by the
    kernel, see engines/contract.py); without it, every line takes the reference path.
    Either way the text and report are those of ``Compensator.process`` line by line."""

    def __init__(self, comp: Compensator):
        self.comp = comp
        self.feed = block_route(comp)

    def run(
        self,
        read: Callable[[int], bytes],
        write: Callable[[bytes], object],
        header=None,
        check_first: Optional[Callable[[str], None]] = None,
        progress: Optional[Callable[[int], None]] = None,
    ) -> None:
        """Compensate everything ``read`` yields into ``write``. ``header`` is written
        before the first line (with that line's ending), ``check_first`` sees the first
        lines of text (the marker check), ``progress(bytes_read)`` is called per block;
        ``header`` may be a function of those first lines (text) that returns the header."""
        done = 0
        for block in self._blocks(read):
            first = not done
            done += len(block)
            if progress is not None:
                progress(done)
            if first:
                head = block[:-1] if isinstance(block, _Unterminated) else block
                if check_first is not None:
                    check_first(head[:16384].decode(ENCODING, ERRORS))
                if header is not None:
                    text = (
                        header(head[:16384].decode(ENCODING, ERRORS))
                        if callable(header)
                        else header
                    )
                    write(self.header(text, head))
            if isinstance(block, _Unterminated) and block.endswith(b"\r\n"):
                # the file ended with a lone CR (its last line is terminated after all): the
                # virtual newline would make that ending CRLF
                write(self._lines(block, 0, len(block) - 1))
                continue
            out = self.chunk(block)
            write(out[:-1] if isinstance(block, _Unterminated) and out.endswith(b"\n") else out)

    @staticmethod
    def header(line: str, head: bytes) -> bytes:
        """``line`` (lines joined by ``\\n``) with the ending of the first line of ``head``
        (``\\n`` if none) after each."""
        first = UNIVERSAL.match(head[:16384].decode(ENCODING, ERRORS))
        ending = split_ending(first.group(0))[1] if first else ""
        ending = ending or "\n"
        return "".join(part + ending for part in line.split("\n")).encode(ENCODING, ERRORS)

    @staticmethod
    def _blocks(read: Callable[[int], bytes]):
        """Blocks of complete lines; a last line without its newline is completed with a
        virtual one, in a block marked as ``_Unterminated``."""
        rest = b""
        while True:
            data = read(CHUNK_BYTES)
            if not data:
                break
            cut = data.rfind(b"\n")
            if cut < 0:
                rest += data
                continue
            block = rest + data[: cut + 1] if rest else data[: cut + 1]
            rest = data[cut + 1 :]
            yield block
        if rest:
            yield _Unterminated(rest + b"\n")

    def chunk(self, buf: bytes) -> bytes:
        """Compensate ``buf``: lines (the last one may lack its ending)."""
        feed = self.feed
        if feed is None:
            return self._lines(buf, 0, None)
        pieces = []
        pos, size = 0, len(buf)
        while pos < size:
            out, stop = feed(buf, pos)
            pieces.append(out)
            if stop >= size:
                break
            pos = buf.find(b"\n", stop) + 1 or size
            pieces.append(self._lines(buf, stop, pos))
        return b"".join(pieces)

    def _lines(self, buf: bytes, start: int, end: Optional[int]) -> bytes:
        """buf[start:end] through ``Compensator.process`` line by line."""
        process = self.comp.process
        out = []
        for raw in UNIVERSAL.findall(buf[start:end].decode(ENCODING, ERRORS)):
            body, ending = split_ending(raw)
            res = process(body)
            out.append(raw if res is body else join_output(res, ending))
        return "".join(out).encode(ENCODING, ERRORS)


def compensate_binary(
    src: IO[bytes], dst: IO[bytes], params: Params, options: Optional[Options] = None, progress=None
) -> Report:
    """Compensate a binary stream (the same output as the line path, :func:`compensate_lines`).

    ``progress(bytes_read)`` is called as the input is consumed."""
    comp = make_compensator(params, options)
    refuse = functools.partial(head_marker, refuse=True)
    opts = options or Options()

    def header(head: str) -> str:  # the marker; a ballbar program also says how (marker.py)
        record = ballbar_record(head, opts.decimals, opts.deadband_mm)
        return marker_line(params) + ("\n" + record if record else "")

    FileEngine(comp).run(src.read, dst.write, header, refuse, progress)
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
            return compensate_binary(src, _NULL_SINK, params, options, progress)
    with open(in_path, "rb") as src, replacing(target, ".gcode") as dst:
        return compensate_binary(src, dst, params, options, progress)
