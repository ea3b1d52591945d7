"""The numbers of G-code words, checked and parsed eight bytes at a time, for the vectorised
file engine's tokeniser.

A word's number is read as the 16 bytes that end where the word ends: two little-endian
uint64 (``lo``: the first eight bytes, ``hi``: the last eight; byte k of a half is its k-th
character), so that a test of every byte is one integer operation per half (SWAR) on arrays
of all the words of a block at once. A number is what the reference path reads as one
(``[-+]?(digits[.[digits]]|.digits)``, at most WORD_WIDTH characters); an X/Y/Z value is
parsed exactly as Python's ``float(text)``.
"""

from __future__ import annotations

import numpy as np

NUM_WIDTH = 10  # longest X/Y/Z number parsed here (longer ones take the line-by-line path)
WORD_WIDTH = 16  # longest number of any word checked here (its line takes the line path)

_U = np.uint64
_LE64 = np.dtype("<u8")  # (read as little-endian on any machine)
_V16 = np.dtype("V16")
_ONES = _U(0x0101010101010101)
_HIGH = _U(0x8080808080808080)
_LOW7 = _U(0x7F7F7F7F7F7F7F7F)
_ZEROS = _U(0x3030303030303030)  # "00000000"
_ALL = _U(0xFFFFFFFFFFFFFFFF)
_P10F = 10.0 ** np.arange(WORD_WIDTH)


def _masks():
    """Per number length n (0..16), index n + 17 if its first character is a sign: the byte
    masks, within each half, of the number, of its sign, and of what is parsed (all but
    the sign)."""
    tables = [[0] * 34 for _ in range(6)]  # number lo/hi, sign lo/hi, parsed lo/hi
    for n in range(1, WORD_WIDTH + 1):
        start = WORD_WIDTH - n  # the column of its first character
        number, first = [0, 0], [0, 0]
        for col in range(start, WORD_WIDTH):
            number[col // 8] |= 0xFF << (8 * (col % 8))
        first[start // 8] = 0xFF << (8 * (start % 8))
        for signed in (0, 1):
            i = n + 17 * signed
            for half in (0, 1):
                tables[half][i] = number[half]
                tables[2 + half][i] = first[half] if signed else 0
                tables[4 + half][i] = number[half] & ~tables[2 + half][i]
    return tuple(np.array(t, np.uint64) for t in tables)


_NUMBER_LO, _NUMBER_HI, _SIGN_LO, _SIGN_HI, _PARSED_LO, _PARSED_HI = _masks()


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
    """Whether at most one byte flag is set in the two halves together (clearing the lowest
    set bit of a half leaves 0 when it had at most one)."""
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


class Numbers:
    """The numbers of the words ending at ``end`` (exclusive, byte positions in ``a``) whose
    number is ``size`` bytes long (after the letter; below 1 or above WORD_WIDTH: not a
    number). ``ok``: each is a number."""

    def __init__(self, a: np.ndarray, end: np.ndarray, size: np.ndarray):
        self.size = size
        padded = np.concatenate([np.zeros(WORD_WIDTH, np.uint8), a])
        windows = np.ndarray((len(a) + 1,), _V16, padded, strides=(1,))  # (unaligned)
        both = windows[end].view(_LE64).reshape(-1, 2)  # (padded[end + 16] is a[end])
        self.lo, self.hi = both[:, 0].copy(), both[:, 1].copy()
        self.first = a[np.clip(end - size, 0, len(a) - 1)]  # (its first character)
        sign = (self.first == 45) | (self.first == 43)
        self.kind = np.clip(size, 0, WORD_WIDTH) + 17 * sign  # (the masks' index)
        number_lo, number_hi = _NUMBER_LO[self.kind], _NUMBER_HI[self.kind]
        sign_lo, sign_hi = _SIGN_LO[self.kind], _SIGN_HI[self.kind]
        digit_lo, digit_hi = _digits(self.lo) & number_lo, _digits(self.hi) & number_hi
        self.dot_lo = _bytes_equal(self.lo, 46) & number_lo
        self.dot_hi = _bytes_equal(self.hi, 46) & number_hi
        other = (number_lo & ~(digit_lo | self.dot_lo | sign_lo)) | (
            number_hi & ~(digit_hi | self.dot_hi | sign_hi)
        )
        self.ok = (
            (size >= 1)
            & (size <= WORD_WIDTH)
            & ((other & _HIGH) == 0)
            & ((digit_lo | digit_hi) != 0)
            & _at_most_one(self.dot_lo, self.dot_hi)
        )

    def values(self, which: np.ndarray) -> np.ndarray:
        """Exact float values of the numbers ``which`` (checked, at most NUM_WIDTH
        characters): everything but the digits and the dot becomes "0"; the digits left of
        the dot move one place right, over it; the 16 digits then make one integer (two
        times eight), and that integer (below 10**10) over 10**decimals is one correctly
        rounded division: exactly Python's ``float(text)``."""
        kind = self.kind[which]
        keep_lo, keep_hi = _PARSED_LO[kind], _PARSED_HI[kind]
        lo = (self.lo[which] & keep_lo) | (_ZEROS & ~keep_lo)
        hi = (self.hi[which] & keep_hi) | (_ZEROS & ~keep_hi)
        dot_lo, dot_hi = self.dot_lo[which], self.dot_hi[which]
        in_hi, in_lo = dot_hi != 0, dot_lo != 0
        # bytes up to the dot: ((the dot's lowest bit) << 8) - 1 in its half, all of lo if
        # the dot is in hi (a dot in the last byte of a half gives 0 - 1: the whole half)
        upto_hi = np.where(in_hi, ((dot_hi >> _U(7)) << _U(8)) - _U(1), _U(0))
        upto_lo = np.where(
            in_hi, _ALL, np.where(in_lo, ((dot_lo >> _U(7)) << _U(8)) - _U(1), _U(0))
        )
        hi = (((hi << _U(8)) | (lo >> _U(56))) & upto_hi) | (hi & ~upto_hi)
        lo = ((lo << _U(8)) & upto_lo) | (lo & ~upto_lo) | _U(0x30)  # (byte 0 shifted in)
        digits = (_eight_digits(lo) * _U(100000000) + _eight_digits(hi)).astype(np.float64)
        dot_col = np.where(
            in_hi, 8 + _flag_byte(dot_hi), np.where(in_lo, _flag_byte(dot_lo), WORD_WIDTH - 1)
        )
        v = digits / _P10F[WORD_WIDTH - 1 - dot_col]
        return np.where(self.first[which] == 45, -v, v)
