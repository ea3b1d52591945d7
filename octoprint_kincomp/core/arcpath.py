"""Writing a G2/G3 as arcs: the reference implementation (the compiled kernel must write the
same bytes, ``engines/csrc/arc.c``).

Under skew and scale a circle becomes an ellipse, which no G2/G3 can describe exactly; but
over a short sweep the compensated path stays very close to a circle. The arc is cut where a
carriage command of a backlash axis reverses (its command extremes, so the take-up lands
there as it does for chords) and into pieces of at most 90 degrees. Each piece is written as
one G2/G3 (IJ form, same direction) whose circle runs through the firmware's start (the
rounded coordinates of the previous line), the piece's compensated midpoint and its rounded
compensated end, when the compensated path stays close enough to that circle: at 7 points
(1/8 .. 7/8 of the piece) the distance of the compensated point (mm) from the circle, radially
in the plane and along the linear axis at the same angle, times ``gain * 1.1`` (``gain``: a
bound of the forward model's norm, so the distance holds for the printed path; 1.1: the
largest deviation of these smooth residuals can lie between two samples) plus
``1.5 * resolution`` (the centre is written rounded) must not exceed ``chord_tol_mm``.
Otherwise the piece is halved, up to 3 times; a piece that still does not fit is linearised
into chords within the tolerance. A piece whose rounded end equals its start in the plane is a
``G1`` (a G2/G3 with equal ends would be a full circle), and so is a sliver (its sagitta at
most a tenth of the output resolution: where a reversal falls next to an end). E is split in
proportion to the path length from the arc's start (:meth:`Arc.length_to`).

With backlash the command of each piece moves every backlash axis one way only, so the
take-up offset of a piece has one direction: the compensated path is the geometric command
plus ``dir * fraction * b(q) / 2``, and a printer whose play holds the carriage that far behind
the drive follows the desired arc within the tolerance (tests/core/test_arc_fit.py checks
every written arc of generated programs so, at fine steps, with and without play).

Arcs are kept when the model is more than a translation, unless ``Options.linearise_arcs``
(firmware without arc support), a smoothed take-up or servo lead is active (their offsets
change along the path), or the machine limits are set and the arc's box, compensated, comes
within the tolerance and the largest take-up offset of a limit: those arcs are linearised
(chords take the limits policy point by point).
"""

from __future__ import annotations

import math
from typing import List, Sequence, Tuple

from . import arcs
from .gcode import fmt
from .path import MM_PER_INCH, EDistribution, Pieces

MAX_DEPTH = 3  # a piece that does not fit is halved at most this often
SAMPLES = (1, 2, 3, 5, 6, 7)  # the eighths where a piece is checked (its middle, 4, fits)
SAMPLE_MARGIN = 1.1
ROUNDING_ALLOWANCE = 1.5  # output resolutions: the written centre is rounded
SLIVER = 0.1  # a piece whose sagitta is at most this many output resolutions is a G1
EIGHTHS = tuple(j * 0.125 for j in range(9))
# a spiral or helix can turn an axis round just before or after a piece's end (where the
# circle's break angle is not): fractions that close in on both ends, to 2^-16 of the piece
NEAR_ENDS = tuple(2.0**-e for e in range(16, 3, -1))
DENSE = (0.0,) + NEAR_ENDS + EIGHTHS[1:-1] + tuple(1.0 - f for f in reversed(NEAR_ENDS)) + (1.0,)


def model_gain(A) -> float:
    """A bound of the spectral norm of the 3x3 matrix A: sqrt(max column sum * max row sum
    of |a_ij|) (1 for the identity, 1 + the largest error term near it)."""
    rows = max(sum(abs(float(A[i][j])) for j in range(3)) for i in range(3))
    cols = max(sum(abs(float(A[i][j])) for i in range(3)) for j in range(3))
    return math.sqrt(rows * cols)


