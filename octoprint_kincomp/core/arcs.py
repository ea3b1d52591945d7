"""G2/G3 arc geometry: centre from IJK or R, sweep, and linearisation into chords.

Planes follow RS274/NIST and Marlin: G17 = XY (offsets I, J), G18 = ZX (first axis Z, second X;
offsets K, I), G19 = YZ (offsets J, K). Angles run from the plane's first axis towards its
second; G3 (counter-clockwise) increases the angle, G2 decreases it. All lengths in mm.
"""

from __future__ import annotations

import bisect
import math
from typing import List, Optional, Sequence, Tuple

Vec = Tuple[float, float, float]

# plane code -> (first axis, second axis, linear axis, offset letter first, offset letter second)
PLANES = {
    17: (0, 1, 2, "I", "J"),
    18: (2, 0, 1, "K", "I"),
    19: (1, 2, 0, "J", "K"),
}

TWO_PI = 2.0 * math.pi
FULL_CIRCLE_EPS_MM = 1e-6
MAX_SEGMENTS = 200000


class ArcError(ValueError):
    """The arc words do not describe an arc (radius too small, zero radius, ...)."""


def norm2(a: float, b: float) -> float:
    """sqrt(a*a + b*b): the length every engine computes the same way (math.hypot is
    more accurate but its algorithm differs between Python versions and C libraries)."""
    return math.sqrt(a * a + b * b)


def arc_centre_from_radius(
    a0: float, b0: float, a1: float, b1: float, r: float, clockwise: bool
) -> Tuple[float, float]:
    """Centre (a, b) of the arc from (a0, b0) to (a1, b1) with signed radius ``r``.

    A negative ``r`` selects the arc longer than 180 degrees (RS274 convention). A radius
    below half the chord is taken as half the chord, as Marlin does (its ``G2``/``G3``: the
    distance of the centre from the chord's midpoint is 0 where ``r^2 < (chord/2)^2``): the
    arc is the half circle over the chord, turning as G2/G3 says (issue 28; such an R was
    refused before and the line passed uncompensated).
    """
    da, db = a1 - a0, b1 - b0
    chord = norm2(da, db)
    if chord < FULL_CIRCLE_EPS_MM:
        raise ArcError("R-form arc with identical start and end (full circles need I/J/K)")
    if r == 0.0:
        raise ArcError("R-form arc with zero radius")
    half = chord / 2.0
    rr = abs(r)
    if rr < half:
        rr = half
    h = math.sqrt(max(rr * rr - half * half, 0.0))
    # Unit normal to the chord, to the left of the travel direction.
    na, nb = -db / chord, da / chord
    # CCW with the short arc has its centre on the left; flip for CW and for the long arc.
    sign = 1.0 if not clockwise else -1.0
    if r < 0:
        sign = -sign
    ma, mb = (a0 + a1) / 2.0, (b0 + b1) / 2.0
    return ma + sign * h * na, mb + sign * h * nb


def arc_sweep(
    a0: float,
    b0: float,
    a1: float,
    b1: float,
    ca: float,
    cb: float,
    clockwise: bool,
    turns: int = 0,
) -> Tuple[float, float, float, float]:
    """(start angle, signed sweep, start radius, end radius) of an arc about (ca, cb).

    An arc whose end equals its start is a full circle. ``turns`` adds complete circles
    (Marlin's ``P`` word).
    """
    r0 = norm2(a0 - ca, b0 - cb)
    r1 = norm2(a1 - ca, b1 - cb)
    if r0 < 1e-9 or r1 < 1e-9:
        raise ArcError("arc centre coincides with its start or end point")
    t0 = math.atan2(b0 - cb, a0 - ca)
    t1 = math.atan2(b1 - cb, a1 - ca)
    if norm2(a1 - a0, b1 - b0) < FULL_CIRCLE_EPS_MM:
        sweep = TWO_PI
    elif clockwise:
        sweep = (t0 - t1) % TWO_PI
    else:
        sweep = (t1 - t0) % TWO_PI
    if sweep <= 0.0:
        sweep = TWO_PI
    sweep += TWO_PI * max(0, turns)
    return t0, (-sweep if clockwise else sweep), r0, r1


def segment_angle(radius: float, chord_tol: float) -> float:
    """Largest angular step whose chord deviates from the arc by at most ``chord_tol``."""
    if radius <= chord_tol:
        return math.pi / 2
    step = min(math.pi / 2, 2.0 * math.acos(1.0 - chord_tol / radius))
    if not step > 0.0:
        # 1 - tol/r rounds to 1 beyond ~1e14 * tol (an I/J/R of hundreds of digits): no
        # machine arc, and a zero step would divide by zero in linearise
        raise ArcError(f"arc radius {radius:g} mm is too large")
    return step


