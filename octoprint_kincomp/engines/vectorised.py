"""Vectorised file compensation: the output of ``Compensator.process``, line for line, for the
lines that make up slicer output, computed a chunk at a time with numpy.

Why: a Python loop costs microseconds per line, a G-code file has millions of lines. Here a
chunk of the file is tokenised with byte-level numpy operations; the lines that matter
(``G0``/``G1`` with single-spaced X/Y/Z/E/F words, optionally a comment) are compensated
together, and everything else - comments and most M-codes unchanged, any line that changes the
modal state (G90/G91/G92/G2/G3/G28/T/M82/M83 ...) through the one streaming engine,
``Compensator.process`` - in order. The state is handed over exactly, so the result is the
same text and the same report as feeding every line to ``Compensator.process``; the tests and
the benchmark check that on whole files.

The vectorised part applies where the per-line fast path of the compensator applies (affine
model, no backlash smoothing, no servo lead, absolute mode, every axis known); elsewhere this
module simply feeds lines to the compensator.

Arcs as slicers write them (``G2``/``G3`` with X, Y, I, J, E, F words, XY plane) do not break
a vectorised run: each is linearised in Python with the very functions the line path uses
(``arcs.linearise``, the E split of the compensator), and its chords join the run as rows
of the vectorised compensation and formatting. Any other arc goes through the compensator.
"""

from __future__ import annotations

import bisect
import math
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Dict, List, NamedTuple, Optional, Tuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..core import arcs as _arcs
from ..core.backlash import hysteresis
from ..core.compensator import MM_PER_INCH, Compensator
from ..core.gcode import Word
from ..core.lines import UNIVERSAL as _UNIVERSAL
from ..core.lines import join_output, split_ending
from ..core.path import EDistribution

CHUNK_BYTES = 1 << 19
MIN_VECTOR_LINES = 24  # shorter runs go line by line (numpy call overhead)
NUM_WIDTH = 10  # longest number token parsed here (longer ones take the line-by-line path)
_ENC = "utf-8"
_ERR = "surrogateescape"

# byte classes: numbers weigh digit 1, '.' 32, anything else 128 (a sign is checked apart);
# separators are >= 250
_CLS = bytearray([128] * 256)
for _c in b"0123456789":
    _CLS[_c] = 1
_CLS[ord(".")] = 32
_SP, _SEMI, _CR, _NL, _TAB = 250, 251, 252, 253, 254
_CLS[ord(" ")] = _SP
_CLS[ord(";")] = _SEMI
_CLS[ord("\r")] = _CR
_CLS[ord("\n")] = _NL
_CLS[ord("\t")] = _TAB
_CLS = bytes(_CLS)

_LETTER = np.zeros(256, np.int8)  # X=1 Y=2 Z=3 E=4 F=5
for _i, _c in enumerate(b"XYZEF"):
    _LETTER[_c] = _i + 1
_DIGIT = np.zeros(256, np.float64)
_DIGIT[48:58] = np.arange(10)
_P10F = 10.0 ** np.arange(24)
_LUT4 = np.frombuffer(b"".join(b"%03d\0" % i for i in range(1000)), np.uint32)
_COLS = np.arange(32)
_DIGIT32 = _DIGIT.astype(np.float32)
_P10F32 = (10.0 ** np.arange(8)).astype(np.float32)
_PLACE32 = np.arange(32, dtype=np.float32)
_P10I = 10 ** np.arange(19, dtype=np.int64)
_BREAK_FIRST = np.zeros(256, bool)  # first byte of a line that may change the state
for _c in b"GgTtNnm\t \x0b\x0c":
    _BREAK_FIRST[_c] = True
# Compensator.process strips any Unicode whitespace before the code (str.lstrip), so a line
# starting with \x1c..\x1f or a non-ASCII byte (U+0085, U+00A0, U+2003 ...) may be a move:
# it takes the line-by-line path (treated as inert, such a move was left uncompensated).
_BREAK_FIRST[0x1C:0x20] = True
_BREAK_FIRST[0x80:] = True
_AXIS_BYTES = (b" X", b" Y", b" Z")


def _ffill(values: np.ndarray, given: np.ndarray, start: float) -> np.ndarray:
    """Forward-fill ``values`` where ``given`` is False, ``start`` before the first given."""
    idx = np.where(given, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where(idx >= 0, values[np.maximum(idx, 0)], start)
    return out


def _ffill_int(values: np.ndarray, start: int) -> np.ndarray:
    """Forward-fill the non-zero entries of ``values``; ``start`` before the first."""
    idx = np.where(values != 0, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], start)


def _interp(table, q: np.ndarray) -> np.ndarray:
    """BacklashAxis.um_at for an array, with the same arithmetic (see params.py)."""
    pts = table.points
    if len(pts) == 1:
        return np.full(len(q), pts[0][1])
    out = np.full(len(q), pts[0][1])
    for (p0, v0), (p1, v1) in zip(pts, pts[1:]):
        val = (v1 - v0) / (p1 - p0) * (q - p0) + v0
        out = np.where((q > p0) & (q < p1), val, out)
        out = np.where(q == p1, v1, out)
    return np.where(q >= pts[-1][0], pts[-1][1], out)


