"""Byte-level tokenisation of a block of G-code lines with numpy, for the vectorised file
engine: where each line starts and ends, which lines are plain ``G0``/``G1`` moves with
single-spaced X/Y/Z/E/F words (the candidates), which may change the modal state (they take
the reference path), and the exact values of the move lines' X/Y/Z numbers (mm or inches as
written).

Every word of a candidate line is looked at through a window of the ``WORD_WIDTH`` bytes
that end where the word ends (one row of a byte matrix per word): its number is checked and,
for X/Y/Z, parsed there with whole-matrix operations, so the cost is a few passes over the
block and over that matrix, whatever the words' lengths. A word whose number is longer than
the window sends its line to the reference path.
"""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

NUM_WIDTH = 10  # longest X/Y/Z number parsed here (longer ones take the line-by-line path)
WORD_WIDTH = 16  # longest number of any word checked here (its line takes the line path)

_LETTER = np.zeros(256, np.int8)  # X=1 Y=2 Z=3 E=4 F=5
for _i, _c in enumerate(b"XYZEF"):
    _LETTER[_c] = _i + 1
_P10F = 10.0 ** np.arange(24)
_BREAK_FIRST = np.zeros(256, bool)  # first byte of a line that may change the state
for _c in b"GgTtNnm\t \x0b\x0c":
    _BREAK_FIRST[_c] = True
# Compensator.process strips any Unicode whitespace before the code (str.lstrip), so a line
# starting with \x1c..\x1f or a non-ASCII byte (U+0085, U+00A0, U+2003 ...) may be a move:
# it takes the line-by-line path (treated as inert, such a move was left uncompensated).
_BREAK_FIRST[0x1C:0x20] = True
_BREAK_FIRST[0x80:] = True

# -- eight bytes at a time ---------------------------------------------------------------
# A word's number is read as the 16 bytes that end where it ends: two little-endian uint64
# (``lo``: the first 8 bytes, ``hi``: the last 8; byte k of a half is its k-th character),
# so a test of every byte is one integer operation per half (SWAR).
_U = np.uint64
_LE64 = np.dtype("<u8")  # (read as little-endian on any machine)
_ONES = _U(0x0101010101010101)
_HIGH = _U(0x8080808080808080)
_LOW7 = _U(0x7F7F7F7F7F7F7F7F)
_ZEROS = _U(0x3030303030303030)  # "00000000"
_ALL = _U(0xFFFFFFFFFFFFFFFF)