def linearise(
    start: Sequence[float],
    end: Sequence[float],
    plane: int,
    ca: float,
    cb: float,
    clockwise: bool,
    chord_tol: float,
    turns: int = 0,
    breaks: Sequence[float] = (0.0, math.pi / 2),
) -> List[Vec]:
    """Chord end points (excluding ``start``, ending exactly at ``end``) of an arc.

    The chords keep within ``chord_tol`` of the arc, the radius is blended linearly from the
    start radius to the end radius (so slightly inconsistent slicer arcs still land on their
    end point), the linear axis moves proportionally (helix), and points are placed exactly at
    every angle ``breaks[i] + n*pi`` inside the sweep. The default breaks are the quadrants, so
    each chord moves every axis monotonically and a backlash reversal falls on a chord end;
    the compensator passes the angles where its skewed commands reverse instead.
    """
    ia, ib, il, _, _ = PLANES[plane]
    a0, b0, l0 = start[ia], start[ib], start[il]
    a1, b1, l1 = end[ia], end[ib], end[il]
    t0, sweep, r0, r1 = arc_sweep(a0, b0, a1, b1, ca, cb, clockwise, turns)
    step = segment_angle(max(r0, r1), chord_tol)
    # 0.8: dropping a chord end next to a forced point lengthens a chord by up to 25 %
    n = min(MAX_SEGMENTS, max(1, int(math.ceil(abs(sweep) / (0.8 * step) - 1e-9))))
    lo, hi = (t0, t0 + sweep) if sweep > 0 else (t0 + sweep, t0)
    if len(breaks) * abs(sweep) / math.pi > MAX_SEGMENTS:
        # a huge P (turn count): the forced points alone would be millions of chords
        raise ArcError(f"arc of {abs(sweep) / TWO_PI:.0f} turns needs too many chords")
    forced = []
    for phi in breaks:
        k = math.ceil((lo - phi) / math.pi)
        while phi + k * math.pi < hi:
            forced.append((phi + k * math.pi - t0) / sweep)
            k += 1
    # Uniform chords, minus those that would end right next to a forced point (no slivers).
    # The nearest forced points are found by bisection: checking every forced point for
    # every chord was quadratic (minutes for an arc with P1000).
    if n > 1 and forced:
        forced_sorted = sorted(forced)
        gap = 0.25 / n

        def clear(x: float) -> bool:
            j = bisect.bisect_left(forced_sorted, x)
            return all(
                abs(x - forced_sorted[i]) > gap for i in (j - 1, j) if 0 <= i < len(forced_sorted)
            )

        fracs = {i / n for i in range(1, n) if clear(i / n)}
        fracs.update(forced)
    elif n > 1:
        fracs = {i / n for i in range(1, n)}
    else:
        fracs = set(forced)
    pts: List[Vec] = []
    dr, dl = r1 - r0, l1 - l0
    cos, sin = math.cos, math.sin
    for f in sorted(x for x in fracs if 1e-12 < x < 1 - 1e-12):
        t = t0 + sweep * f
        r = r0 + dr * f
        if plane == 17:
            pts.append((ca + r * cos(t), cb + r * sin(t), l0 + dl * f))
            continue
        p = [0.0, 0.0, 0.0]
        p[ia] = ca + r * cos(t)
        p[ib] = cb + r * sin(t)
        p[il] = l0 + dl * f
        pts.append((p[0], p[1], p[2]))
    pts.append((float(end[0]), float(end[1]), float(end[2])))
    return pts


def centre_from_words(
    start: Sequence[float],
    end: Sequence[float],
    plane: int,
    offsets: Tuple[Optional[float], Optional[float]],
    radius: Optional[float],
    clockwise: bool,
    absolute_ij: bool = False,
) -> Tuple[float, float]:
    """Arc centre (first, second plane axis) from the offset words or the R word (mm)."""
    ia, ib, _, _, _ = PLANES[plane]
    oa, ob = offsets
    if oa is not None or ob is not None:
        oa = oa or 0.0
        ob = ob or 0.0
        if absolute_ij:
            return oa, ob
        return start[ia] + oa, start[ib] + ob
    if radius is None:
        raise ArcError("arc without centre offsets or R")
    return arc_centre_from_radius(start[ia], start[ib], end[ia], end[ib], radius, clockwise)


# Arcs kept as arcs (core/arcpath.py) are cut into pieces of at most this sweep (rad) before
# they are fitted, and at the break angles (where a carriage command reverses)
MAX_PIECE_RAD = math.pi
BREAK_EDGE = 1e-9  # break fractions closer than this to an end are not cut (no slivers)


