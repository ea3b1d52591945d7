"""Fixed-point text of float arrays, as the reference path writes numbers (gcode.fmt:
``"%.{dec}f" % v`` without trailing zeros, bare dot or negative zero), for the vectorised file
engine.

A number is written into a row of a byte matrix by table look-ups: its axis word with sign
and integer part (" X-12", one 8-byte entry of a table per letter) and its decimals in
groups of three (".5", ".125", "001", each a 4-byte entry). What is not written is the byte
0, which the row assembly (assembly.py) drops, so no entry needs to know where the next
one starts.
"""

from __future__ import annotations

from typing import Dict, Tuple

import numpy as np

INT_LIMIT = 10000  # integer parts written by the tables: 0..9999 (in output units)
_BLANK_INT = 2 * INT_LIMIT  # the entry of an axis that is not written


def _texts_to_table(texts, width: int, dtype) -> np.ndarray:
    """Byte strings (at most ``width`` bytes each, padded with 0) as one integer each whose
    memory is the text (a copy of an entry copies the text, on any byte order)."""
    return np.frombuffer(b"".join(t.ljust(width, b"\0") for t in texts), dtype)


_INT_TABLES: Dict[int, np.ndarray] = {}
_FRAC_TABLES: Tuple[np.ndarray, np.ndarray] = ()  # type: ignore[assignment]


def _int_table(letter: int) -> np.ndarray:
    """ " <letter>[-]<integer part>" for 0..9999 (index + INT_LIMIT: negative); the last
    entry is blank."""
    table = _INT_TABLES.get(letter)
    if table is None:
        head = b" " + bytes([letter])
        texts = [head + b"%d" % i for i in range(INT_LIMIT)]
        texts += [head + b"-%d" % i for i in range(INT_LIMIT)]
        table = _INT_TABLES[letter] = _texts_to_table(texts + [b""], 8, np.uint64)
    return table


def _frac_tables() -> Tuple[np.ndarray, np.ndarray]:
    """Three decimals, for the first group (with the dot) and a later one: index v for the
    last group written (trailing zeros dropped, nothing for 0), v + 1000 for one that more
    digits follow (all three)."""
    global _FRAC_TABLES
    if not _FRAC_TABLES:
        full = [b"%03d" % v for v in range(1000)]
        last = [t.rstrip(b"0") for t in full]
        first = [b"." + t if t else b"" for t in last] + [b"." + t for t in full]
        _FRAC_TABLES = (
            _texts_to_table(first, 4, np.uint32),
            _texts_to_table(last + full, 4, np.uint32),
        )
    return _FRAC_TABLES


class Formatter:
    """Fixed-point text of floats, identical to ``gcode.fmt(v, dec)``."""

    def __init__(self, dec: int):
        self.dec = dec
        self.scale = 10.0**dec
        self.groups = (dec + 2) // 3  # groups of three decimals
        self.width = (8 + 4 * self.groups + 7) // 8 * 8  # bytes of one axis word in a row

    def ints(self, v: np.ndarray):
        """(magnitude in units of 10**-dec as int64, negative flag)."""
        r = np.abs(v) * self.scale
        n = np.floor(r + 0.5)
        frac = r - np.floor(r)
        risky = (np.abs(frac - 0.5) < 1e-6) | ~(r <= 1e12)  # (and NaN)
        if risky.any():  # exact decimal rounding of the binary value: let Python decide
            fmt = "%." + str(self.dec) + "f"
            for i in np.flatnonzero(risky).tolist():
                text = fmt % float(v[i])
                n[i] = float(int(text.lstrip("-").replace(".", "")))
        # (beyond the tables, or NaN: fits() then refuses them, and the cast stays defined)
        n = np.where(n <= 2.0**62, n, -1.0).astype(np.int64)
        return n, (v < 0) & (n > 0)

    def text(self, n: int, neg: bool) -> str:
        s = str(n).rjust(self.dec + 1, "0")
        if self.dec:
            s = (s[: -self.dec] + "." + s[-self.dec :]).rstrip("0").rstrip(".")
        return "-" + s if neg else s

    def fits(self, n: np.ndarray) -> bool:
        """Whether every magnitude has an integer part the tables write."""
        return n.size == 0 or (int(n.min()) >= 0 and int(n.max()) < INT_LIMIT * 10**self.dec)

    def put(
        self,
        rows: np.ndarray,
        col: int,
        letter: int,
        n: np.ndarray,
        neg: np.ndarray,
        written: np.ndarray,
        at=slice(None),
    ) -> None:
        """Write " <letter><number>" where ``written`` into rows ``at`` of ``rows`` (a byte
        matrix whose width is a multiple of 8), ``width`` bytes from byte ``col`` (a
        multiple of 8); 0 bytes elsewhere."""
        unit = 10**self.dec
        whole, frac = np.divmod(n, unit)
        idx = np.where(written, whole + INT_LIMIT * neg, _BLANK_INT)
        rows.view(np.uint64)[at, col // 8] = _int_table(letter)[idx]
        rows32 = rows.view(np.uint32)
        col = col // 4
        first, later = _frac_tables()
        digits = frac * (10 ** (3 * self.groups - self.dec))  # 3 decimals a group
        digits *= written
        if self.groups == 1:  # (millimetres to three decimals)
            rows32[at, col + 2] = first[digits]
            return
        for g in range(self.groups):
            below = 1000 ** (self.groups - 1 - g)
            value = (digits // below) % 1000
            more = (digits % below) != 0 if below > 1 else False
            rows32[at, col + 2 + g] = (first if g == 0 else later)[value + 1000 * more]
