"""The vectorised computation of the file engine: a run of plain move lines (desired
machine points, mm) compensated, checked against the limits and rendered as bytes in whole
arrays, with exactly the reference path's arithmetic (core/path.py: the inverse model, the
backlash reversal rule of core/backlash.py, take-up moves before the reversing move, the
offset ``dir * fraction * b(q) / 2`` mm, the limits policy, ``gcode.fmt`` text)."""

from __future__ import annotations

from typing import List, NamedTuple, Optional, Tuple

import numpy as np

from ...core.backlash import hysteresis
from ...core.compensator import MM_PER_INCH
from .assembly import assemble
from .text import Formatter


def _ffill(values: np.ndarray, given: np.ndarray, start) -> np.ndarray:
    """Forward-fill ``values`` where ``given`` is False, ``start`` before the first given
    (``values`` may be changed in place)."""
    n = len(values)
    gaps = np.flatnonzero(~given)
    if len(gaps) == 0:
        return values
    if len(gaps) <= n - n // 4:  # a quarter or more given (X and Y, say): each run of gaps
        # takes the value before it
        run = np.diff(gaps, prepend=-2) != 1
        before = (gaps[run] - 1)[np.cumsum(run) - 1]
        values[gaps] = np.where(before >= 0, values[np.maximum(before, 0)], start)
        return values
    # less than a quarter given (Z, say): each given value is repeated up to the next
    at = np.flatnonzero(given)
    out = np.empty(n, values.dtype)
    out[: at[0] if len(at) else n] = start
    if len(at):
        out[at[0] :] = np.repeat(values[at], np.diff(at, append=n))
    return out


def _interp(table, q: np.ndarray) -> np.ndarray:
    """BacklashAxis.um_at for an array, with the same arithmetic (see params.py)."""
    pts = table.points
    if len(pts) == 1:
        return np.full(len(q), pts[0][1])
    if len(pts) == 2:  # (the common table: the same operations in fewer passes)
        (p0, v0), (p1, v1) = pts
        val = (v1 - v0) / (p1 - p0) * (q - p0) + v0
        return np.where(q <= p0, v0, np.where(q >= p1, v1, val))
    out = np.full(len(q), pts[0][1])
    for (p0, v0), (p1, v1) in zip(pts, pts[1:]):
        val = (v1 - v0) / (p1 - p0) * (q - p0) + v0
        out = np.where((q > p0) & (q < p1), val, out)
        out = np.where(q == p1, v1, out)
    return np.where(q >= pts[-1][0], pts[-1][1], out)


class Rows(NamedTuple):
    """Output rows of a vectorised run (its move lines) and where their bytes come from:
    spans (start, length) of the segment's input; ``resume`` is where the input continues
    after the last row."""

    P: np.ndarray  # (3, n) desired machine points, mm
    given: np.ndarray  # (3, n) axes written whatever their text
    line: np.ndarray  # line index in the block (limit reports, endings)
    crlf: np.ndarray  # the line ends with CRLF (take-up rows copy it)
    pre_s: np.ndarray  # the input before the row: the rest of the last move line and any
    pre_l: np.ndarray  # lines in between
    code_s: np.ndarray  # 2 bytes: "G0"/"G1"
    fpre_s: np.ndarray  # a leading F word (" F1200"), written after X/Y/Z
    fpre_l: np.ndarray
    resume: int


