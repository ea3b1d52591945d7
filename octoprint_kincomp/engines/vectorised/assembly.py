"""The bytes of a vectorised run (rows.py): one row of a byte matrix per output line, each
laid out in fixed places with the byte 0 where nothing is written, then the whole matrix
without its 0 bytes (one pass) is the text, in order.

A row holds, left to right: the input before its move (the rest of the last move line and
any lines in between, copied), the code ("G0"/"G1" copied, a take-up's "G1"), the X/Y/Z
words (text.py: table look-ups), and a leading F word (copied) or a take-up's line ending.
The input a row copies ends right before the code, so the row's copy and its code are one
span. Where the input before a move is longer than a row's share, it takes a row of its
own; longer than a whole row, it is put in between afterwards. A block holding a NUL byte
is not assembled here (tokens.py: ``nul``).
"""

from __future__ import annotations

from typing import List, Tuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .text import Formatter

MAX_SPAN = 126  # most input bytes before a row's code that are copied into the row
_COLS8 = np.arange(256, dtype=np.uint8)
SPLICE_COST = 10000  # a spliced span costs about as much as this many bytes of rows


def _layout(pre_l: np.ndarray, n_rows: int, rest: int) -> Tuple[int, int]:
    """(K, width): a row copies up to K input bytes before its code (K + 2 a multiple of 8),
    then has ``rest`` bytes for its words and tail; a longer span before a move gets a row
    of its own (up to ``width`` bytes), a longer one still is spliced in. K is the one of
    least cost: the bytes of all rows, and SPLICE_COST for each splice. A row is at most 255
    bytes (copies' lengths are compared as bytes): ``rest`` is at most 96 (3 words of 24
    bytes for 8 decimals in inches, a tail of 24), so a row at most 224."""
    counts = np.cumsum(np.bincount(np.minimum(pre_l, 511), minlength=512))
    best = None
    for k in range(6, MAX_SPAN + 1, 8):
        width = k + 2 + rest
        if width > 255:
            break
        own = counts[min(width, 511)] - counts[k]  # K < length <= width
        spliced = len(pre_l) - counts[min(width, 511)]
        cost = width * (n_rows + own) + SPLICE_COST * spliced
        if best is None or cost < best[0]:
            best = (cost, k, width)
    return best[1], best[2]


def assemble(
    seg: np.ndarray,
    rows,
    fmtr: Formatter,
    N: np.ndarray,
    NEG: np.ndarray,
    W: np.ndarray,
    order_pos: np.ndarray,
    pre_rows: np.ndarray,
    takeups: np.ndarray,
    take_crlf: np.ndarray,
) -> List[np.ndarray]:
    """The output of a run (rows.Rows: its moves' spans of ``seg``, the segment's input
    bytes): the emitted lines are the moves (at ``order_pos``) and their take-ups, of which
    those at ``takeups`` are written (``take_crlf``: their line ending is CRLF); the input
    before a move goes into row ``pre_rows`` (its take-up's, if it has one); ``N``, ``NEG``,
    ``W`` (3, lines): each line's X/Y/Z numbers (text.Formatter.ints) and whether each is
    written. Returns the pieces of the text in order (buffers): the rows without their 0
    bytes, a long span put in between, and the input after the last row."""
    ntot = N.shape[1]
    pre_l = rows.pre_l
    F = int(rows.fpre_l.max()) if len(pre_l) else 0
    tail_w = (max(F, 2) + 7) // 8 * 8
    K, width = _layout(pre_l, ntot, 3 * fmtr.width + tail_w)
    code, words = K, K + 2
    tail = words + 3 * fmtr.width
    short = pre_l <= K
    own = np.flatnonzero(~short & (pre_l <= width))
    spliced = np.flatnonzero(pre_l > width)
    # each emitted line's copy of the input: a move its input before it and its code, a
    # take-up the input before its move (its move then only its code)
    has_t = pre_rows != order_pos
    pre = np.where(short, pre_l, 0)
    span_s = np.where(has_t, rows.code_s, rows.code_s - pre)
    span_l = np.where(has_t, 2, pre + 2)
    if ntot != len(order_pos):
        s, n = np.zeros(ntot, np.int64), np.zeros(ntot, np.int64)
        s[order_pos], n[order_pos] = span_s, span_l
        s[pre_rows[has_t]], n[pre_rows[has_t]] = rows.pre_s[has_t], pre[has_t]
        span_s, span_l = s, n
    # the rows: the emitted lines, a row of its own before a move whose span is long
    at = slice(None)  # (where each emitted line's row is)
    if len(own):
        marks = np.zeros(ntot, np.int64)
        marks[pre_rows[own]] = 1
        at = np.arange(ntot) + np.cumsum(marks)
        own_rows = at[pre_rows[own]] - 1
        s, n = np.zeros(ntot + len(own), np.int64), np.zeros(ntot + len(own), np.int64)
        s[at], n[at] = span_s, span_l
        span_s, span_l = s, n
    R = np.empty((len(span_s), width), np.uint8)
    src = np.concatenate([seg, np.zeros(width, np.uint8)])
    copy = sliding_window_view(src, words)[span_s]
    copy *= _COLS8[:words] < span_l.astype(np.uint8)[:, None]
    R[:, :words] = copy
    R[:, words:] = 0
    if len(own):
        copy = sliding_window_view(src, width)[rows.pre_s[own]]
        copy *= _COLS8[:width] < pre_l[own].astype(np.uint8)[:, None]
        R[own_rows] = copy
    direct = len(own) == 0  # (each emitted line's row is its index)
    t_rows = takeups if direct else at[takeups]
    R[t_rows, code] = 71  # G1
    R[t_rows, code + 1] = 49
    for k in range(3):
        fmtr.put(R, words + k * fmtr.width, ord("XYZ"[k]), N[k], NEG[k], W[k], at)
    if F:
        lead = np.flatnonzero(rows.fpre_l)
        copy = sliding_window_view(src, F)[rows.fpre_s[lead]]
        copy *= np.arange(F) < rows.fpre_l[lead][:, None]  # (rare: not made faster)
        R[order_pos[lead] if direct else at[order_pos[lead]], tail : tail + F] = copy
    R[t_rows, tail] = np.where(take_crlf, 13, 10)
    R[t_rows[take_crlf], tail + 1] = 10
    # the text: the rows without their 0 bytes, a spliced span before its move's rows
    flat = R.ravel()
    written = flat != 0
    pieces = []
    prev = 0
    first = pre_rows[spliced] if direct else at[pre_rows[spliced]]
    for row, start, n in zip(first.tolist(), rows.pre_s[spliced].tolist(), pre_l[spliced].tolist()):
        cut, end = prev * width, row * width
        pieces.append(np.compress(written[cut:end], flat[cut:end]))
        pieces.append(seg[start : start + n])
        prev = row
    pieces.append(np.compress(written[prev * width :], flat[prev * width :]))
    pieces.append(seg[rows.resume :])
    return pieces