class _Formatter:
    """Fixed-point text of floats, identical to ``"%.{dec}f" % v`` without negative zero."""

    def __init__(self, dec: int):
        self.dec = dec
        self.scale = 10.0 ** dec

    def ints(self, v: np.ndarray):
        """(magnitude in units of 10**-dec as int64, negative flag)."""
        r = np.abs(v) * self.scale
        n = np.floor(r + 0.5)
        frac = r - np.floor(r)
        risky = (np.abs(frac - 0.5) < 1e-6) | (r > 1e12) | ~np.isfinite(r)
        if risky.any():  # exact decimal rounding of the binary value: let Python decide
            fmt = "%." + str(self.dec) + "f"
            for i in np.flatnonzero(risky).tolist():
                text = fmt % float(v[i])
                n[i] = float(int(text.lstrip("-").replace(".", "")))
        n = n.astype(np.int64)
        return n, (v < 0) & (n > 0)

    def text(self, n: int, neg: bool) -> str:
        s = str(n).rjust(self.dec + 1, "0")
        s = s[: -self.dec] + "." + s[-self.dec:] if self.dec else s
        return "-" + s if neg else s

    def fill(self, fullT: np.ndarray, maskT: np.ndarray, col: int, width: int, letter: int,
             n: np.ndarray, neg: np.ndarray, written: np.ndarray) -> np.ndarray:
        """Write " <letter><number>" into rows col..col+width of the transposed row matrix
        ``fullT`` (one matrix row per output column, so every write is one long 1-D run).

        Layout of the block: space, letter, sign slot, integer digits (right-aligned), dot,
        decimals; ``maskT`` selects what is really written. Returns each row's length (0 if
        not written). Digits come three at a time from a table of "000".."999".
        """
        dec = self.dec
        n_int = width - 4 - dec
        ip = n // _P10I[dec]
        nint = np.ones(len(n), np.int64)
        for e in range(1, n_int):
            nint += ip >= _P10I[e]
        start = 3 + n_int - nint - neg  # first written column after " X"
        fullT[col] = 32
        fullT[col + 1] = letter
        maskT[col] = written
        maskT[col + 1] = written
        right = col + width - 1
        rest = n
        place = 0
        while place < dec + n_int:
            cell = _LUT4[rest % 1000]
            rest = rest // 1000
            for j in (2, 1, 0):  # "ddd": byte 2 is the least significant digit
                if place >= dec + n_int:
                    break
                pos = right - place if place < dec else right - place - 1
                fullT[pos] = (cell >> (8 * j)) & 0xFF
                if place < dec:
                    maskT[pos] = written
                else:
                    maskT[pos] = written & (pos - col >= start)
                place += 1
        fullT[right - dec] = 46
        maskT[right - dec] = written
        sign_col = col + 2 + n_int - nint  # just before the first integer digit
        ng = np.flatnonzero(neg & written)
        if len(ng):
            fullT[sign_col[ng], ng] = 45
            maskT[sign_col[ng], ng] = True
        return np.where(written, 2 + neg + nint + 1 + dec, 0)


class _Chords(NamedTuple):
    """The chord rows of a run's arcs (FileEngine._chords)."""

    P: List[Tuple[float, float, float]]
    given: List[Tuple[bool, bool, bool]]
    line: List[int]
    first: List[bool]  # the first chord of its arc (it takes the input before the arc)
    post: List[Tuple[int, int]]  # (start, length) of the tail in the synthetic pool
    synth: List[str]  # the synthetic pool: "G1", then the chord tails
    n: int
    last_e: Optional[Tuple[int, float]]  # (line, value) of the last E word of the arcs
    last_f: Optional[Tuple[int, float]]


class _Rows(NamedTuple):
    """Output rows of a vectorised run (moves and arc chords) and where their bytes come
    from: spans of the pool (segment input, then synthetic bytes); ``resume`` is where the
    input continues after the last row."""

    P: np.ndarray  # (n, 3) desired machine points, mm
    given: np.ndarray  # (n, 3) axes written whatever their text
    line: np.ndarray  # line index in the block (limit reports, endings)
    crlf: np.ndarray  # the line ends with CRLF (take-up rows copy it)
    pre_s: np.ndarray
    pre_l: np.ndarray
    code_s: np.ndarray  # 2 bytes: "G0"/"G1"
    fpre_s: np.ndarray
    fpre_l: np.ndarray
    post_s: np.ndarray
    post_l: np.ndarray
    resume: int


# A line is read by its shape: the line with the number characters deleted, e.g.
# "G2 X12.5 Y-3 I1 J0 E0.41" -> "G X Y I J E". A number then consists of [0-9.+-] only, and
# on that alphabet float() accepts exactly the grammar of gcode.parse_words (anything else
# raises and the reference path reports the line); lines longer than FAST_MAX_LEN (the
# kernel's MAX_LINE) take the reference path, so no number reaches gcode.MAX_WORD_VALUE.
NUMBER_BYTES = b"0123456789.+-"
FAST_MAX_LEN = 96


def word_shapes(letters: str):
    """Every shape for words ``letters`` in this order, each one present or not: (present
    flags, token index of each letter in ``line.split(" ")`` (0: absent), the shape)."""
    for mask in range(1 << len(letters)):
        on = [bool(mask >> i & 1) for i in range(len(letters))]
        idx, n = [], 1
        for present in on:
            idx.append(n if present else 0)
            n += present
        key = " ".join(["G"] + [c for c, present in zip(letters, on) if present]).encode()
        yield on, idx, key


# slicer-style arcs: G2/G3, then X Y I J E F words in this order (I or J at least), single
# spaces, no comment
_ARC_SHAPES = {key: tuple(idx) for on, idx, key in word_shapes("XYIJEF") if on[2] or on[3]}


class _Arc(NamedTuple):
    clockwise: bool
    x: Optional[float]
    y: Optional[float]
    i: Optional[float]
    j: Optional[float]
    e_word: Optional[Word]
    f_text: Optional[str]  # the F word as written (it follows E)
    f: Optional[float]
    given: Tuple[bool, bool, bool]
    crlf: bool


def _parse_arc(raw: bytes) -> Optional[_Arc]:
    """A simple arc line (with its ending), or None for the compensator to handle."""
    crlf = raw[-2:] == b"\r\n"
    body = raw[:-2] if crlf else raw[:-1]
    if len(body) > FAST_MAX_LEN or body[:3] not in (b"G2 ", b"G3 "):
        return None
    shape = _ARC_SHAPES.get(body.translate(None, NUMBER_BYTES))
    if shape is None:
        return None
    ix, iy, ii, ij, ie, i_f = shape
    parts = body.split(b" ")
    try:  # on [0-9.+-] float() accepts the G-code number grammar exactly
        x = float(parts[ix][1:]) if ix else None
        y = float(parts[iy][1:]) if iy else None
        i = float(parts[ii][1:]) if ii else None
        j = float(parts[ij][1:]) if ij else None
        e = float(parts[ie][1:]) if ie else None
        f = float(parts[i_f][1:]) if i_f else None
    except ValueError:
        return None  # malformed: the compensator reports it
    e_word = Word("E", e, parts[ie].decode("ascii")) if ie else None
    f_text = parts[i_f].decode("ascii") if i_f else None
    return _Arc(body[1] == 50, x, y, i, j, e_word, f_text, f, (bool(ix), bool(iy), False),
                crlf)


class _Unterminated(bytes):
    """The last block of a file that did not end with a newline (one was added)."""