def _half_masks():
    """Per number length n (0..16) and sign (index n + 17 if its first character is a sign):
    the byte masks within each half of the number, of its sign, and of what is kept of it
    to be parsed (all but the sign)."""
    tables = [[0] * 34 for _ in range(6)]  # tok_lo, tok_hi, sign_lo, sign_hi, keep_lo, keep_hi
    for n in range(1, 17):
        start = 16 - n  # column of the first character
        tok = [0, 0]
        for col in range(start, 16):
            tok[col // 8] |= 0xFF << (8 * (col % 8))
        first = [0, 0]
        first[start // 8] = 0xFF << (8 * (start % 8))
        for signed in (0, 1):
            i = n + 17 * signed
            for half in (0, 1):
                tables[half][i] = tok[half]
                tables[2 + half][i] = first[half] if signed else 0
                tables[4 + half][i] = tok[half] & ~tables[2 + half][i]
    return tuple(np.array(t, np.uint64) for t in tables)


_TOK_LO, _TOK_HI, _SIGN_LO, _SIGN_HI, _KEEP_LO, _KEEP_HI = _half_masks()
_V16 = np.dtype("V16")


def _digits(x: np.ndarray) -> np.ndarray:
    """0x80 in each byte of ``x`` that is an ASCII digit, 0 elsewhere (no carry crosses a
    byte: each sum stays below 0x100, each difference above 0)."""
    at_least_0 = (x | _HIGH) - _ZEROS  # high bit: (byte & 0x7F) >= '0'
    above_9 = (x & _LOW7) + _U(0x4646464646464646)  # high bit: (byte & 0x7F) >= ':'
    return at_least_0 & ~above_9 & ~x & _HIGH


def _bytes_equal(x: np.ndarray, c: int) -> np.ndarray:
    """0x80 in each byte of ``x`` equal to ``c``, 0 elsewhere."""
    y = x ^ (_ONES * _U(c))
    nonzero = (((y & _LOW7) + _LOW7) | y) & _HIGH
    return nonzero ^ _HIGH


def _at_most_one(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether at most one byte flag is set in the two halves together."""
    return ((lo & (lo - _U(1))) == 0) & ((hi & (hi - _U(1))) == 0) & ((lo == 0) | (hi == 0))


def _eight_digits(v: np.ndarray) -> np.ndarray:
    """The value of eight ASCII digits (the first the most significant)."""
    v = v - _ZEROS
    v = ((v * _U(10)) + (v >> _U(8))) & _U(0x00FF00FF00FF00FF)
    v = ((v * _U(100)) + (v >> _U(16))) & _U(0x0000FFFF0000FFFF)
    return ((v * _U(10000)) + (v >> _U(32))) & _U(0x00000000FFFFFFFF)


def _flag_byte(flag: np.ndarray) -> np.ndarray:
    """The byte index (0..7) of the single flag (0x80 in one byte) of each element."""
    return (np.frexp(flag.astype(np.float64))[1] // 8 - 1).astype(np.int64)


def _firsts(positions: np.ndarray, ends: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """For sorted byte ``positions`` (of some character) and the lines ending at ``ends``:
    per line, whether it holds one and the first one's index into ``positions``."""
    upto = np.searchsorted(positions, ends)
    before = np.empty_like(upto)
    before[0] = 0
    before[1:] = upto[:-1]
    return upto > before, before


class Tokens:
    """Byte-level tokenisation of a block of complete lines (each ending with b'\\n')."""

    def __init__(self, buf: bytes):
        self.buf = buf
        a = np.frombuffer(buf, np.uint8)
        self.a = a
        self.nul = b"\x00" in buf  # (the row assembly pads with NUL: such a block goes by line)
        nl = np.flatnonzero(a == 10)
        n = len(nl)
        self.n_lines = n
        ls = np.empty(n, np.int64)
        ls[0] = 0
        ls[1:] = nl[:-1] + 1
        self.ls, self.le = ls, nl
        self.crlf = (nl > 0) & (a[np.maximum(nl - 1, 0)] == 13)
        # a CR that does not end a line is a line end of its own for the reference reader
        self.lone_cr = int(np.count_nonzero(a == 13)) != int(np.count_nonzero(self.crlf))
        last = len(a) - 1
        c0 = a[ls]
        c1 = a[np.minimum(ls + 1, last)]
        c2 = a[np.minimum(ls + 2, last)]
        cand = (nl - ls >= 3) & (c0 == 71) & ((c1 == 48) | (c1 == 49)) & (c2 == 32)
        # lines that may change the modal state go through the compensator one by one
        brk = _BREAK_FIRST[c0] & ~cand
        mline = (c0 == 77) & ~((c1 >= 48) & (c1 <= 57))
        m_state = (c0 == 77) & (((c1 == 56) & ((c2 == 50) | (c2 == 51)))
                                | ((c1 == 52) & (c2 == 56)))
        brk |= mline | m_state
        bad = np.zeros(n, bool)
        # the command part of a candidate ends before " ;" (one space, a word before it) or
        # at the line ending
        cmd_end = np.where(self.crlf, nl - 1, nl)
        semis = np.flatnonzero(a == 59)
        if len(semis):
            has_semi, first = _firsts(semis, nl)
            hs = np.flatnonzero(has_semi & cand)
            if len(hs):
                p = semis[first[hs]]
                cmd_end[hs] = p - 1
                bad[hs] |= (a[p - 1] != 32) | (a[p - 2] == 32) | (p - 2 < ls[hs] + 1)
        # words: after each space of a candidate's command part, up to the next space or
        # the end of the command part
        sp = np.flatnonzero(a == 32)
        upto = np.searchsorted(sp, nl)
        per_line = np.diff(upto, prepend=0)
        sline = np.repeat(np.arange(n), per_line)
        keep = cand[sline]
        keep &= sp < cmd_end[sline]
        wi = np.flatnonzero(keep)
        tpos, tline = sp[wi], sline[wi]
        nxt = np.append(sp, len(a))[wi + 1]
        ts = tpos + 1
        te = np.minimum(nxt, cmd_end[tline])
        num_len = te - ts - 1  # the number after the letter
        letter = _LETTER[a[np.minimum(ts, last)]]
        bad[tline[num_len < 1]] = True
        # each word's number, checked in the 16 bytes that end with it: digits, at most one
        # dot, a sign only first, at least one digit
        padded = np.concatenate([np.zeros(WORD_WIDTH, np.uint8), a])
        windows = np.ndarray((len(a) + 1,), _V16, padded, strides=(1,))  # (unaligned)
        both = windows[te].view(_LE64).reshape(-1, 2)  # (padded[te + 16] is a[te])
        lo, hi = both[:, 0].copy(), both[:, 1].copy()
        first_char = a[np.minimum(ts + 1, last)]
        sign = (first_char == 45) | (first_char == 43)
        kind = np.clip(num_len, 0, WORD_WIDTH) + 17 * sign  # (the tables' index)
        tok_lo, tok_hi = _TOK_LO[kind], _TOK_HI[kind]
        sign_lo, sign_hi = _SIGN_LO[kind], _SIGN_HI[kind]
        dig_lo, dig_hi = _digits(lo) & tok_lo, _digits(hi) & tok_hi
        dot_lo, dot_hi = _bytes_equal(lo, 46) & tok_lo, _bytes_equal(hi, 46) & tok_hi
        other = (tok_lo & ~(dig_lo | dot_lo | sign_lo)) | (tok_hi & ~(dig_hi | dot_hi | sign_hi))
        other &= _HIGH
        ok = (letter > 0) & (num_len >= 1) & (num_len <= WORD_WIDTH) & (other == 0) & \
            ((dig_lo | dig_hi) != 0) & _at_most_one(dot_lo, dot_hi)
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
        xi = np.flatnonzero(is_xyz & self.cand[tline])
        xl = tline[xi]
        newline = np.ones(len(xi), bool)
        newline[1:] = xl[1:] != xl[:-1]
        self.move_lines = xl[newline]
        move_of = np.cumsum(newline) - 1
        nm = len(self.move_lines)
        self.move_vals = np.full((3, nm), np.nan)  # per axis
        self.move_bad_number = np.zeros(nm, bool)
        self.xyz_end = np.zeros(nm, np.int64)
        if len(xi):
            too_long = num_len[xi] > NUM_WIDTH
            self.move_bad_number[move_of[too_long]] = True
            kx = kind[xi]
            vals = _parse_numbers(lo[xi], hi[xi], _KEEP_LO[kx], _KEEP_HI[kx], dot_lo[xi],
                                  dot_hi[xi], first_char[xi] == 45)
            vals[too_long] = np.nan  # (not parsed here: its segment takes the line path)
            self.move_vals[letter[xi] - 1, move_of] = vals
            # X/Y/Z words are contiguous: the last one of a line ends them
            last_of_line = np.ones(len(xi), bool)
            last_of_line[:-1] = newline[1:]
            self.xyz_end[move_of[last_of_line]] = te[xi[last_of_line]]
        # a leading F word of a move line (the output moves it after X/Y/Z)
        self.fpre_start = np.zeros(nm, np.int64)
        self.fpre_end = np.zeros(nm, np.int64)
        lf = np.flatnonzero(lead_f)
        if len(lf) and nm:
            k = np.minimum(np.searchsorted(self.move_lines, tline[lf]), nm - 1)
            hit = self.move_lines[k] == tline[lf]
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


def _parse_numbers(lo, hi, keep_lo, keep_hi, dot_lo, dot_hi, negative) -> np.ndarray:
    """Exact float values of checked numbers of at most NUM_WIDTH characters, each in the
    halves ``lo``/``hi`` of its 16 bytes: ``keep_*`` the byte masks of its digits and dot,
    ``dot_*`` its dot's flag (0x80), if any.

    Everything but the digits and the dot becomes "0"; the digits left of the dot move one
    place right, over it; the 16 digits then make one integer (two times eight digits), and
    that integer (below 10**10) over 10**decimals is one correctly rounded division: exactly
    Python's ``float(text)``.
    """
    lo = (lo & keep_lo) | (_ZEROS & ~keep_lo)
    hi = (hi & keep_hi) | (_ZEROS & ~keep_hi)
    in_hi = dot_hi != 0
    in_lo = dot_lo != 0
    # bytes up to the dot: ((the dot's lowest bit) << 8) - 1 in its half, all of lo if the
    # dot is in hi (a dot in the last byte of a half gives 0 - 1: the whole half)
    upto_hi = np.where(in_hi, ((dot_hi >> _U(7)) << _U(8)) - _U(1), _U(0))
    upto_lo = np.where(in_hi, _ALL, np.where(in_lo, ((dot_lo >> _U(7)) << _U(8)) - _U(1),
                                              _U(0)))
    hi = ((((hi << _U(8)) | (lo >> _U(56))) & upto_hi) | (hi & ~upto_hi))
    lo = ((lo << _U(8)) & upto_lo) | (lo & ~upto_lo) | _U(0x30)  # (byte 0 shifted in: "0")
    digits = (_eight_digits(lo) * _U(100000000) + _eight_digits(hi)).astype(np.float64)
    dot_col = np.where(in_hi, 8 + _flag_byte(dot_hi), np.where(in_lo, _flag_byte(dot_lo),
                                                                WORD_WIDTH - 1))
    v = digits / _P10F[WORD_WIDTH - 1 - dot_col]
    return np.where(negative, -v, v)
