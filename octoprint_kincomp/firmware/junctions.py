"""How fast each firmware lets the head pass from one move into the next, and how its
lookahead turns those limits into entry, cruise and exit speeds.

Units: mm, s, mm/s, mm/s^2; squared speeds in mm^2/s^2. ``U`` is the blocks' unit directions
(n, 3: X, Y, Z), ``L`` their lengths, ``acc`` each block's own acceleration (the firmware's
base acceleration capped so that no axis exceeds its own maximum), ``vn`` the nominal speeds.
A junction ``i`` joins block ``i`` to block ``i + 1``; the functions return the highest
squared speed the firmware allows there (before the nominal speeds and stops are applied by
the caller, :mod:`.planner`). Each is written from the firmware's own source (docs/marlin.md,
docs/klipper.md, docs/reprapfirmware.md: the rules and how each was checked):

* **Marlin 2.1.2, junction deviation** (:func:`marlin_jd`): ``v^2 = a_j JD s / (1 - s)`` with
  ``s = sin(t/2)`` of the angle ``t`` between the moves' extensions and ``a_j`` the block's
  acceleration capped by every axis' ``M201`` along the unit vector of the change of
  direction (``limit_value_by_axis_maximum``); a move under 1 mm turning by less than
  45 degrees is also held to ``v^2 <= a_j L / theta`` (``JD_HANDLE_SMALL_SEGMENTS``, the
  deflection angle ``theta`` from Marlin's polynomial ``acos``, which bottoms out at
  0.033 rad); a reversal stops (0.05 mm/s, taken as 0).
* **Marlin 2.1.2, classic jerk** (:func:`marlin_jerk`, ``M205 X Y Z``): the smaller nominal
  speed of the two blocks, scaled down until no axis' speed changes by more than its jerk
  (an axis keeping its direction: the difference; an axis reversing: the larger of the two
  magnitudes); raised to the block's own "safe speed" when both blocks' safe speeds exceed
  99 % of it.
* **Klipper** (:func:`klipper`): ``v^2 <= R jd a`` with ``R = s / (1 - s)``, ``jd = scv^2
  (sqrt 2 - 1) / max_accel`` and ``a`` **each move's own acceleration** (both moves: a
  Z-limited move corners slower), and the centripetal limit ``v^2 <= 0.5 L a tan(t/2)`` of
  both moves; straight on: no limit; a reversal stops.
* **RepRapFirmware 3.5** (:func:`rrf`): ``v = min_i M566_i / |u_i - u_prev,i|`` over the
  drives; under the default jerk policy (``M566 P0``) moves of different classes (one moves
  X or Y, the other not) are never joined: the head stops between them.

The lookahead: :func:`forward_backward` (Marlin, RepRapFirmware: the largest speeds that can
still brake to every later limit and to a stop at the end) and :func:`klipper_lookahead`
(Klipper's ``LookAheadQueue.flush`` with its ``minimum_cruise_ratio``: a move that both
accelerates and decelerates peaks as if accelerating at ``max_accel (1 - ratio)``).
"""

from __future__ import annotations

import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

MARLIN_REVERSAL_COS = 0.999999  # Marlin: above this junction cosine the moves reverse
MARLIN_SMALL_MM = 1.0  # JD_HANDLE_SMALL_SEGMENTS: moves shorter than this
MARLIN_SMALL_COS = -0.7071067812  # ... that turn by less than 45 degrees
# Marlin's fast acos(-t) (MinMax polynomial of asin; max error +-0.033 rad)
_ASIN_POLY = (0.032843707, -1.451838349, 29.66153956, -131.1123477, 262.8130562, -242.7199627)
_ASIN_TOP = 84.31466202
SQRT2_1 = math.sqrt(2.0) - 1.0


def _cosines(U: np.ndarray) -> np.ndarray:
    """Cosine of each junction angle as the firmware computes it: ``-u_prev . u`` (-1: the
    path goes straight on, +1: it reverses)."""
    return -np.einsum("ij,ij->i", U[:-1], U[1:])


def _axis_capped(value: np.ndarray, vec: np.ndarray, amax: Optional[np.ndarray]) -> np.ndarray:
    """``value`` (per row) capped so that no axis of ``vec`` (n, 3, rows need not be unit)
    exceeds its maximum ``amax`` (3,): ``min(value, amax_i / |vec_i|)``."""
    if amax is None:
        return value
    absv = np.abs(vec)
    with np.errstate(divide="ignore"):
        lim = np.where(absv > 1e-12, amax[None, :] / np.maximum(absv, 1e-300), np.inf)
    return np.minimum(value, lim.min(axis=1))


def marlin_theta(t: np.ndarray) -> np.ndarray:
    """Marlin's approximation of ``acos(t)`` (rad) for ``t >= 0`` (``pi/2 - asin`` by its
    polynomial): the deflection angle of a junction whose moves' directions have the dot
    product ``t``; about 0.033 rad for ``t = 1``."""
    acc = np.full_like(t, _ASIN_TOP)
    for c in reversed(_ASIN_POLY):
        acc = c + t * acc
    return math.pi / 2 - acc