def emit_rows(comp, i0: int, rows: Rows, seg: np.ndarray) -> Optional[Tuple[List[np.ndarray], int]]:
    """Compensate and render ``rows`` (desired machine points, in order); the output
    (pieces, buffers) and the number of take-up moves, or None when the line path has to
    decide (a limit error under the policy 'error', a coordinate the tables do not write).
    Nothing is changed in the compensator or its report then. ``seg``: the input bytes
    the rows' spans point into; ``i0``: the block's line index of the segment's first
    line (limit reports). Arrays are per axis: (3, n)."""
    rep = comp.report
    opts = comp.options
    st = comp.state
    u = MM_PER_INCH if st.inches else 1.0
    dec = opts.decimals + (2 if st.inches else 0)
    fmtr = Formatter(dec)
    P, g3, moves = rows.P, rows.given, rows.line
    nm = P.shape[1]
    m0 = st.m
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = comp.model.inverse_rows
    b0, b1, b2 = comp.model.offset_mm
    x, y, z = P[0] - b0, P[1] - b1, P[2] - b2
    Q = np.empty((3, nm))
    Q[0] = a00 * x + a01 * y + a02 * z
    Q[1] = a10 * x + a11 * y + a12 * z
    Q[2] = a20 * x + a21 * y + a22 * z
    q0 = st.q_last
    if q0 is None:
        q0 = comp.model.inverse(m0)
    Qp = np.empty_like(Q)
    Qp[:, 0] = q0
    Qp[:, 1:] = Q[:, :-1]
    Pp = np.empty_like(P)
    Pp[:, 0] = m0
    Pp[:, 1:] = P[:, :-1]
    bl = comp.backlash
    dirs_after = np.empty((3, nm), np.int64)
    rev_any = np.zeros(nm, bool)
    anchors = list(bl.s.anchor)
    for k in range(3):
        if not bl.active[k]:
            dirs_after[k] = bl.s.dir[k]
            continue
        qk, qp = Q[k], Qp[k]
        # the tracker's own comparisons (q against anchor -/+ deadband: rounding at the
        # deadband's edge must not differ from it)
        up = qk > qp + bl.deadband
        down = qk < qp - bl.deadband
        a = bl.s.anchor[k]
        if (a is not None and a != q0[k]) or np.any(~up & ~down & (qk != qp)):
            # the anchor is not the current command somewhere: the tracker's hysteresis,
            # point by point (arcs put chord ends next to reversals)
            dk, rk, anchors[k] = hysteresis(qk.tolist(), bl.s.dir[k], a, q0[k], bl.deadband)
            dirs_after[k] = dk
            rev_any |= np.asarray(rk, bool)
            continue
        # anchored at the start and no sub-deadband step: the anchor is always the current
        # command, so a reversal is a step beyond the deadband against dir
        moved = up | down
        after = _ffill(up.astype(np.int64) - down, moved, bl.s.dir[k])
        before = np.empty_like(after)
        before[0] = bl.s.dir[k]
        before[1:] = after[:-1]
        rev_any |= moved & (after != before)
        dirs_after[k] = after
        anchors[k] = float(qk[-1])
    half = comp.backlash.half
    C = Q.copy()
    tups = np.flatnonzero(rev_any)
    Ct = Qp[:, tups]
    Pt = Pp[:, tups]
    for k in range(3):
        if bl.active[k]:
            # rows with no direction get + 0.0: the same number (and the same text)
            d = dirs_after[k]
            C[k] += d * half * _interp(bl.tables[k], Q[k])
            Ct[k] += d[tups] * half * _interp(bl.tables[k], Ct[k])
    # where each point is emitted: take-ups right before their rows
    order_pos = np.arange(nm) + np.cumsum(rev_any)
    tpos = tups + np.arange(len(tups))
    limits = None
    if opts.limits is not None:
        limits = check_limits(comp, C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves)
        if limits is None:
            return None
    # text (as scaled integers) of every evaluated point, in emission order
    ntot = nm + len(tups)
    N = np.empty((3, ntot), np.int64)
    NEG = np.empty((3, ntot), bool)
    for k in range(3):
        if len(tups):
            G = np.empty(ntot)
            G[order_pos] = C[k]
            G[tpos] = Ct[k]
        else:
            G = C[k]
        N[k], NEG[k] = fmtr.ints((G + st.g[k]) / u)
    if not fmtr.fits(N):
        return None  # (a coordinate of 10,000 output units or more: the line path writes it)
    if limits is not None:
        count_limits(comp, *limits, i0)
    # max correction per axis (um)
    for k in range(3):
        cm = float(np.max(np.abs(C[k] - P[k]))) * 1000.0
        if len(tups):
            cm = max(cm, float(np.max(np.abs(Ct[k] - Pt[k]))) * 1000.0)
        if cm > rep.max_correction_um[k]:
            rep.max_correction_um[k] = cm
    # written: given axes of moves, or text changed since the previous point
    W = np.empty((3, ntot), bool)
    for k in range(3):
        old = st.fw_text[k]
        if old is None:
            old = "%.*f" % (dec, st.fw[k] / u)
        whole, _, frac = old.lstrip("-").partition(".")  # trimmed: "10.5" is 10500
        on = int(whole + frac.ljust(dec, "0"))
        nk, negk = N[k], NEG[k]
        W[k, 0] = nk[0] != on or negk[0] != (old.startswith("-") and on > 0)
        np.not_equal(nk[1:], nk[:-1], out=W[k, 1:])
        W[k, 1:] |= negk[1:] != negk[:-1]
        if len(tups):
            W[k, order_pos] |= g3[k]
        else:
            W[k] |= g3[k]
    take_emit = (W[0, tpos] | W[1, tpos] | W[2, tpos]) if len(tups) else np.zeros(0, bool)
    # (a move's input before it comes before its take-up)
    out = assemble(
        seg,
        rows,
        fmtr,
        N,
        NEG,
        W,
        order_pos,
        order_pos - rev_any,
        tpos[take_emit],
        rows.crlf[tups[take_emit]],
    )
    # state handover
    for k in range(3):
        text = fmtr.text(int(N[k, -1]), bool(NEG[k, -1]))
        st.fw_text[k] = text
        st.fw[k] = float(text) * u
    st.m = [float(P[0, -1]), float(P[1, -1]), float(P[2, -1])]
    st.q_last = (float(Q[0, -1]), float(Q[1, -1]), float(Q[2, -1]))
    st.limit_recheck = [True, True, True]
    for k in range(3):
        bl.s.dir[k] = int(dirs_after[k, -1])
        if bl.active[k]:
            bl.s.anchor[k] = anchors[k]
    return out, int(take_emit.sum())