class FileEngine:
    """Feeds a whole file through one Compensator, vectorising the plain move lines."""

    def __init__(self, comp: Compensator):
        self.comp = comp
        # the compiled fast path, where it was built: it takes the move lines one by one
        # at a fraction of the cost of the vectorised path (kernel.py)
        self.kernel = comp.fast
        self.vector_ok = comp.accelerable

    # -- driver --------------------------------------------------------------------------
    def run(self, read: Callable[[int], bytes], write: Callable[[bytes], object],
            header: Optional[str] = None,
            check_first: Optional[Callable[[str], None]] = None,
            progress: Optional[Callable[[int], None]] = None) -> None:
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
                job = (block, pool.submit(_Tokens, block) if self._vectorised(block) else None)
                if pending is not None:
                    write(self._finish_block(*pending))
                pending = job
            if pending is not None:
                write(self._finish_block(*pending))

    @staticmethod
    def _blocks(read: Callable[[int], bytes]):
        """Blocks of complete lines; the last one is completed with a virtual newline and
        marked by a trailing ``None`` sentinel handled in _finish_block."""
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
            rest = data[cut + 1:]
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
        if isinstance(block, _Unterminated) and len(out) and out[-1] in (10, b"\n"[0]):
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
    def chunk(self, buf: bytes, tk: Optional["_Tokens"] = None) -> bytes:
        """Compensate one block of complete lines (``tk``: its tokens, if already made)."""
        if not self._vectorised(buf):
            if self.kernel is not None:
                return self._kernel_chunk(buf)
            return self._lines(buf, 0, None)
        if tk is None:
            tk = _Tokens(buf)
        if tk.lone_cr:
            return self._lines(buf, 0, None)
        pieces: list = []  # bytes and uint8 arrays (both are buffers)
        brk = tk.breaking
        n = tk.n_lines
        # slicer-style arcs need not break a run (see the module doc)
        soft: Dict[int, "_Arc"] = {}
        for b in np.flatnonzero(brk & tk.arc_start).tolist():
            arc = _parse_arc(buf[int(tk.ls[b]): int(tk.le[b]) + 1])
            if arc is not None:
                soft[b] = arc
        i = 0
        soft_lines = sorted(soft)
        si = 0
        for b in [x for x in np.flatnonzero(brk).tolist() if x not in soft] + [n]:
            if b > i:
                inner = []
                while si < len(soft_lines) and soft_lines[si] < b:
                    inner.append(soft_lines[si])
                    si += 1
                if inner:
                    self._run(tk, i, b, inner, soft, pieces)
                else:
                    self._segment(tk, i, b, pieces)
            if b < n:
                pieces.append(self._lines(buf, int(tk.ls[b]), int(tk.le[b]) + 1))
            i = b + 1
        if len(pieces) == 1 and not isinstance(pieces[0], bytes):
            return pieces[0]
        return b"".join(pieces)

    def _vectorised(self, buf: bytes) -> bool:
        """Whether this block takes the vectorised path: where the model allows it, if
        there is no kernel, or if the block has slicer-style arcs (the vectorised path
        linearises them in bulk; the kernel would leave each to the line path)."""
        return self.vector_ok and (self.kernel is None or buf.startswith((b"G2 ", b"G3 "))
                                   or b"\nG2 " in buf or b"\nG3 " in buf)

    def _kernel_chunk(self, buf: bytes) -> bytes:
        """One block through the compiled kernel; each line it does not take (state
        changes, arcs, M-codes, a lone CR ...) through the compensator."""
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

    def _segment(self, tk: "_Tokens", i0: int, i1: int, pieces: List[bytes]) -> None:
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
        if not (i1 - i0 < MIN_VECTOR_LINES or not comp.state.absolute or None in comp.state.m
                or comp.state.q_drive is not None or tk.move_bad_number[j0:j1].any()):
            result = self._vector(tk, i0, i1, cand, j0, j1)
        # short runs, or a limit error (the line path raises at its line)
        pieces.append(result if result is not None else self._lines(buf, start, end))

    # -- the vectorised computation ------------------------------------------------------
    def _vector(self, tk: "_Tokens", i0: int, i1: int, cand: np.ndarray, j0: int,
                j1: int) -> Optional[bytes]:
        """Lines [i0, i1) with no state-changing line among them, vectorised."""
        comp = self.comp
        moves = tk.move_lines[j0:j1]
        nm = len(moves)
        if nm == 0:
            return self._finish_inert(tk, i0, i1, cand)
        u = MM_PER_INCH if comp.state.inches else 1.0
        v3 = tk.move_vals[j0:j1]  # (nm, 3), NaN where the axis is not given
        g3 = ~np.isnan(v3)
        P = np.empty((nm, 3))
        for k in range(3):
            P[:, k] = _ffill(v3[:, k] * u - comp.state.w[k], g3[:, k], comp.state.m[k])
        seg_start, seg_end = int(tk.ls[i0]), int(tk.le[i1 - 1]) + 1
        ls = tk.ls[moves] - seg_start
        xyz_end = tk.xyz_end[j0:j1] - seg_start
        pre_s = np.empty(nm, np.int64)
        pre_s[0] = 0
        pre_s[1:] = xyz_end[:-1]
        zero = np.zeros(nm, np.int64)
        rows = _Rows(P, g3, moves, tk.crlf[moves], pre_s, ls - pre_s, ls,
                     tk.fpre_start[j0:j1] - seg_start, tk.fpre_end[j0:j1] - tk.fpre_start[j0:j1],
                     zero, zero, int(xyz_end[-1]))
        res = self._emit_rows(tk, i0, rows, tk.a[seg_start:seg_end], b"")
        if res is None:
            return None
        out, n_take = res
        self._finish_counts(tk, i0, i1, cand, nm, n_take)
        return out

    # -- runs with slicer-style arcs ------------------------------------------------------
    def _run(self, tk: "_Tokens", i0: int, i1: int, arc_lines: List[int],
             arcs: Dict[int, "_Arc"], pieces: List[bytes]) -> None:
        """Lines [i0, i1): no state-changing line but the simple arcs at ``arc_lines``."""
        comp = self.comp
        out = None
        if not (i1 - i0 < MIN_VECTOR_LINES or not comp.state.absolute or None in comp.state.m
                or comp.state.q_drive is not None or comp.state.plane != 17
                or comp.state.ij_absolute or comp.pure_translation):
            out = self._mixed(tk, i0, i1, arc_lines, arcs)
        if out is None:
            # what the vector path does not decide (an arc error, a limit error, absolute
            # E from an unknown position, a modal state it does not handle): as before
            self._split(tk, i0, i1, arc_lines, pieces)
        else:
            pieces.append(out)

    def _split(self, tk: "_Tokens", i0: int, i1: int, arc_lines: List[int],
               pieces: List[bytes]) -> None:
        """Lines [i0, i1) with the arcs at ``arc_lines`` taken as breaking lines."""
        i = i0
        for b in arc_lines + [i1]:
            if b > i:
                self._segment(tk, i, b, pieces)
            if b < i1:
                pieces.append(self._lines(tk.buf, int(tk.ls[b]), int(tk.le[b]) + 1))
            i = b + 1

    def _mixed(self, tk: "_Tokens", i0: int, i1: int, arc_lines: List[int],
               arcs: Dict[int, "_Arc"]) -> Optional[bytes]:
        """Moves and simple arcs of lines [i0, i1) in one vectorised pass; None (nothing
        changed) when the line path has to decide."""
        comp = self.comp
        u = MM_PER_INCH if comp.state.inches else 1.0
        j0, j1 = np.searchsorted(tk.move_lines, [i0, i1]).tolist()
        if tk.move_bad_number[j0:j1].any():
            return None
        real = tk.move_lines[j0:j1]
        nr, na = len(real), len(arc_lines)
        # targets of moves and arcs in line order, forward-filled as the line path does
        lines = np.concatenate([real, np.asarray(arc_lines, np.int64)])
        order = np.argsort(lines, kind="stable")
        V = np.full((nr + na, 3), np.nan)
        V[:nr] = tk.move_vals[j0:j1]
        for n, a in enumerate(arc_lines):
            arc = arcs[a]
            V[nr + n, 0] = arc.x if arc.x is not None else np.nan
            V[nr + n, 1] = arc.y if arc.y is not None else np.nan
        V = V[order]
        G = ~np.isnan(V)
        T = np.empty_like(V)
        for k in range(3):
            T[:, k] = _ffill(V[:, k] * u - comp.state.w[k], G[:, k], comp.state.m[k])
        arc_pos = np.flatnonzero(order >= nr)  # where the arcs are among the targets
        seg_start, seg_end = int(tk.ls[i0]), int(tk.le[i1 - 1]) + 1
        ch = self._chords(tk, i0, i1, arc_lines, arcs, T, arc_pos)
        if ch is None:
            return None
        chord_P, chord_given, chord_line, chord_first, chord_post, synth = ch[:6]
        n_chords, last_arc_e, last_arc_f = ch[6:]
        # rows: moves and chords in output order
        lines_all = np.concatenate([real, np.asarray(chord_line, np.int64)])
        rorder = np.argsort(lines_all, kind="stable")
        nrows = nr + n_chords
        is_chord = rorder >= nr
        P = np.empty((nrows, 3))
        P[~is_chord] = T[order < nr]
        P[is_chord] = np.asarray(chord_P, np.float64).reshape(-1, 3)
        g3 = np.empty((nrows, 3), bool)
        g3[~is_chord] = G[order < nr]
        g3[is_chord] = np.asarray(chord_given, bool).reshape(-1, 3)
        row_line = lines_all[rorder]
        crlf = tk.crlf[row_line]
        # byte spans: input (relative to the segment start), then the synthetic pool
        base_syn = seg_end - seg_start
        ls = tk.ls[row_line] - seg_start
        code_s = np.where(is_chord, base_syn, ls)
        fpre_s = np.zeros(nrows, np.int64)
        fpre_l = np.zeros(nrows, np.int64)
        rm = ~is_chord
        fpre_s[rm] = tk.fpre_start[j0:j1] - seg_start
        fpre_l[rm] = tk.fpre_end[j0:j1] - tk.fpre_start[j0:j1]
        post_s = np.zeros(nrows, np.int64)
        post_l = np.zeros(nrows, np.int64)
        cp = np.asarray(chord_post, np.int64).reshape(-1, 2)
        post_s[is_chord] = base_syn + cp[:, 0]
        post_l[is_chord] = cp[:, 1]
        # where the input resumes after each row: after a move's X/Y/Z words, after the
        # whole line of an arc's last chord; a chord other than the first takes no input
        resume = np.empty(nrows, np.int64)
        resume[rm] = tk.xyz_end[j0:j1] - seg_start
        resume[is_chord] = tk.le[row_line[is_chord]] + 1 - seg_start
        first = np.ones(nrows, bool)
        first[is_chord] = np.asarray(chord_first, bool)
        pre_s = np.empty(nrows, np.int64)
        pre_s[0] = 0
        pre_s[1:] = resume[:-1]
        pre_l = np.where(first, ls - pre_s, 0)
        pre_s = np.where(first, pre_s, 0)
        rows = _Rows(P, g3, row_line, crlf, pre_s, pre_l, code_s, fpre_s, fpre_l, post_s,
                     post_l, int(resume[-1]))
        res = self._emit_rows(tk, i0, rows, tk.a[seg_start:seg_end],
                              "".join(synth).encode("ascii"))
        if res is None:
            return None
        out, n_take = res
        cand = np.flatnonzero(tk.cand[i0:i1]) + i0
        self._finish_counts(tk, i0, i1, cand, nr + na, n_take, na, n_chords,
                            last_arc_e, last_arc_f)
        return out

    def _chords(self, tk: "_Tokens", i0: int, i1: int, arc_lines: List[int],
                arcs: Dict[int, "_Arc"], T: np.ndarray, arc_pos: np.ndarray
                ) -> Optional["_Chords"]:
        """The arcs of a run linearised as the line path does (``T``: the targets of moves
        and arcs in line order, ``arc_pos``: the arcs among them): their chord rows and the
        synthetic bytes of those rows; None when the line path has to decide."""
        comp = self.comp
        u = MM_PER_INCH if comp.state.inches else 1.0
        # E positions before each arc (absolute E only), from the E words of the run
        e_rel = comp.e_relative
        e_lines, e_starts, e_ends = tk.e_words(i0, i1)
        breaks = comp.moves.extreme_angles(17)
        tol = comp.options.chord_tol_mm
        synth = ["G1"]  # the synthetic pool: "G1", then the chord tails
        synth_len = 2
        chord_P: List[Tuple[float, float, float]] = []
        chord_given: List[Tuple[bool, bool, bool]] = []
        chord_line: List[int] = []
        chord_post: List[Tuple[int, int]] = []
        chord_first: List[bool] = []
        n_chords = 0
        last_arc_e: Optional[Tuple[int, float]] = None
        last_arc_f: Optional[Tuple[int, float]] = None
        Tl = T.tolist()
        m0 = tuple(float(v) for v in comp.state.m)
        e_list = e_lines.tolist()
        no_axes = (False, False, False)
        sqrt = math.sqrt
        linearise = _arcs.linearise
        for n, a in enumerate(arc_lines):
            arc = arcs[a]
            pos = int(arc_pos[n])
            start = tuple(Tl[pos - 1]) if pos > 0 else m0
            end = tuple(Tl[pos])
            e_word = arc.e_word
            e0 = None
            if e_word is not None and not e_rel:
                # the E position before the arc: the last E word of a move or an arc
                j = bisect.bisect_left(e_list, a) - 1
                tok_line = e_list[j] if j >= 0 else -1
                if last_arc_e is not None and last_arc_e[0] > tok_line:
                    e0 = last_arc_e[1]
                elif j >= 0:
                    e0 = float(tk.buf[int(e_starts[j]) + 1: int(e_ends[j])])
                else:
                    e0 = comp.state.e_pos
                if e0 is None:
                    return None  # absolute E from an unknown E: the line path passes it
            ca = start[0] + (arc.i * u if arc.i is not None else 0.0)
            cb = start[1] + (arc.j * u if arc.j is not None else 0.0)
            try:
                pts = linearise(start, end, 17, ca, cb, arc.clockwise, tol, 0, breaks)
            except _arcs.ArcError:
                return None  # malformed: reported by the line path
            # chord lengths exactly as the line path sums them (0 + dx^2 + dy^2 + dz^2)
            lengths = []
            px, py, pz = start
            for x, y, z in pts:
                lengths.append(sqrt((x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2))
                px, py, pz = x, y, z
            last = len(pts) - 1
            ending = "\r\n" if arc.crlf else "\n"
            f_text = arc.f_text
            if e_word is not None:
                edist = EDistribution(e_word, e_rel, e0, sum(lengths))
                s_done = 0.0
            for idx in range(last + 1):
                if e_word is not None:
                    s_done += lengths[idx]
                    post = " " + edist.take(s_done, idx == last)
                else:
                    post = ""
                if idx == 0 and f_text is not None:
                    post += " " + f_text  # the line's other words go on the first chord
                post += ending
                chord_post.append((synth_len, len(post)))  # ASCII: characters are bytes
                synth.append(post)
                synth_len += len(post)
            chord_P.extend(pts)
            chord_given.extend([no_axes] * last)
            chord_given.append(arc.given)
            chord_line.extend([a] * (last + 1))
            chord_first.append(True)
            chord_first.extend([False] * last)
            n_chords += last + 1
            if e_word is not None:
                last_arc_e = (a, e_word.value)
            if arc.f is not None:
                last_arc_f = (a, arc.f)
        return _Chords(chord_P, chord_given, chord_line, chord_first, chord_post, synth,
                       n_chords, last_arc_e, last_arc_f)

    # -- the vectorised computation ------------------------------------------------------
    def _emit_rows(self, tk: "_Tokens", i0: int, rows: "_Rows", seg: np.ndarray,
                   synth: bytes) -> Optional[Tuple[np.ndarray, int]]:
        """Compensate and render ``rows`` (desired machine points, in order); the output
        bytes and the number of take-up moves, or None when the line path has to decide
        (a limit error under the policy 'error'). Nothing is changed in the compensator
        then."""
        comp = self.comp
        rep = comp.report
        opts = comp.options
        u = MM_PER_INCH if comp.state.inches else 1.0
        dec = opts.decimals + (2 if comp.state.inches else 0)
        fmtr = _Formatter(dec)
        P, g3, moves = rows.P, rows.given, rows.line
        nm = len(P)
        m0 = comp.state.m
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = comp.model.inverse_rows
        b0, b1, b2 = comp.model.offset_mm
        x, y, z = P[:, 0] - b0, P[:, 1] - b1, P[:, 2] - b2
        Q = np.empty((nm, 3))
        Q[:, 0] = a00 * x + a01 * y + a02 * z
        Q[:, 1] = a10 * x + a11 * y + a12 * z
        Q[:, 2] = a20 * x + a21 * y + a22 * z
        q0 = comp.state.q_last
        if q0 is None:
            q0 = comp.model.inverse(m0)
        Qp = np.empty_like(Q)
        Qp[0] = q0
        Qp[1:] = Q[:-1]
        Pp = np.empty_like(P)
        Pp[0] = m0
        Pp[1:] = P[:-1]
        bl = comp.backlash
        dirs_after = np.zeros((nm, 3), np.int64)
        rev_any = np.zeros(nm, bool)
        anchors = list(bl.s.anchor)
        for k in range(3):
            if bl.active[k]:
                # the tracker's own comparisons (q against anchor -/+ deadband: rounding at
                # the deadband's edge must not differ from it)
                up = Q[:, k] > Qp[:, k] + bl.deadband
                down = Q[:, k] < Qp[:, k] - bl.deadband
                a = bl.s.anchor[k]
                if (a is not None and a != q0[k]) or np.any(
                        ~up & ~down & (Q[:, k] != Qp[:, k])):
                    # the anchor is not the current command somewhere: the tracker's
                    # hysteresis, point by point (arcs put chord ends next to reversals)
                    dk, rk, anchors[k] = hysteresis(Q[:, k].tolist(), bl.s.dir[k], a, q0[k],
                                                    bl.deadband)
                    dirs_after[:, k] = dk
                    rev_any |= np.asarray(rk, bool)
                    continue
                # anchored at the start and no sub-deadband step: the anchor is always the
                # current command, so a reversal is a step beyond the deadband against dir
                s = np.where(up, 1, np.where(down, -1, 0))
                after = _ffill_int(s, bl.s.dir[k])
                before = np.empty_like(after)
                before[0] = bl.s.dir[k]
                before[1:] = after[:-1]
                rev_any |= (s != 0) & (s != before)
                dirs_after[:, k] = after
                anchors[k] = float(Q[-1, k])
            else:
                dirs_after[:, k] = bl.s.dir[k]
        half = comp.backlash.half
        C = Q.copy()
        tups = np.flatnonzero(rev_any)
        Ct = Qp[tups].copy()
        Pt = Pp[tups]
        for k in range(3):
            if bl.active[k]:
                # rows with no direction get + 0.0: the same number (and the same text)
                d = dirs_after[:, k]
                C[:, k] += d * half * _interp(bl.tables[k], Q[:, k])
                dt = d[tups]
                Ct[:, k] += dt * half * _interp(bl.tables[k], Ct[:, k])
        # where each point is emitted: take-ups right before their rows
        order_pos = np.arange(nm) + np.cumsum(rev_any)
        tpos = tups + np.arange(len(tups))
        if opts.limits is not None:
            ok = self._limits(C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves, i0)
            if not ok:
                return None
        # max correction per axis (um)
        for k, a in enumerate("xyz"):
            cm = float(np.max(np.abs(C[:, k] - P[:, k]))) * 1000.0
            if len(tups):
                cm = max(cm, float(np.max(np.abs(Ct[:, k] - Pt[:, k]))) * 1000.0)
            if cm > rep.max_correction_um[a]:
                rep.max_correction_um[a] = cm
        # text (as scaled integers) of every evaluated point, in emission order
        ntot = nm + len(tups)
        N = np.empty((ntot, 3), np.int64)
        NEG = np.empty((ntot, 3), bool)
        G = np.empty((ntot, 3), np.float64)
        for k in range(3):
            G[order_pos, k] = C[:, k]
            if len(tups):
                G[tpos, k] = Ct[:, k]
            fw = (G[:, k] + comp.state.g[k]) / u
            N[:, k], NEG[:, k] = fmtr.ints(fw)
        # written: given axes of moves, or text changed since the previous point
        prevN = np.empty_like(N)
        prevNEG = np.empty_like(NEG)
        for k in range(3):
            old = comp.state.fw_text[k]
            if old is None:
                old = "%.*f" % (dec, comp.state.fw[k] / u)
            on = int(old.lstrip("-").replace(".", ""))
            prevN[0, k] = on
            prevNEG[0, k] = old.startswith("-") and on > 0
        prevN[1:] = N[:-1]
        prevNEG[1:] = NEG[:-1]
        changed = (N != prevN) | (NEG != prevNEG)
        is_move = np.zeros(ntot, bool)
        is_move[order_pos] = True
        W = np.zeros((ntot, 3), bool)
        W[order_pos] = g3
        W |= changed
        take_emit = W[tpos].any(axis=1) if len(tups) else np.zeros(0, bool)
        # render the generated parts: move rows " X.. Y.." and take-up rows "G1 X..\n"
        big = int(N.max()) if ntot else 0
        block = 2 + 1 + max(1, len(str(big // 10 ** dec))) + 1 + dec
        total_w = 2 + 3 * block + 2
        fullT = np.empty((total_w, ntot), np.uint8)  # transposed: see _Formatter.fill
        maskT = np.zeros((total_w, ntot), bool)
        row_len = np.zeros(ntot, np.int64)
        col = 2
        for k in range(3):
            row_len += fmtr.fill(fullT, maskT, col, block, ord("XYZ"[k]), N[:, k], NEG[:, k],
                                 W[:, k])
            col += block
        if len(tups):
            # take-up rows: "G1" first and the line ending of their move's line last
            crlf = rows.crlf[tups]
            fullT[0, tpos], fullT[1, tpos] = 71, 49
            fullT[total_w - 2, tpos] = np.where(crlf, 13, 10)
            fullT[total_w - 1, tpos] = 10
            te_rows = tpos[take_emit]
            maskT[0, te_rows] = True
            maskT[1, te_rows] = True
            maskT[total_w - 2, te_rows] = True
            maskT[total_w - 1, te_rows] = crlf[take_emit]
            row_len[te_rows] += 3 + crlf[take_emit]
            dropped = tpos[~take_emit]
            maskT[:, dropped] = False
            row_len[dropped] = 0
        gen = fullT.T[maskT.T]
        row_off = np.cumsum(row_len) - row_len
        # assemble from a pool: this segment's input, the synthetic bytes (arc chords), then
        # the generated rows. Per row: input up to its line (the first row of a line), its
        # take-up row, its "G0"/"G1", its generated X/Y/Z, a leading F word, the chord's
        # tail; the input then resumes after the row (the last piece runs to the end).
        gbase = len(seg) + len(synth)
        take_row = np.zeros(nm, np.int64)
        has_t = np.zeros(nm, bool)
        if len(tups):
            take_row[tups] = tpos
            has_t[tups] = True
        S = np.empty(6 * nm + 1, np.int64)
        L = np.empty(6 * nm + 1, np.int64)
        S[0:-1:6] = rows.pre_s
        L[0:-1:6] = rows.pre_l
        S[1::6] = gbase + row_off[take_row]
        L[1::6] = np.where(has_t, row_len[take_row], 0)
        S[2::6] = rows.code_s
        L[2::6] = 2
        S[3::6] = gbase + row_off[order_pos]
        L[3::6] = row_len[order_pos]
        S[4::6] = rows.fpre_s
        L[4::6] = rows.fpre_l
        S[5::6] = rows.post_s
        L[5::6] = rows.post_l
        S[-1] = rows.resume
        L[-1] = len(seg) - rows.resume
        total = int(L.sum())
        dst = np.cumsum(L) - L
        idx = np.repeat((S - dst).astype(np.int32), L)
        idx += np.arange(total, dtype=np.int32)
        parts = [seg]
        if synth:
            parts.append(np.frombuffer(synth, np.uint8))
        parts.append(gen)
        pool = np.concatenate(parts)
        out = np.take(pool, idx)  # a buffer; joined/written without another copy
        # state handover
        last = ntot - 1
        for k in range(3):
            text = fmtr.text(int(N[last, k]), bool(NEG[last, k]))
            comp.state.fw_text[k] = text
            comp.state.fw[k] = float(text) * u
        comp.state.m = [float(P[-1, 0]), float(P[-1, 1]), float(P[-1, 2])]
        comp.state.q_last = (float(Q[-1, 0]), float(Q[-1, 1]), float(Q[-1, 2]))
        comp.state.limit_recheck = [True, True, True]
        for k in range(3):
            bl.s.dir[k] = int(dirs_after[-1, k])
            if bl.active[k]:
                bl.s.anchor[k] = anchors[k]
        return out, int(take_emit.sum())

    def _finish_counts(self, tk, i0, i1, cand, n_moves, n_take, n_arcs=0, n_chords=0,
                       arc_e=None, arc_f=None) -> None:
        """Report counts, feed and E position after lines [i0, i1); ``arc_e``/``arc_f``:
        (line, value) of the last E/F word of the run's arcs."""
        comp = self.comp
        rep = comp.report
        nl = i1 - i0
        comp.state.lineno += nl
        rep.lines += nl
        rep.lines_out += nl + n_take + n_chords - n_arcs
        rep.moves += len(cand) + n_arcs
        rep.moves_compensated += n_moves
        rep.takeup_moves += n_take
        rep.arcs_linearised += n_arcs
        rep.arc_segments += n_chords
        u = MM_PER_INCH if comp.state.inches else 1.0
        fl = tk.last_value(5, i0, i1)
        if arc_f is not None and (fl is None or arc_f[0] > fl[0]):
            fl = arc_f
        if fl is not None:
            comp.state.feed = fl[1] * u
        el = tk.last_value(4, i0, i1)
        if arc_e is not None and (el is None or arc_e[0] > el[0]):
            el = arc_e
        if el is not None:
            comp.state.e_pos = None if comp.e_relative else el[1]

    def _finish_inert(self, tk, i0, i1, cand) -> bytes:
        self._finish_counts(tk, i0, i1, cand, 0, 0)
        return tk.buf[int(tk.ls[i0]): int(tk.le[i1 - 1]) + 1]

    def _limits(self, C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves, i0) -> bool:
        """Limits policy on all points, reported in emission order (take-up before its row,
        axes in order, as the line path meets them); False means 'policy error hit', and
        then nothing is counted (the line path raises at its line)."""
        comp = self.comp
        rep = comp.report
        lim = comp.options.limits
        events = []  # (emission position, axis, line index in block, value)
        outside = 0
        for k in range(3):
            lo, hi = lim[2 * k], lim[2 * k + 1]
            for arr_c, arr_p, rows, pos in ((Ct, Pt, tups, tpos), (C, P, None, order_pos)):
                if len(arr_c) == 0:
                    continue
                inside = (arr_p[:, k] >= lo) & (arr_p[:, k] <= hi)
                hit = inside & ((arr_c[:, k] < lo) | (arr_c[:, k] > hi))
                if hit.any():
                    if comp.options.policy == "error":
                        return False
                    idx = np.flatnonzero(hit)
                    line_rows = moves[rows[idx]] if rows is not None else moves[idx]
                    for p, li, v in zip(pos[idx].tolist(), line_rows.tolist(),
                                        arr_c[idx, k].tolist()):
                        events.append((p, k, li, v))
                    if comp.options.policy == "clamp":
                        arr_c[idx, k] = np.clip(arr_c[idx, k], lo, hi)
                if rows is None:
                    outside += int((~inside & (arr_p[:, k] != Pp[:, k])).sum())
        rep.source_outside += outside
        if events:
            events.sort()
            base_line = comp.state.lineno - i0
            for _p, k, li, v in events:
                rep.limit_hits += 1
                if len(rep.limit_examples) < 20:
                    rep.limit_examples.append((base_line + li + 1, "XYZ"[k], round(v, 6)))
        return True


class _Tokens:
    """Byte-level tokenisation of a block of complete lines (each ending with b'\\n')."""

    def __init__(self, buf: bytes):
        self.buf = buf
        a = np.frombuffer(buf, np.uint8)
        self.a = a
        cls = np.frombuffer(buf.translate(_CLS), np.uint8)
        sep = np.flatnonzero(cls >= _SP)
        sk = cls[sep]
        isnl = sk == _NL
        nl = sep[isnl]
        n = len(nl)
        self.n_lines = n
        ls = np.empty(n, np.int64)
        ls[0] = 0
        ls[1:] = nl[:-1] + 1
        self.ls, self.le = ls, nl
        self.crlf = (nl > 0) & (a[np.maximum(nl - 1, 0)] == 13)
        last = len(a) - 1
        # a CR that does not end a line is a line end of its own for the reference reader
        crs = sep[sk == _CR]
        self.lone_cr = bool(len(crs)) and bool(np.any(a[np.minimum(crs + 1, last)] != 10))
        c0 = a[ls]
        c1 = a[np.minimum(ls + 1, last)]
        c2 = a[np.minimum(ls + 2, last)]
        length = nl - ls
        cand = (length >= 3) & (c0 == 71) & ((c1 == 48) | (c1 == 49)) & (c2 == 32)
        # lines that may change the modal state go through the compensator one by one
        brk = _BREAK_FIRST[c0] & ~cand
        mline = (c0 == 77) & ~((c1 >= 48) & (c1 <= 57))
        m_state = (c0 == 77) & (((c1 == 56) & ((c2 == 50) | (c2 == 51)))
                                | ((c1 == 52) & (c2 == 56)))
        brk |= mline | m_state
        # tokens: after each space separator of a candidate line, up to the next separator
        lid = np.cumsum(isnl) - isnl
        in_cand = cand[lid]
        is_sp = (sk == _SP) & in_cand
        is_semi = (sk == _SEMI) & in_cand
        # first ';' of each candidate line ends its command part
        semi_pos = np.full(n, -1, np.int64)
        si = np.flatnonzero(is_semi)
        if len(si):
            first_lines, first_idx = np.unique(lid[si], return_index=True)
            semi_pos[first_lines] = sep[si[first_idx]]
        has_semi = semi_pos >= 0
        cmd_end = np.where(has_semi, semi_pos - 1, np.where(self.crlf, nl - 1, nl))
        bad = np.zeros(n, bool)
        # " ;" : one space before the comment, and a word (not a space) before that space
        hs = np.flatnonzero(has_semi & cand)
        if len(hs):
            p = semi_pos[hs]
            bad[hs] |= (a[p - 1] != 32) | (a[np.maximum(p - 2, 0)] == 32) | (p - 2 < ls[hs] + 1)
        # tabs or stray CR inside the command part
        odd = np.flatnonzero(((sk == _TAB) | (sk == _CR)) & in_cand)
        if len(odd):
            oline = lid[odd]
            inside = sep[odd] < cmd_end[oline]
            bad[oline[inside]] = True
        ti = np.flatnonzero(is_sp)
        tpos = sep[ti]
        tline = lid[ti]
        keep = tpos < cmd_end[tline]
        ti, tpos, tline = ti[keep], tpos[keep], tline[keep]
        ts = tpos + 1
        te = sep[ti + 1]
        tl = te - ts
        bad[tline[tl < 2]] = True
        # words: a letter of XYZEF and a number [-+]?(\d+\.?\d*|\.\d+)
        letter = _LETTER[a[np.minimum(ts, last)]]
        bounds = np.empty(2 * len(ts) + 1, np.int64)
        bounds[0:-1:2] = ts + 1
        bounds[1:-1:2] = np.maximum(te, ts + 1)
        bounds[-1] = len(a)
        if len(ts):
            # (a word that would start past the end - a trailing space before the block's
            # last newline - is empty, its line already bad: its sum does not matter, but
            # reduceat wants every index inside the array)
            sums = np.add.reduceat(cls, np.minimum(bounds[:-1], len(a) - 1),
                                   dtype=np.uint32)[0::2][: len(ts)]
        else:
            sums = np.zeros(0, np.uint32)
        digits = sums & 31
        dots = (sums >> 5) & 3
        others = sums >> 7
        first_num = a[np.minimum(ts + 1, last)]
        signed = (first_num == 45) | (first_num == 43)
        ok = (letter > 0) & (digits >= 1) & (digits <= 24) & (dots <= 1) & (
            (others == 0) | ((others == 1) & signed))
        bad[tline[~ok]] = True
        # one word per letter per line; X/Y/Z words together, before E/F words except an F
        # that may come first
        nt = len(ts)
        first_in_line = np.ones(nt, bool)
        first_in_line[1:] = tline[1:] != tline[:-1]
        heads = np.flatnonzero(first_in_line)
        if nt:
            bit = np.left_shift(1, letter.astype(np.int64))
            line_or = np.bitwise_or.reduceat(bit, heads)
            line_sum = np.add.reduceat(bit, heads)
            bad[tline[heads[line_or != line_sum]]] = True
        is_xyz = (letter >= 1) & (letter <= 3)
        prev_xyz = np.zeros(nt, bool)
        prev_xyz[1:] = is_xyz[:-1]
        lead_f = (letter == 5) & first_in_line
        after_lead_f = np.zeros(nt, bool)
        after_lead_f[1:] = lead_f[:-1]
        ok_xyz = first_in_line | prev_xyz | after_lead_f
        bad[tline[is_xyz & ~ok_xyz]] = True
        self.cand = cand & ~bad
        self.breaking = brk | (cand & bad)
        # lines that may be slicer-style arcs (fastfile._parse_arc decides)
        self.arc_start = (length >= 3) & (c0 == 71) & ((c1 == 50) | (c1 == 51)) & (c2 == 32)
        # the move lines (candidates with X/Y/Z words) of this block, in order
        xi = np.flatnonzero(is_xyz & ok & self.cand[tline])
        xl = tline[xi]
        newline = np.ones(len(xi), bool)
        newline[1:] = xl[1:] != xl[:-1]
        self.move_lines = xl[newline]
        move_of = np.cumsum(newline) - 1
        nm = len(self.move_lines)
        self.move_vals = np.full((nm, 3), np.nan)
        self.move_bad_number = np.zeros(nm, bool)
        self.xyz_end = np.zeros(nm, np.int64)
        if len(xi):
            s0 = ts[xi] + 1
            e0 = te[xi]
            too_long = (e0 - s0) > NUM_WIDTH
            self.move_bad_number[move_of[too_long]] = True
            vals = np.full(len(xi), np.nan)  # (a long one is not parsed: its line breaks)
            fit = ~too_long
            vals[fit] = _parse_numbers(a, s0[fit], e0[fit], dots[xi][fit])
            self.move_vals[move_of, letter[xi] - 1] = vals
            self.xyz_end[move_of] = e0  # X/Y/Z words are contiguous: the last one ends them
        # a leading F word of a move line (the output moves it after X/Y/Z)
        self.fpre_start = np.zeros(nm, np.int64)
        self.fpre_end = np.zeros(nm, np.int64)
        lf = np.flatnonzero(lead_f)
        if len(lf):
            k = np.searchsorted(self.move_lines, tline[lf])
            k = np.minimum(k, max(nm - 1, 0))
            hit = (nm > 0) & (self.move_lines[k] == tline[lf]) if nm else np.zeros(0, bool)
            self.fpre_start[k[hit]] = tpos[lf[hit]]
            self.fpre_end[k[hit]] = te[lf[hit]]
        # E and F words: the last one of a run sets the engine's e_pos / feed
        self._tline, self._letter, self._ts, self._te = tline, letter, ts, te

    def last_value(self, which: int, i0: int, i1: int) -> Optional[Tuple[int, float]]:
        """(line, value) of the last word ``which`` (4: E, 5: F) of the candidate lines in
        [i0, i1), or None."""
        j0 = int(np.searchsorted(self._tline, i0, side="left"))
        j1 = int(np.searchsorted(self._tline, i1, side="left"))
        hits = np.flatnonzero(self._letter[j0:j1] == which)
        if len(hits) == 0:
            return None
        j = j0 + int(hits[-1])
        return int(self._tline[j]), float(self.buf[int(self._ts[j]) + 1: int(self._te[j])])

    def e_words(self, i0: int, i1: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lines and byte spans (word start, end) of the E words of the candidate lines in
        [i0, i1), in order."""
        j0 = int(np.searchsorted(self._tline, i0, side="left"))
        j1 = int(np.searchsorted(self._tline, i1, side="left"))
        hits = j0 + np.flatnonzero(self._letter[j0:j1] == 4)
        return self._tline[hits], self._ts[hits], self._te[hits]


def _parse_numbers(a: np.ndarray, s0: np.ndarray, e0: np.ndarray,
                   dots: np.ndarray) -> np.ndarray:
    """Exact float values of validated number tokens a[s0:e0] (``dots`` = 0 or 1 each).

    Tokens are grouped by length so each group is a plain (n x len) byte matrix: the digits
    make an integer by one matrix-vector product (float32 while exact, below 10**7), the
    dot's place by another; int / 10**decimals is then exactly Python's float(text).
    """
    L = e0 - s0
    out = np.empty(len(L))
    order = np.argsort(L.astype(np.int8), kind="stable")
    counts = np.bincount(L)
    pos = 0
    for n in np.flatnonzero(counts).tolist():
        c = int(counts[n])
        rows = order[pos:pos + c]
        pos += c
        M = sliding_window_view(a, n)[s0[rows]]
        if n <= 7:
            full = (_DIGIT32[M] @ _P10F32[n - 1::-1]).astype(np.float64)
        else:
            full = _DIGIT[M] @ _P10F[n - 1::-1]
        dot_place = ((M == 46) @ _PLACE32[n - 1::-1]).astype(np.int64)
        fi = full.astype(np.int64)
        has_dot = dots[rows] > 0
        intall = np.where(has_dot, (fi // _P10I[dot_place + 1]) * _P10I[dot_place]
                          + fi % _P10I[dot_place], fi)
        v = intall / _P10F[np.where(has_dot, dot_place, 0)]
        out[rows] = np.where(M[:, 0] == 45, -v, v)
    return out