def strictly_between(
    va: float, vb: float, sa: float, sb: float, ea: float, eb: float, clockwise: bool
) -> bool:
    """Whether the direction (va, vb) lies strictly between the start direction (sa, sb) and
    the end direction (ea, eb), turning clockwise or counter-clockwise from the start: its
    angle from the start in (0, that of the end), both taken in [0, 2 pi). Decided by the
    signs of cross products alone, without angles (what the compiled kernel does too, at no
    trigonometric cost)."""
    turn = -1.0 if clockwise else 1.0
    hv = _half_turn(turn * (sa * vb - sb * va), sa * va + sb * vb)
    he = _half_turn(turn * (sa * eb - sb * ea), sa * ea + sb * eb)
    if hv < 0 or he < 0:  # along the start direction itself: angle 0
        return False
    if hv != he:
        return hv < he
    return turn * (va * eb - vb * ea) > 0.0


def _half_turn(cross: float, dot: float) -> int:
    """The half turn an angle from a start direction lies in, from its cross product (taken
    positive in the turning sense) and its dot product with that direction: 0 for (0, pi],
    1 for (pi, 2 pi), -1 for 0 itself."""
    if cross > 0.0:
        return 0
    if cross < 0.0:
        return 1
    return 0 if dot < 0.0 else -1


