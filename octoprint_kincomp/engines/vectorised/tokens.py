"""Byte-level tokenisation of a block of G-code lines with numpy, for the vectorised file
engine: where each line starts and ends, which lines are plain ``G0``/``G1`` moves with
single-spaced X/Y/Z/E/F words (the candidates), which may change the modal state (they take
the reference path), and the exact values of the move lines' X/Y/Z numbers (mm or inches as
written). Every step works on all lines, or all words, of the block at once; the words'
numbers are checked and parsed in numbers.py.
"""

from __future__ import annotations

from typing import List, Optional, Tuple

import numpy as np

from .numbers import NUM_WIDTH, Numbers

_LETTER = np.zeros(256, np.int8)  # X=1 Y=2 Z=3 E=4 F=5
for _i, _c in enumerate(b"XYZEF"):
    _LETTER[_c] = _i + 1
_BREAK_FIRST = np.zeros(256, bool)  # first byte of a line that may change the state
for _c in b"GgTtNnm\t \x0b\x0c":
    _BREAK_FIRST[_c] = True
# Compensator.process strips any Unicode whitespace before the code (str.lstrip), so a line
# starting with \x1c..\x1f or a non-ASCII byte (U+0085, U+00A0, U+2003 ...) may be a move:
# it takes the line-by-line path (treated as inert, such a move was left uncompensated).
_BREAK_FIRST[0x1C:0x20] = True
_BREAK_FIRST[0x80:] = True