class Arc:
    """One G2/G3 in the desired frame (mm): ``point(f)`` is the point a fraction ``f``
    (0..1) of the way along it, by angle: the radius blends linearly from the start radius to
    the end radius (so slightly inconsistent slicer arcs still end on their end point) and
    the linear axis moves in proportion (helix). Every engine evaluates it with the same
    operations in the same order."""

    __slots__ = (
        "plane",
        "ia",
        "ib",
        "il",
        "ca",
        "cb",
        "t0",
        "sweep",
        "r0",
        "r1",
        "dr",
        "l0",
        "dl",
        "start",
        "end",
    )

    def __init__(
        self,
        start: Sequence[float],
        end: Sequence[float],
        plane: int,
        ca: float,
        cb: float,
        clockwise: bool,
        turns: int = 0,
    ):
        ia, ib, il, _, _ = PLANES[plane]
        self.plane, self.ia, self.ib, self.il = plane, ia, ib, il
        self.ca, self.cb = ca, cb
        self.t0, self.sweep, self.r0, self.r1 = arc_sweep(
            start[ia], start[ib], end[ia], end[ib], ca, cb, clockwise, turns
        )
        self.dr = self.r1 - self.r0
        self.l0 = start[il]
        self.dl = end[il] - start[il]
        self.start = (float(start[0]), float(start[1]), float(start[2]))
        self.end = (float(end[0]), float(end[1]), float(end[2]))

    def point(self, f: float) -> Vec:
        if f == 0.0:
            return self.start
        if f == 1.0:
            return self.end
        t = self.t0 + self.sweep * f
        r = self.r0 + self.dr * f
        p = [0.0, 0.0, 0.0]
        p[self.ia] = self.ca + r * math.cos(t)
        p[self.ib] = self.cb + r * math.sin(t)
        p[self.il] = self.l0 + self.dl * f
        return (p[0], p[1], p[2])

    def points(self, fa: float, fb: float, n: int) -> List[Vec]:
        """The points at the fractions ``fa + (fb - fa) * j / n``, j = 0..n, as
        :meth:`point` gives them but with the angle stepped by a rotation: two cosine/sine
        pairs instead of n + 1 (the compiled kernel does the same, operation for operation;
        the rounding differs from :meth:`point` by about 1e-16 of the radius a step)."""
        t = self.t0 + self.sweep * fa
        step = self.sweep * (fb - fa) / n
        c, s = math.cos(t), math.sin(t)
        cs, ss = math.cos(step), math.sin(step)
        ia, ib, il = self.ia, self.ib, self.il
        out = []
        for j in range(n + 1):
            f = fa + (fb - fa) * (j / n)
            if f == 0.0:
                out.append(self.start)
            elif f == 1.0:
                out.append(self.end)
            else:
                r = self.r0 + self.dr * f
                p = [0.0, 0.0, 0.0]
                p[ia] = self.ca + r * c
                p[ib] = self.cb + r * s
                p[il] = self.l0 + self.dl * f
                out.append((p[0], p[1], p[2]))
            c, s = c * cs - s * ss, s * cs + c * ss
        return out

    def length_to(self, f: float) -> float:
        """Path length (mm) from the start to fraction ``f`` (the helix of the blended
        radius; E is split in proportion to it)."""
        planar = abs(self.sweep) * f * (self.r0 + 0.5 * self.dr * f)
        lin = self.dl * f
        return math.sqrt(planar * planar + lin * lin)

    def cuts(self, breaks: Sequence[float]) -> List[float]:
        """End fractions of the pieces the arc is written in (the last is 1.0): cut at every
        angle ``breaks[i] + n*pi`` inside the sweep, then each piece into equal parts of at
        most ``MAX_PIECE_RAD``."""
        t0, sweep = self.t0, self.sweep
        lo, hi = (t0, t0 + sweep) if sweep > 0 else (t0 + sweep, t0)
        width = abs(sweep)
        if (len(breaks) + 1) * width / math.pi > MAX_SEGMENTS:
            raise ArcError(f"arc of {width / TWO_PI:.0f} turns needs too many pieces")
        fracs = []
        for phi in breaks:
            k = math.ceil((lo - phi) / math.pi)
            while phi + k * math.pi < hi:
                f = (phi + k * math.pi - t0) / sweep
                if BREAK_EDGE < f < 1.0 - BREAK_EDGE:
                    fracs.append(f)
                k += 1
        fracs.sort()
        fracs.append(1.0)
        out = []
        fa = 0.0
        prev = None
        for fb in fracs:
            if fb == prev:
                continue  # two axes reverse at the same angle
            prev = fb
            n = math.ceil(width * (fb - fa) / MAX_PIECE_RAD - 1e-9)
            for i in range(1, n):
                out.append(fa + (fb - fa) * i / n)
            out.append(fb)
            fa = fb
        return out
