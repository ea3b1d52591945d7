"""Byte-level tokenisation of a block of G-code lines with numpy, for the vectorised file
engine: where each line starts and ends, which lines are plain ``G0``/``G1`` moves with
single-spaced X/Y/Z/E/F words (the candidates), which may change the modal state (they take
the reference path), and the exact values of the move lines' X/Y/Z numbers (mm or inches as
written)."""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

NUM_WIDTH = 10  # longest number token parsed here (longer ones take the line-by-line path)

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


class Tokens:
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