def _firsts(positions: np.ndarray, ends: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """For sorted byte ``positions`` (of some character) and the lines ending at ``ends``:
    per line, whether it holds one and the first one's index into ``positions``."""
    upto = np.searchsorted(positions, ends)
    before = np.empty_like(upto)
    before[0] = 0
    before[1:] = upto[:-1]
    return upto > before, before


class Tokens:
    """Byte-level tokenisation of a block of complete lines (each ending with b'\\n').

    Per line: ``ls``/``le`` (start, newline), ``crlf``, ``cand`` (a plain move line the
    vectorised path takes), ``breaking`` (a line for the reference path); per move line (a
    candidate with X/Y/Z words): ``move_lines`` (its line), ``move_vals`` (3, n: X/Y/Z as
    written, NaN where not given), ``move_bad_number`` (a number too long to parse here),
    ``xyz_end`` (where its X/Y/Z words end), ``fpre_start``/``fpre_end`` (a leading F word:
    " F1200"). ``lone_cr``: a CR that does not end a line; ``nul``: a NUL byte (the row
    assembly's filler) in the block."""

    def __init__(self, buf: bytes):
        self.buf = buf
        a = np.frombuffer(buf, np.uint8)
        self.a = a
        self.nul = b"\x00" in buf
        nl = np.flatnonzero(a == 10)
        self.n_lines = len(nl)
        self.ls = np.empty(len(nl), np.int64)
        self.ls[0] = 0
        self.ls[1:] = nl[:-1] + 1
        self.le = nl
        self.crlf = (nl > 0) & (a[np.maximum(nl - 1, 0)] == 13)
        # a CR that does not end a line is a line end of its own for the reference reader
        self.lone_cr = int(np.count_nonzero(a == 13)) != int(np.count_nonzero(self.crlf))
        cand, brk = self._classify()
        bad = np.zeros(len(nl), bool)
        cmd_end = self._command_ends(cand, bad)
        tpos, tline, te = self._words(cand, cmd_end)
        ts = tpos + 1
        letter = _LETTER[a[np.minimum(ts, len(a) - 1)]]
        numbers = Numbers(a, te, te - ts - 1)
        bad[tline[~(numbers.ok & (letter > 0))]] = True
        lead_f, is_xyz = self._check_order(tline, letter, bad)
        self.cand = cand & ~bad
        self.breaking = brk | (cand & bad)
        self._moves(np.flatnonzero(is_xyz & self.cand[tline]), tline, letter, te, numbers)
        self._leading_f(np.flatnonzero(lead_f), tpos, tline, te)
        # E and F words: the last one of a run sets the engine's e_pos / feed
        self._tline, self._letter, self._ts, self._te = tline, letter, ts, te

    def _classify(self) -> Tuple[np.ndarray, np.ndarray]:
        """(candidate, breaking) per line, from its first three bytes."""
        a, ls, last = self.a, self.ls, len(self.a) - 1
        c0 = a[ls]
        c1 = a[np.minimum(ls + 1, last)]
        c2 = a[np.minimum(ls + 2, last)]
        cand = (self.le - ls >= 3) & (c0 == 71) & ((c1 == 48) | (c1 == 49)) & (c2 == 32)
        # lines that may change the modal state go through the compensator one by one: an
        # M code not spelled with a digit first, M82/M83 (extruder mode), M48 (probing), and
        # any with a leading zero (M082 is M82 to the reference path's int())
        brk = _BREAK_FIRST[c0] & ~cand
        mline = (c0 == 77) & ~((c1 >= 49) & (c1 <= 57))
        m_state = (c0 == 77) & (
            ((c1 == 56) & ((c2 == 50) | (c2 == 51))) | ((c1 == 52) & (c2 == 56))
        )
        return cand, brk | mline | m_state

    def _command_ends(self, cand: np.ndarray, bad: np.ndarray) -> np.ndarray:
        """Where each line's command part ends: before " ;" (one space, a word before it)
        or at the line ending; a candidate with another comment spelling is ``bad``."""
        a, ls, nl = self.a, self.ls, self.le
        cmd_end = np.where(self.crlf, nl - 1, nl)
        semis = np.flatnonzero(a == 59)
        if len(semis):
            has_semi, first = _firsts(semis, nl)
            hs = np.flatnonzero(has_semi & cand)
            if len(hs):
                p = semis[first[hs]]
                cmd_end[hs] = p - 1
                bad[hs] |= (a[p - 1] != 32) | (a[p - 2] == 32) | (p - 2 < ls[hs] + 1)
        return cmd_end

    def _words(self, cand: np.ndarray, cmd_end: np.ndarray):
        """The words of the candidates' command parts: (the space before each, its line,
        its end: the next space or the end of the command part)."""
        a, nl = self.a, self.le
        sp = np.flatnonzero(a == 32)
        per_line = np.diff(np.searchsorted(sp, nl), prepend=0)
        sline = np.repeat(np.arange(len(nl)), per_line)
        keep = cand[sline]
        keep &= sp < cmd_end[sline]
        wi = np.flatnonzero(keep)
        tpos, tline = sp[wi], sline[wi]
        te = np.minimum(np.append(sp, len(a))[wi + 1], cmd_end[tline])
        return tpos, tline, te

    @staticmethod
    def _check_order(tline: np.ndarray, letter: np.ndarray, bad: np.ndarray):
        """One word per letter per line; X/Y/Z words together, before E/F words except an
        F that may come first (a line otherwise is ``bad``). Returns (leading F word, X/Y/Z
        word) per word."""
        nt = len(tline)
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
        bad[tline[is_xyz & ~(first_in_line | prev_xyz | after_lead_f)]] = True
        return lead_f, is_xyz

    def _moves(
        self,
        xi: np.ndarray,
        tline: np.ndarray,
        letter: np.ndarray,
        te: np.ndarray,
        numbers: Numbers,
    ) -> None:
        """The move lines, from their X/Y/Z words ``xi`` (in order)."""
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
            too_long = numbers.size[xi] > NUM_WIDTH
            self.move_bad_number[move_of[too_long]] = True
            vals = numbers.values(xi)
            vals[too_long] = np.nan  # (not parsed here: its segment takes the line path)
            self.move_vals[letter[xi] - 1, move_of] = vals
            # X/Y/Z words are contiguous: the last one of a line ends them
            last_of_line = np.ones(len(xi), bool)
            last_of_line[:-1] = newline[1:]
            self.xyz_end[move_of[last_of_line]] = te[xi[last_of_line]]

    def _leading_f(
        self, lf: np.ndarray, tpos: np.ndarray, tline: np.ndarray, te: np.ndarray
    ) -> None:
        """A leading F word of a move line (the output moves it after X/Y/Z)."""
        nm = len(self.move_lines)
        self.fpre_start = np.zeros(nm, np.int64)
        self.fpre_end = np.zeros(nm, np.int64)
        if len(lf) and nm:
            k = np.minimum(np.searchsorted(self.move_lines, tline[lf]), nm - 1)
            hit = self.move_lines[k] == tline[lf]
            self.fpre_start[k[hit]] = tpos[lf[hit]]
            self.fpre_end[k[hit]] = te[lf[hit]]

    def values(self, which: int, i0: int, i1: int) -> List[float]:
        """The values of the words ``which`` (4: E, 5: F) of the candidate lines in
        [i0, i1), in order."""
        j0 = int(np.searchsorted(self._tline, i0, side="left"))
        j1 = int(np.searchsorted(self._tline, i1, side="left"))
        hits = np.flatnonzero(self._letter[j0:j1] == which) + j0
        return [float(self.buf[int(self._ts[j]) + 1 : int(self._te[j])]) for j in hits.tolist()]

    def last_value(self, which: int, i0: int, i1: int) -> Optional[Tuple[int, float]]:
        """(line, value) of the last word ``which`` (4: E, 5: F) of the candidate lines in
        [i0, i1), or None."""
        j0 = int(np.searchsorted(self._tline, i0, side="left"))
        j1 = int(np.searchsorted(self._tline, i1, side="left"))
        hits = np.flatnonzero(self._letter[j0:j1] == which)
        if len(hits) == 0:
            return None
        j = j0 + int(hits[-1])
        return int(self._tline[j]), float(self.buf[int(self._ts[j]) + 1 : int(self._te[j])])
