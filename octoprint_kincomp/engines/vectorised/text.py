"""Fixed-point text of float arrays, as the reference path writes numbers (gcode.fmt:
``"%.{dec}f" % v`` without trailing zeros, bare dot or negative zero), for the vectorised file
engine."""

from __future__ import annotations

import numpy as np

_LUT4 = np.frombuffer(b"".join(b"%03d\0" % i for i in range(1000)), np.uint32)
_P10I = 10 ** np.arange(19, dtype=np.int64)


class Formatter:
    """Fixed-point text of floats, identical to ``gcode.fmt(v, dec)``."""

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
        if self.dec:
            s = (s[: -self.dec] + "." + s[-self.dec:]).rstrip("0").rstrip(".")
        return "-" + s if neg else s

    def trailing_zeros(self, n: np.ndarray) -> np.ndarray:
        """How many of the ``dec`` decimals of each number are trailing zeros (not written)."""
        tz = np.zeros(len(n), np.int64)
        for e in range(1, self.dec + 1):
            tz += n % _P10I[e] == 0
        return tz

    def fill(self, fullT: np.ndarray, maskT: np.ndarray, col: int, width: int, letter: int,
             n: np.ndarray, neg: np.ndarray, written: np.ndarray) -> np.ndarray:
        """Write " <letter><number>" into rows col..col+width of the transposed row matrix
        ``fullT`` (one matrix row per output column, so every write is one long 1-D run).

        Layout of the block: space, letter, sign slot, integer digits (right-aligned), dot,
        decimals; ``maskT`` selects what is really written (not the trailing zeros of the
        decimals, nor the dot when all are). Returns each row's length (0 if not written).
        Digits come three at a time from a table of "000".."999".
        """
        dec = self.dec
        tz = self.trailing_zeros(n)
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
                    maskT[pos] = written & (tz <= place)
                else:
                    maskT[pos] = written & (pos - col >= start)
                place += 1
        fullT[right - dec] = 46
        maskT[right - dec] = written & (tz < dec)
        sign_col = col + 2 + n_int - nint  # just before the first integer digit
        ng = np.flatnonzero(neg & written)
        if len(ng):
            fullT[sign_col[ng], ng] = 45
            maskT[sign_col[ng], ng] = True
        return np.where(written, 2 + neg + nint + np.where(tz < dec, 1 + dec - tz, 0), 0)