def check_limits(comp, C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves):
    """The limits policy on all points (``C``, ``Ct``: clamped in place under "clamp"):
    (the hits in emission order - take-up before its row, axes in order, as the line path
    meets them - and the count of desired points outside), for count_limits, or None
    where the policy "error" is hit (the line path raises at its line). The report is not
    touched: the run may still go to the line path."""
    lim = comp.options.limits
    events = []  # (emission position, axis, line index in block, value)
    outside = 0
    for k in range(3):
        lo, hi = lim[2 * k], lim[2 * k + 1]
        for arr_c, arr_p, rows, pos in ((Ct, Pt, tups, tpos), (C, P, None, order_pos)):
            if arr_c.shape[1] == 0:
                continue
            inside = (arr_p[k] >= lo) & (arr_p[k] <= hi)
            hit = inside & ((arr_c[k] < lo) | (arr_c[k] > hi))
            if hit.any():
                if comp.options.policy == "error":
                    return None
                idx = np.flatnonzero(hit)
                line_rows = moves[rows[idx]] if rows is not None else moves[idx]
                for p, li, v in zip(pos[idx].tolist(), line_rows.tolist(), arr_c[k, idx].tolist()):
                    events.append((p, k, li, v))
                if comp.options.policy == "clamp":
                    arr_c[k, idx] = np.clip(arr_c[k, idx], lo, hi)
            if rows is None:
                outside += int((~inside & (arr_p[k] != Pp[k])).sum())
    events.sort()
    return events, outside


def count_limits(comp, events, outside: int, i0: int) -> None:
    """Report what check_limits found (``i0``: the block's line index of the segment's
    first line)."""
    rep = comp.report
    rep.source_outside += outside
    base_line = comp.state.lineno - i0
    for _p, k, li, v in events:
        rep.limit_hits += 1
        if len(rep.limit_examples) < 20:
            rep.limit_examples.append((base_line + li + 1, "XYZ"[k], round(v, 6)))