class ArcWriter:
    """Writes arcs for one compensator's path writer (shares its state, model, tracker)."""

    def __init__(self, writer, comp):
        self.w = writer
        self.state = writer.state
        self.backlash = writer.backlash
        self.options = writer.options
        self.k_dev = model_gain(writer.model.A) * SAMPLE_MARGIN
        bl = self.backlash
        # per plane: the angles where the command of a backlash axis reverses
        self.breaks = {
            plane: tuple(phi for k, phi in comp.moves.extreme_axes(plane) if bl.active[k])
            for plane in arcs.PLANES
        }
        tables = [t for k, t in enumerate(bl.tables) if bl.active[k]]
        self.max_offset = bl.half * max((um for t in tables for _, um in t.points), default=0.0)
        # per output unit (index: inches): what may be spent on the fit, and the sagitta
        # below which a piece is a G1 (mm)
        tol = self.options.chord_tol_mm
        res = (10.0**-self.options.decimals, MM_PER_INCH * 10.0 ** -(self.options.decimals + 2))
        self.budget = (tol - ROUNDING_ALLOWANCE * res[0], tol - ROUNDING_ALLOWANCE * res[1])
        self.sliver = (SLIVER * res[0], SLIVER * res[1])
        self.overshoot = res  # mm: how far a written circle may carry a backlash axis back
        self._eighths_of, self._eighths = None, {}  # (see eighths)

    def usable(self) -> bool:
        """Whether arcs can be written as arcs here (see the module docstring)."""
        w = self.w
        return (
            not self.options.linearise_arcs
            and self.backlash.smoothing == 0
            and w.servo_s is None
            and None not in self.state.fw
        )

    def inside_limits(self, arc: arcs.Arc) -> bool:
        """With limits: the arc's box (desired) and that box compensated, widened by the
        tolerance and the largest take-up offset, lie inside the limits."""
        lim = self.options.limits
        if lim is None:
            return True
        rmax = max(arc.r0, arc.r1)
        lo, hi = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        lo[arc.ia], hi[arc.ia] = arc.ca - rmax, arc.ca + rmax
        lo[arc.ib], hi[arc.ib] = arc.cb - rmax, arc.cb + rmax
        l0, l1 = arc.start[arc.il], arc.end[arc.il]
        lo[arc.il], hi[arc.il] = min(l0, l1), max(l0, l1)
        margin = self.options.chord_tol_mm + self.max_offset
        for k in range(3):
            if lo[k] < lim[2 * k] or hi[k] > lim[2 * k + 1]:
                return False
        for i in range(8):
            p = tuple(hi[k] if i >> k & 1 else lo[k] for k in range(3))
            q = self.w.carriage(p)
            for k in range(3):
                if q[k] - margin < lim[2 * k] or q[k] + margin > lim[2 * k + 1]:
                    return False
        return True

    def dense(self, arc: arcs.Arc) -> bool:
        """Whether the arc may turn an axis round off its break angles by more than a
        quarter of the deadband: a helix, or a spiral whose radius changes by ``r'`` (mm/rad)
        with ``r'^2 / (2 r) > deadband / 4`` (the dip next to an end where the circle's
        extreme would be); a slicer's arc (radii equal to its rounding) is not."""
        if arc.dl != 0.0:
            return True
        r = min(arc.r0, arc.r1)
        return arc.dr * arc.dr > arc.sweep * arc.sweep * r * 0.5 * self.backlash.deadband

    def eighths(self, arc: arcs.Arc, fa: float, fb: float):
        """The points at the eighths of the piece ``fa``..``fb`` of ``arc`` (desired, mm,
        :meth:`Arc.points`) and their carriage commands (mm): worked out once per piece of
        the arc being written (:meth:`monotone` checks the commands, the fit samples
        them)."""
        if self._eighths_of is not arc:
            self._eighths_of, self._eighths = arc, {}
        got = self._eighths.get((fa, fb))
        if got is None:
            points = arc.points(fa, fb, 8)
            got = self._eighths[fa, fb] = (points, [self.w.carriage(p) for p in points])
        return got

    def monotone(self, arc: arcs.Arc, cuts: Sequence[float]) -> bool:
        """Whether the command of every backlash axis moves one way along each piece (it
        does not rise and fall by more than the deadband, checked at eighths of the piece,
        and for :meth:`dense` arcs ever closer to both ends too): a spiral or a helix can
        reverse between the break angles of a circle; such arcs are linearised (their
        chords take the reversals where they fall)."""
        bl = self.backlash
        if not bl.any_active:
            return True
        db = bl.deadband
        carriage = self.w.carriage
        dense = self.dense(arc)
        fa = 0.0
        for fb in cuts:
            if dense:
                qs = [carriage(arc.point(fa + (fb - fa) * f)) for f in DENSE]
            else:
                qs = self.eighths(arc, fa, fb)[1]
            for k in range(3):
                if not bl.active[k]:
                    continue
                lo = hi = qs[0][k]
                rise = fall = 0.0
                for q in qs:
                    v = q[k]
                    if v - lo > rise:
                        rise = v - lo
                    if hi - v > fall:
                        fall = hi - v
                    if v < lo:
                        lo = v
                    if v > hi:
                        hi = v
                if rise > db and fall > db:
                    return False
            fa = fb
        return True

    # -- writing -----------------------------------------------------------------------
    def write(
        self,
        code_text: str,
        arc: arcs.Arc,
        cuts: Sequence[float],
        clockwise: bool,
        given,
        e_word,
        tail,
        comment: str,
        e_relative: bool,
    ) -> List[str]:
        """The lines of one arc cut at ``cuts`` (:meth:`Arc.cuts` with :attr:`breaks`);
        ``tail``: its words other than X/Y/Z/I/J/K/R/P."""
        st = self.state
        bl = self.backlash
        w = self.w
        job = _Job(
            self,
            arc,
            clockwise,
            code_text,
            given,
            tail,
            comment,
            EDistribution(e_word, e_relative, st.e_pos, arc.length_to(1.0)),
            e_word,
        )
        fa, pa = 0.0, arc.start
        qa = w.carriage(pa)
        if st.q_drive is not None:  # drives that are not at the command of the start
            qa = tuple(q if d is None else d for q, d in zip(qa, st.q_drive))
            st.q_drive = None
        for fb in cuts:
            pb = arc.point(fb)
            qb = w.carriage(pb)
            if bl.any_active and bl.detect_reversals(qa, qb, qa):
                takeup = w.emit(
                    "G1", pa, qa, (), [], "", 0.0, None, slack=self.options.chord_tol_mm * (fa > 0)
                )
                if takeup is not None:
                    job.out.append(takeup)
                    st.report.takeup_moves += 1
            job.piece(fa, fb, pb, qb, 0)
            fa, pa, qa = fb, pb, qb
        rep = st.report
        if job.arcs == 0:
            rep.arcs_linearised += 1
        elif job.segments == 1:
            rep.arcs_kept += 1
        else:
            rep.arcs_split += 1
        rep.arc_segments += job.segments
        if job.dev > rep.arc_max_deviation_um:
            rep.arc_max_deviation_um = job.dev
        return job.out


