"""Whole-file compensation by blocks: the output of ``Compensator.process``, line for line,
for a file read a block (512 KB of complete lines) at a time.

Each block goes, where the model allows an accelerated engine, through the compiled kernel
(``Kernel.feed``: plain moves and arcs in C, engines/csrc) or, without the kernel, through the
vectorised numpy engine: the block is tokenised with byte-level numpy operations
(``tokens.py``, its numbers eight bytes at a time in ``numbers.py``) on a second thread while
the previous block is compensated; runs of plain ``G0``/``G1`` lines with single-spaced
X/Y/Z/E/F words are compensated and checked against the limits as whole arrays
(``rows.py``), and written as the rows of a byte matrix, numbers by table look-ups
(``text.py``), input spans copied, that is then read without its filler bytes
(``assembly.py``: one pass, cut only where a long input span is put in between). Every
other line (state changes, arcs, M-codes, odd spellings) goes through the reference path,
``Compensator.process``, in order; the state is handed over exactly, so the result is the
same text and report as feeding every line to ``Compensator.process`` (the tests and the
benchmark check that on whole files). Where the model allows no accelerated engine
(smoothed take-ups, servo lead, non-affine models), every line takes the reference path.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Callable, List, Optional

import numpy as np

from ...core.compensator import MM_PER_INCH, Compensator
from ...core.lines import UNIVERSAL as _UNIVERSAL
from ...core.lines import join_output, split_ending
from .rows import Rows, _ffill, emit_rows
from .tokens import Tokens

CHUNK_BYTES = 1 << 19
MIN_VECTOR_LINES = 24  # shorter runs go line by line (numpy call overhead)
_ENC = "utf-8"
_ERR = "surrogateescape"


class _Unterminated(bytes):
    """The last block of a file that did not end with a newline (one was added)."""


class FileEngine:
    """Feeds a whole file through one Compensator: the kernel's blocks, the vectorised runs
    of plain moves, every other line through ``Compensator.process``."""

    def __init__(self, comp: Compensator):
        self.comp = comp
        # the compiled fast path, where it was built: it takes the move lines one by one
        # at a fraction of the cost of the vectorised path (kernel.py)
        self.kernel = comp.fast
        self.vector_ok = comp.accelerable

    # -- driver --------------------------------------------------------------------------
    def run(
        self,
        read: Callable[[int], bytes],
        write: Callable[[bytes], object],
        header: Optional[str] = None,
        check_first: Optional[Callable[[str], None]] = None,
        progress: Optional[Callable[[int], None]] = None,
    ) -> None:
        """Compensate everything ``read`` yields into ``write``.

        ``header`` is written before the first line (with that line's ending), as the line
        path does; ``check_first`` sees the first lines of text (the marker check).
        Tokenising a block does not depend on the compensator's state, so the next block is
        tokenised on a second thread while the current one is compensated (numpy releases
        the GIL); the output is the same as doing it in turn.
        """
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="kincomp-tok") as pool:
            pending = None  # (block, future of its tokens)
            first = True
            done = 0
            for block in self._blocks(read):
                done += len(block)
                if progress is not None:
                    progress(done)
                if first:
                    self._start(block, header, check_first, write)
                    first = False
                job = (block, pool.submit(Tokens, block) if self._vectorised(block) else None)
                if pending is not None:
                    write(self._finish_block(*pending))
                pending = job
            if pending is not None:
                write(self._finish_block(*pending))

    @staticmethod
    def _blocks(read: Callable[[int], bytes]):
        """Blocks of complete lines; a last line without its newline is completed with a
        virtual one, in a block marked as ``_Unterminated`` (_finish_block drops it again)."""
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

    def _finish_block(self, block: bytes, tokens):
        if isinstance(block, _Unterminated) and block.endswith(b"\r\n"):
            # The file ended with a lone CR (its last line is terminated after all): the
            # virtual newline would make that ending CRLF, and the lines a last move expands
            # into would be joined with CRLF. The line path on the real bytes keeps the CR.
            return self._lines(block, 0, len(block) - 1)
        out = self.chunk(block, tokens.result() if tokens is not None else None)
        if isinstance(block, _Unterminated) and out.endswith(b"\n"):
            out = out[:-1]
        return out

    def _start(self, block: bytes, header, check_first, write) -> None:
        if isinstance(block, _Unterminated):  # the header takes the real first ending
            block = block[:-1]
        head = block[:16384].decode(_ENC, _ERR)
        if check_first is not None:
            check_first(head)
        if header is not None:
            first_line = _UNIVERSAL.match(head)
            ending = split_ending(first_line.group(0))[1] if first_line else ""
            write((header + (ending or "\n")).encode(_ENC, _ERR))

    # -- one block of complete lines ------------------------------------------------------
    def chunk(self, buf: bytes, tk: Optional[Tokens] = None) -> bytes:
        """Compensate one block of complete lines (``tk``: its tokens, if already made)."""
        if not self._vectorised(buf):
            if self.kernel is not None:
                return self._kernel_chunk(buf)
            return self._lines(buf, 0, None)
        if tk is None:
            tk = Tokens(buf)
        if tk.lone_cr or tk.nul:  # (a NUL byte: the row assembly's filler, assembly.py)
            return self._lines(buf, 0, None)
        pieces: list = []  # bytes and uint8 arrays (both are buffers)
        n = tk.n_lines
        i = 0
        for b in np.flatnonzero(tk.breaking).tolist() + [n]:
            if b > i:
                self._segment(tk, i, b, pieces)
            if b < n:
                pieces.append(self._lines(buf, int(tk.ls[b]), int(tk.le[b]) + 1))
            i = b + 1
        return b"".join(pieces)

    def _vectorised(self, buf: bytes) -> bool:
        """Whether this block takes the vectorised path: where the model allows it and
        there is no kernel."""
        return self.vector_ok and self.kernel is None

    def _kernel_chunk(self, buf: bytes) -> bytes:
        """One block through the compiled kernel; each line it does not take (state
        changes, M-codes, a lone CR ...) through the compensator."""
        feed, comp = self.kernel.feed, self.comp
        pieces = []
        pos, size = 0, len(buf)
        while pos < size:
            out, stop = feed(comp.state, buf, pos)
            pieces.append(out)
            if stop >= size:
                break
            pos = buf.index(b"\n", stop) + 1
            pieces.append(self._lines(buf, stop, pos))
        return b"".join(pieces)

    def _lines(self, buf: bytes, start: int, end: Optional[int]) -> bytes:
        """Feed buf[start:end] (complete lines) to the compensator line by line."""
        comp = self.comp
        text = buf[start:end].decode(_ENC, _ERR)
        out = []
        for raw in _UNIVERSAL.findall(text):
            body, ending = split_ending(raw)
            res = comp.process(body)
            if res is body:
                out.append(raw)
            else:
                out.append(join_output(res, ending))
        return "".join(out).encode(_ENC, _ERR)

    def _segment(self, tk: Tokens, i0: int, i1: int, pieces: List[bytes]) -> None:
        """Lines [i0, i1) of the block: no line among them changes the modal state."""
        comp = self.comp
        buf = tk.buf
        start, end = int(tk.ls[i0]), int(tk.le[i1 - 1]) + 1
        cand = np.flatnonzero(tk.cand[i0:i1]) + i0
        if len(cand) == 0:  # comments and inert commands only
            comp.state.lineno += i1 - i0
            comp.report.lines += i1 - i0
            comp.report.lines_out += i1 - i0
            pieces.append(buf[start:end])
            return
        j0, j1 = np.searchsorted(tk.move_lines, [i0, i1]).tolist()
        result = None
        if not (
            i1 - i0 < MIN_VECTOR_LINES
            or not comp.state.absolute
            or None in comp.state.m
            or comp.state.q_drive is not None
            or tk.move_bad_number[j0:j1].any()
        ):
            result = self._vector(tk, i0, i1, cand, j0, j1)
        # short runs, or a limit error (the line path raises at its line)
        if result is not None:
            pieces.extend(result)
        else:
            pieces.append(self._lines(buf, start, end))

    # -- runs of plain moves ---------------------------------------------------------------
    def _vector(
        self, tk: Tokens, i0: int, i1: int, cand: np.ndarray, j0: int, j1: int
    ) -> Optional[List[bytes]]:
        """Lines [i0, i1) with no state-changing line among them, vectorised: the output
        in pieces (buffers), or None where the line path has to write them."""
        comp = self.comp
        moves = tk.move_lines[j0:j1]
        nm = len(moves)
        if nm == 0:
            return [self._finish_inert(tk, i0, i1, cand)]
        u = MM_PER_INCH if comp.state.inches else 1.0
        v3 = tk.move_vals[:, j0:j1]  # (3, nm), NaN where the axis is not given
        g3 = ~np.isnan(v3)
        P = np.empty((3, nm))
        for k in range(3):
            P[k] = _ffill(v3[k] * u - comp.state.w[k], g3[k], comp.state.m[k])
        seg_start, seg_end = int(tk.ls[i0]), int(tk.le[i1 - 1]) + 1
        ls = tk.ls[moves] - seg_start
        xyz_end = tk.xyz_end[j0:j1] - seg_start
        pre_s = np.empty(nm, np.int64)
        pre_s[0] = 0
        pre_s[1:] = xyz_end[:-1]
        rows = Rows(
            P,
            g3,
            moves,
            tk.crlf[moves],
            pre_s,
            ls - pre_s,
            ls,
            tk.fpre_start[j0:j1] - seg_start,
            tk.fpre_end[j0:j1] - tk.fpre_start[j0:j1],
            int(xyz_end[-1]),
        )
        res = emit_rows(self.comp, i0, rows, tk.a[seg_start:seg_end])
        if res is None:
            return None
        out, n_take = res
        self._finish_counts(tk, i0, i1, cand, nm, n_take)
        return out

    # -- counts ----------------------------------------------------------------------------
    def _finish_counts(self, tk, i0, i1, cand, n_moves, n_take) -> None:
        """Report counts, feed and E position after lines [i0, i1)."""
        comp = self.comp
        rep = comp.report
        nl = i1 - i0
        comp.state.lineno += nl
        rep.lines += nl
        rep.lines_out += nl + n_take
        rep.moves += len(cand)
        rep.moves_compensated += n_moves
        rep.takeup_moves += n_take
        u = MM_PER_INCH if comp.state.inches else 1.0
        fl = tk.last_value(5, i0, i1)
        if fl is not None:
            comp.state.feed = fl[1] * u
        if not comp.e_relative:
            el = tk.last_value(4, i0, i1)
            if el is not None:
                comp.state.e_pos = el[1]
        elif comp.state.e_pos is not None:  # relative E adds up (MoveHandler.track_e)
            e = comp.state.e_pos
            for v in tk.values(4, i0, i1):
                e = e + v
            comp.state.e_pos = e

    def _finish_inert(self, tk, i0, i1, cand) -> bytes:
        self._finish_counts(tk, i0, i1, cand, 0, 0)
        return tk.buf[int(tk.ls[i0]) : int(tk.le[i1 - 1]) + 1]