def marlin_jd(
    U: np.ndarray,
    L: np.ndarray,
    acc: np.ndarray,
    jd_mm: float,
    amax: Optional[np.ndarray],
    small_segments: bool = True,
) -> np.ndarray:
    """Marlin's junction deviation limit (see the module docstring); ``amax``: the axes'
    ``M201`` (mm/s^2, (3,)) or None."""
    cos_t = _cosines(U)
    rev = cos_t > MARLIN_REVERSAL_COS
    cos_c = np.maximum(cos_t, -MARLIN_REVERSAL_COS)
    sin_d2 = np.sqrt(0.5 * (1.0 - cos_c))
    w = U[1:] - U[:-1]
    norm = np.linalg.norm(w, axis=1)
    w = w / np.where(norm > 0, norm, 1.0)[:, None]
    a_j = _axis_capped(acc[1:].copy(), w, amax)
    v2 = a_j * jd_mm * sin_d2 / (1.0 - sin_d2)
    if small_segments:
        small = (L[1:] < MARLIN_SMALL_MM) & (cos_c < MARLIN_SMALL_COS)
        theta = marlin_theta(np.clip(-cos_c, 0.0, 1.0))
        v2 = np.where(small, np.minimum(v2, L[1:] * a_j / theta), v2)
    v2[rev] = 0.0
    return v2


def _jerk_of(v_exit: np.ndarray, v_entry: np.ndarray) -> np.ndarray:
    """Marlin 2.1.2's speed change of one axis across a junction (mm/s): coasting in one
    direction the difference, reversing the larger of the two magnitudes."""
    coast_down = (v_entry > 0) | (v_exit < 0)
    coast_up = (v_entry < 0) | (v_exit > 0)
    return np.where(
        v_exit > v_entry,
        np.where(coast_down, v_exit - v_entry, np.maximum(v_exit, -v_entry)),
        np.where(coast_up, v_entry - v_exit, np.maximum(-v_exit, v_entry)),
    )


