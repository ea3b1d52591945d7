"""The vectorised computation of the file engine: a run of plain move lines (desired
machine points, mm) compensated, checked against the limits and rendered as bytes in whole
arrays, with exactly the reference path's arithmetic (core/path.py: the inverse model, the
backlash reversal rule of core/backlash.py, take-up moves before the reversing move, the
offset ``dir * fraction * b(q) / 2`` mm, the limits policy, ``gcode.fmt`` text)."""

from __future__ import annotations

from typing import NamedTuple, Optional, Tuple

import numpy as np

from ...core.backlash import hysteresis
from ...core.compensator import MM_PER_INCH
from .text import Formatter


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


class Rows(NamedTuple):
    """Output rows of a vectorised run (its move lines) and where their bytes come from:
    spans of the segment's input; ``resume`` is where the input continues after the last
    row."""

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


def emit_rows(comp, i0: int, rows: Rows, seg: np.ndarray) -> Optional[Tuple[np.ndarray, int]]:
    """Compensate and render ``rows`` (desired machine points, in order); the output
    bytes and the number of take-up moves, or None when the line path has to decide
    (a limit error under the policy 'error'). Nothing is changed in the compensator
    then. ``seg``: the input bytes the rows' spans point into; ``i0``: the block's line
    index of the segment's first line (limit reports)."""
    rep = comp.report
    opts = comp.options
    u = MM_PER_INCH if comp.state.inches else 1.0
    dec = opts.decimals + (2 if comp.state.inches else 0)
    fmtr = Formatter(dec)
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
        ok = check_limits(comp, C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves, i0)
        if not ok:
            return None
    # max correction per axis (um)
    for k in range(3):
        cm = float(np.max(np.abs(C[:, k] - P[:, k]))) * 1000.0
        if len(tups):
            cm = max(cm, float(np.max(np.abs(Ct[:, k] - Pt[:, k]))) * 1000.0)
        if cm > rep.max_correction_um[k]:
            rep.max_correction_um[k] = cm
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
        whole, _, frac = old.lstrip("-").partition(".")  # trimmed: "10.5" is 10500
        on = int(whole + frac.ljust(dec, "0"))
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
    # assemble from a pool: this segment's input, then the generated rows. Per row: input
    # up to its line, its take-up row, its "G0"/"G1", its generated X/Y/Z, a leading F
    # word; the input then resumes after the row (the last piece runs to the end).
    gbase = len(seg)
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
    pool = np.concatenate([seg, gen])
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


def check_limits(comp, C, P, Pp, Ct, Pt, tups, order_pos, tpos, moves, i0) -> bool:
    """Limits policy on all points, reported in emission order (take-up before its row,
    axes in order, as the line path meets them); False means 'policy error hit', and
    then nothing is counted (the line path raises at its line)."""
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