class _Job:
    """The lines of one arc being written."""

    def __init__(
        self, aw: ArcWriter, arc, clockwise, code_text, given, tail, comment, edist, e_word
    ):
        self.aw, self.arc, self.clockwise = aw, arc, clockwise
        self.code_text, self.given, self.tail, self.comment = code_text, given, tail, comment
        self.edist, self.e_word = edist, e_word
        self.out: List[str] = []
        self.pieces = Pieces(self.out, edist)
        self.first = True
        self.arcs = 0  # G2/G3 written
        self.segments = 0  # lines written for the arc (not take-ups)
        self.dev = 0.0  # worst deviation of a written arc piece (um)

    def words(self, f: float, last: bool):
        """(E share and, on the first line, the other words; the E word) of a segment
        ending at f."""
        e_text = None
        if self.e_word is not None:
            e_text = self.edist.take(self.arc.length_to(f), last)
        if self.first:
            return [e_text if wd is self.e_word else wd.text for wd in self.tail], e_text
        return ([e_text] if e_text is not None else []), e_text

    def line(self, code: str, p, q, f: float, extra: List[str]) -> None:
        last = f == 1.0
        w = self.aw.w
        write_axes = self.given if last else ()
        mark = self.edist.mark()
        words, e_text = self.words(f, last)
        slack = 0.0 if last else self.aw.options.chord_tol_mm  # (a point on the way)
        line = w.emit(
            code,
            p,
            q,
            write_axes,
            extra + words,
            self.comment,
            0.0,
            None,
            keep_empty=True,
            slack=slack,
        )
        if self.pieces.add(line, w.moved, words, e_text, last, mark):
            self.first = False
            self.comment = ""
            if line is self.out[-1]:
                self.segments += 1

    def piece(self, fa: float, fb: float, pb, qb, depth: int) -> None:
        arc = self.arc
        half = abs(arc.sweep) * (fb - fa) * 0.5
        if max(arc.r0, arc.r1) * half * half * 0.5 <= self.aw.sliver[self.aw.state.inches]:
            self.line("G1", pb, qb, fb, [])  # a sliver: a chord is as good as an arc
            return
        fit = self.fit(fa, fb, pb, qb)
        if fit is not None:
            if fit is False:  # the rounded end is the start: a G1
                self.line("G1", pb, qb, fb, [])
                return
            self.line(self.code_text, pb, qb, fb, fit[0])
            self.arcs += 1
            dev = fit[1] * 1000.0
            if dev > self.dev:
                self.dev = dev
            return
        w = self.aw.w
        if depth < MAX_DEPTH:
            fm = fa + (fb - fa) * 0.5
            pm = arc.point(fm)
            qm = w.carriage(pm)
            self.piece(fa, fm, pm, qm, depth + 1)
            self.piece(fm, fb, pb, qb, depth + 1)
            return
        # no arc fits: chords within the tolerance (the piece is monotone: no reversal)
        step = arcs.segment_angle(max(arc.r0, arc.r1), self.aw.options.chord_tol_mm)
        n = max(1, math.ceil(abs(arc.sweep) * (fb - fa) / (0.8 * step) - 1e-9))
        for i in range(1, n + 1):
            f = fa + (fb - fa) * i / n if i < n else fb
            p = arc.point(f) if i < n else pb
            self.line("G1", p, w.carriage(p) if i < n else qb, f, [])

    def target(self, q) -> Tuple[float, float, float]:
        """Firmware coordinates (mm) of the compensated point whose carriage command is
        ``q`` (mm): the command, its take-up offset and the firmware's G92 offset."""
        bl = self.aw.backlash
        g = self.aw.state.g
        if bl.any_active:
            o = bl.offsets(q)
            return q[0] + o[0] + g[0], q[1] + o[1] + g[1], q[2] + o[2] + g[2]
        return q[0] + g[0], q[1] + g[1], q[2] + g[2]

    def overshoots(self, S, E, ka: float, kb: float, radius: float, sa: float, sb: float) -> bool:
        """Whether the written circle (centre ka, kb; start S, end E, firmware mm; sa, sb:
        centre -> start) turns a backlash axis of the plane round inside the piece by more
        than the output resolution. The piece ends where the command of such an axis
        reverses; a circle whose extreme in that axis lies before the end carries the axis
        past it and back, and the play then holds the carriage on the wrong side (by that
        amount) until the next reversal."""
        aw, arc = self.aw, self.arc
        ia, ib = arc.ia, arc.ib
        allowed = aw.overshoot[aw.state.inches]
        ea, eb = E[ia] - ka, E[ib] - kb
        for k, centre, va, vb in (
            (ia, ka, radius, 0.0),
            (ia, ka, -radius, 0.0),
            (ib, kb, 0.0, radius),
            (ib, kb, 0.0, -radius),
        ):
            if not aw.backlash.active[k]:
                continue
            if strictly_between(va, vb, sa, sb, ea, eb, self.clockwise):  # its extreme in k
                extreme = centre + (va if k == ia else vb)
                lo, hi = min(S[k], E[k]), max(S[k], E[k])
                over = extreme - hi if extreme > hi else lo - extreme
                if over > allowed:
                    return True
        return False

    def fit(self, fa: float, fb: float, pb, qb):
        """The arc words ([I.., J..], deviation mm) of the piece fa..fb, False when its rounded
        end equals the start in the plane, None when no arc fits."""
        aw, arc = self.aw, self.arc
        st = aw.state
        w = aw.w
        bl = aw.backlash
        ia, ib, il = arc.ia, arc.ib, arc.il
        u = MM_PER_INCH if st.inches else 1.0
        dec = aw.options.decimals + (2 if st.inches else 0)
        S = st.fw
        o = bl.offsets(qb) if bl.any_active else None
        E = [0.0, 0.0, 0.0]
        for k in range(3):
            c = qb[k] if o is None else qb[k] + o[k]
            E[k] = w.fw_after(k, c, u, dec)[2]
        if E[ia] == S[ia] and E[ib] == S[ib]:
            return False
        budget = aw.budget[st.inches]
        if budget <= 0.0:
            return None
        commands = aw.eighths(arc, fa, fb)[1]
        M = self.target(commands[4])
        bx = M[ia] - S[ia]
        by = M[ib] - S[ib]
        cx = E[ia] - S[ia]
        cy = E[ib] - S[ib]
        d = 2.0 * (bx * cy - by * cx)
        if d == 0.0 or (d > 0.0) == self.clockwise:
            return None  # collinear, or the circle would turn the other way
        b2 = bx * bx + by * by
        c2 = cx * cx + cy * cy
        ux = (cy * b2 - by * c2) / d
        uy = (bx * c2 - cx * b2) / d
        radius = arcs.norm2(ux, uy)
        ka = S[ia] + ux
        kb = S[ib] + uy
        sa, sb = -ux, -uy  # centre -> start
        lin0 = S[il]
        dlin = E[il] - lin0
        sweep = 0.0
        if dlin != 0.0:
            ea, eb = E[ia] - ka, E[ib] - kb
            sweep = math.atan2(sa * eb - sb * ea, sa * ea + sb * eb)
            if self.clockwise:
                sweep = -sweep
            if sweep <= 0.0:
                # a half circle's end lies at +-pi: atan2 may give either sign (the circle
                # turns the right way, checked above, so the sweep is in (0, 2 pi))
                sweep += 2.0 * math.pi
        dev = 0.0
        for j in SAMPLES:
            T = self.target(commands[j])
            va = T[ia] - ka
            vb = T[ib] - kb
            dr = arcs.norm2(va, vb) - radius
            lin = lin0
            if dlin != 0.0:
                ang = math.atan2(sa * vb - sb * va, sa * va + sb * vb)
                if self.clockwise:
                    ang = -ang
                lin = lin0 + dlin * (ang / sweep)
            dl = T[il] - lin
            e = arcs.norm2(dr, dl)
            if e > dev:
                dev = e
        dev *= aw.k_dev
        if dev > budget:
            return None
        if bl.any_active and self.overshoots(S, E, ka, kb, radius, sa, sb):
            return None
        la, lb = arcs.PLANES[arc.plane][3:]
        if st.ij_absolute:
            va, vb = ka / u, kb / u
        else:
            va, vb = ux / u, uy / u
        words = sorted([la + fmt(va, dec), lb + fmt(vb, dec)])
        return words, dev