def marlin_safe_speed(U: np.ndarray, vn: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """Marlin's "safe speed" of each block (mm/s): its nominal speed lowered so that no axis
    starts or stops faster than its jerk."""
    cs = np.abs(U) * vn[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(cs > jerk[None, :], jerk[None, :] / cs, 1.0)
    return vn * f.min(axis=1)


def marlin_jerk(U: np.ndarray, vn: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """Marlin's classic jerk junction limit (see the module docstring); ``jerk``: the axes'
    ``M205 X Y Z`` (mm/s, (3,))."""
    vp, vc = vn[:-1], vn[1:]
    cs = U * vn[:, None]  # each axis' speed at the block's nominal speed
    vmax = np.minimum(vp, vc)
    with np.errstate(divide="ignore", invalid="ignore"):
        ssf = np.where(vc < vp, vc / np.where(vp > 0, vp, 1.0), 1.0)
    factor = np.ones_like(vmax)
    limited = np.zeros(len(vmax), dtype=bool)
    for k in range(3):
        v_exit = cs[:-1, k] * ssf
        v_entry = cs[1:, k]
        v_exit = np.where(limited, v_exit * factor, v_exit)
        v_entry = np.where(limited, v_entry * factor, v_entry)
        j = _jerk_of(v_exit, v_entry)
        over = j > jerk[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(over, factor * jerk[k] / np.where(over, j, 1.0), factor)
        limited |= over
    vmax = np.where(limited, vmax * factor, vmax)
    safe = marlin_safe_speed(U, vn, jerk)
    both_safe = (safe[:-1] > 0.99 * vmax) & (safe[1:] > 0.99 * vmax)
    vmax = np.where(both_safe, safe[1:], vmax)
    return vmax * vmax


def klipper(
    U: np.ndarray, L: np.ndarray, acc: np.ndarray, scv_mm_s: float, max_accel: float
) -> np.ndarray:
    """Klipper's junction limit (``Move.calc_junction``, see the module docstring)."""
    cos_t = _cosines(U)
    sin_d2 = np.sqrt(np.maximum(0.5 * (1.0 - cos_t), 0.0))
    cos_d2 = np.sqrt(np.maximum(0.5 * (1.0 + cos_t), 0.0))
    angled = (1.0 - sin_d2 > 0.0) & (cos_d2 > 0.0)
    one_minus = np.where(angled, 1.0 - sin_d2, 1.0)
    r_jd = sin_d2 / one_minus
    quarter_tan = 0.25 * sin_d2 / np.where(angled, cos_d2, 1.0)
    jd = scv_mm_s**2 * SQRT2_1 / max_accel
    a_prev, a_next = acc[:-1], acc[1:]
    v2 = np.minimum.reduce(
        [
            r_jd * jd * a_next,
            r_jd * jd * a_prev,
            2.0 * L[1:] * a_next * quarter_tan,
            2.0 * L[:-1] * a_prev * quarter_tan,
        ]
    )
    return np.where(angled, v2, np.inf)


def rrf(U: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """RepRapFirmware's junction limit (see the module docstring); ``jerk``: the drives'
    ``M566`` in mm/s ((3,))."""
    dU = np.abs(U[1:] - U[:-1])
    with np.errstate(divide="ignore"):
        lim = np.where(dU > 1e-12, jerk[None, :] / np.maximum(dU, 1e-300), np.inf)
    v = lim.min(axis=1)
    xy = np.any(np.abs(U[:, :2]) > 1e-12, axis=1)
    v = np.where(xy[:-1] == xy[1:], v, 0.0)
    return v * v


# ---------------------------------------------------------------------------------------
# lookahead


def forward_backward(J: np.ndarray, c: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Entry and exit squared speeds (mm^2/s^2) of every block from the junction limits ``J``
    (the highest squared speed at each block's start, 0 after a stop) and ``c = 2 a L`` (the
    squared speed a block can gain or lose): the largest speeds that can still brake to every
    later limit and to a stop after the last block (vectorised with prefix sums)."""
    P = np.concatenate([[0.0], np.cumsum(c)])
    # backward: e_i = min(J_i, e_{i+1} + c_i), exit of the last block 0
    g = np.minimum.accumulate(np.concatenate([J + P[:-1], [P[-1]]])[::-1])[::-1]
    e = g[:-1] - P[:-1]
    # forward: x_{i+1} = min(e_{i+1}, x_i + c_i), x_0 = 0 (J_0 = 0)
    ee = np.concatenate([e, [0.0]])
    h = np.minimum.accumulate(ee - P)
    x = np.maximum(h + P, 0.0)
    return x[:-1], x[1:]


def _klipper_starts(
    J: Sequence[float], dv2: Sequence[float], mdv2: Sequence[float]
) -> Tuple[List[float], List[float]]:
    """Klipper's ``max_start_v2`` and ``max_mcr_start_v2`` of each move (``calc_junction``:
    what the previous move can reach, the junction limit; 0 after a stop)."""
    n = len(J)
    ms, mms = [0.0] * n, [0.0] * n
    for i in range(1, n):
        if J[i] <= 0.0:
            continue
        ms[i] = min(J[i], ms[i - 1] + dv2[i - 1])
        mms[i] = min(ms[i], mms[i - 1] + mdv2[i - 1])
    return ms, mms


def _klipper_flush(
    group: range, ms, mms, dv2, mdv2, vmax2, out: List[Tuple[float, float, float]]
) -> None:
    """``LookAheadQueue.flush`` of one stop-to-stop run of moves (Klipper's lazy flushing
    plans the same as flushing the whole run at its stop): (start, cruise, end) squared
    speeds of each move into ``out``."""
    info = {}
    next_v2 = next_mcr_v2 = peak_v2 = 0.0
    pending = 0
    for i in reversed(group):
        reach = next_v2 + dv2[i]
        start = min(ms[i], reach)
        cruise = None
        pending += 1
        reach_mcr = next_mcr_v2 + mdv2[i]
        mcr_start = min(mms[i], reach_mcr)
        if mcr_start < reach_mcr:  # the move can accelerate
            if mcr_start + mdv2[i] > next_mcr_v2 or pending > 1:
                peak_v2 = (mcr_start + reach_mcr) * 0.5
            cruise = min((start + reach) * 0.5, vmax2[i], peak_v2)
            pending = 0
        info[i] = (start, cruise, next_v2)
        next_v2, next_mcr_v2 = start, mcr_start
    prev_cruise = 0.0
    for i in group:
        start, cruise, end = info[i]
        if cruise is None:  # cannot accelerate: the previous move's cruise carries on
            cruise = min(prev_cruise, start)
        out[i] = (min(start, cruise), cruise, min(end, cruise))
        prev_cruise = cruise


def klipper_lookahead(
    J: np.ndarray,
    acc: np.ndarray,
    L: np.ndarray,
    vn2: np.ndarray,
    mcr_accel: float,
    is_wait: np.ndarray,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start, cruise and end squared speeds of every block as Klipper's lookahead plans them
    (see the module docstring); ``mcr_accel = max_accel (1 - minimum_cruise_ratio)``."""
    n = len(L)
    dv2 = (2.0 * acc * L).tolist()
    mdv2 = np.minimum(2.0 * L * mcr_accel, 2.0 * acc * L).tolist()
    ms, mms = _klipper_starts(J.tolist(), dv2, mdv2)
    vmax2 = vn2.tolist()
    out: List[Tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * n
    begin = 0
    for i in range(1, n + 1):
        if i == n or J[i] <= 0.0:  # a stop before block i ends the run
            run = range(begin, i)
            moves = [k for k in run if not is_wait[k]]
            if moves:
                _klipper_flush(range(moves[0], moves[-1] + 1), ms, mms, dv2, mdv2, vmax2, out)
            begin = i
    arr = np.array(out, dtype=float).reshape(-1, 3)
    return arr[:, 0], arr[:, 1], arr[:, 2]
