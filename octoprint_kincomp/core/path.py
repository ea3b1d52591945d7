"""Writing a compensated path: a polyline of desired machine positions in, G-code lines out.

This is where a move is transformed (the reference implementation; the accelerated engines
must write the same bytes): each point's desired machine position ``p`` (mm, homed frame)
goes through the inverse kinematic model to the carriage command ``q``, gets the backlash
take-up offset (``dir * fraction * b(q) / 2``, mm) and, with servo pre-compensation, the
lead ``v * T`` per axis; the limits policy is applied; the firmware coordinate
``fw = c + g`` is written with the output resolution (``decimals`` in mm, two more in
inches). Backlash reversals are decided on the carriage command (under skew an axis can be
driven back and forth although its desired coordinate does not change) and taken up by an
extra move (``G1`` to the start point with the new offset) or ramped over ``smoothing_mm``
of following path. E is split over sub-segments in proportion to their length.
"""

from __future__ import annotations

import math
from typing import List, Optional, Tuple

from .compensation_errors import CompensationError, LimitError
from .gcode import Word, decimals_of, fmt

AXIS_LETTERS = ("X", "Y", "Z")
MM_PER_INCH = 25.4


class EDistribution:
    """Splits one E word over sub-segments by path length, keeping the total exact: the
    last piece of an absolute E is the word as written; relative E is split in whole units
    of its own resolution (at least 5 decimals) so the pieces add up exactly.

    A move written in one piece takes the E word as written: its resolution (``decimals``,
    ``scale``, and for relative E the word in whole ``units``) is worked out only when a
    piece of it is taken (:meth:`_split`)."""

    __slots__ = (
        "word",
        "relative",
        "e0",
        "total_len",
        "decimals",
        "scale",
        "units",
        "units_done",
        "part",
    )

    def __init__(self, word: Optional[Word], relative: bool, e0: Optional[float], total_len: float):
        self.word = word
        self.relative = relative
        self.e0 = e0
        self.total_len = total_len
        self.decimals = None  # (not worked out yet)
        self.units_done = 0  # relative E: units of the pieces taken so far
        self.part = 0  # units of the last piece taken

    def _split(self) -> None:
        """Work out the word's resolution (its decimals, at least 5) and, for relative E,
        the word in whole units of it."""
        if self.decimals is None:
            self.decimals = max(decimals_of(self.word.text), 5)
            self.scale = 10**self.decimals
            if self.relative:
                self.units = round(self.word.value * self.scale)

    def take(self, s_end: float, last: bool) -> Optional[str]:
        """The E word of the piece that ends ``s_end`` mm along the path."""
        w = self.word
        if w is None:
            return None
        if last and (not self.relative or self.units_done == 0):
            return w.text  # the whole E word in one piece: exactly as written
        self._split()
        if last:
            self.part = self.units - self.units_done
            return "E" + fmt(self.part / self.scale, self.decimals)
        f = s_end / self.total_len if self.total_len > 0 else 1.0
        if self.relative:
            upto = round(self.units * f)
            self.part = upto - self.units_done
            self.units_done = upto
            return "E" + fmt(self.part / self.scale, self.decimals)
        return "E" + fmt(self.e0 + (w.value - self.e0) * f, self.decimals)

    def mark(self):
        """What :meth:`untake` goes back to (before a piece is taken)."""
        return (self.units_done, self.part) if self.word is not None and self.relative else None

    def untake(self, mark) -> None:
        """Forget the pieces taken since :meth:`mark`: their share goes to the next one."""
        if mark is not None:
            self.units_done, self.part = mark

    def merged(self, prev_part: Optional[int]) -> str:
        """The E word of the last piece and the one before it (units ``prev_part`` when
        relative) written as one: the last piece had no length (see :class:`Pieces`)."""
        if not self.relative:
            return self.word.text
        self._split()
        return "E" + fmt((prev_part + self.part) / self.scale, self.decimals)


class Pieces:
    """The output lines of one move cut into pieces (chords, arc pieces, ramp splits) and
    the rule that no piece of no length carries extrusion or words where the move has length
    (issue 28): a piece whose rounded coordinates do not move (``moved`` false) but that
    carries words (E, or the first piece's F) is not written; its words go on to the next
    piece (E by length, so the next piece's share holds it). The last piece cannot pass
    its E on: it is folded into the piece written before it (whose E then reaches the
    word's end value). A move of one piece is written as it is."""

    __slots__ = ("out", "edist", "prev")

    def __init__(self, out: List[str], edist: EDistribution):
        self.out = out
        self.edist = edist
        self.prev = None  # (index in out, its E text, its relative E units) of the last piece

    def add(
        self, line: str, moved: bool, words: List[str], e_text: Optional[str], last: bool, mark
    ) -> bool:
        """Place a piece just emitted (``line``: its text, ``words``: its words after the
        axes, ``e_text``: its E word, ``mark``: the E split before it). False: it was not
        written (the caller passes its words on: first piece's tail and comment)."""
        out = self.out
        if moved or not words:
            self._keep(line, e_text)
            return True
        if not last:
            self.edist.untake(mark)
            return False
        prev = self.prev
        if prev is None or e_text is None or len(words) != 1:
            self._keep(line, e_text)
            return True
        idx, prev_text, prev_part = prev
        merged = self.edist.merged(prev_part)
        old = out[idx]
        at = old.index(" " + prev_text)
        out[idx] = old[: at + 1] + merged + old[at + 1 + len(prev_text) :]
        return True

    def _keep(self, line: str, e_text: Optional[str]) -> None:
        ed = self.edist
        self.out.append(line)
        if e_text is not None:
            part = ed.part if ed.word is not None and ed.relative else None
            self.prev = (len(self.out) - 1, e_text, part)


def lerp(a, b, f):
    """Point ``f`` (0..1) of the way from ``a`` to ``b``; None stays None."""
    return tuple(
        None if a[k] is None or b[k] is None else a[k] + (b[k] - a[k]) * f for k in range(3)
    )


def segment_lengths(start, points) -> List[Optional[float]]:
    """The length (mm) of each segment of the polyline ``start -> points`` (desired
    positions, None: unknown): over the axes its end knows, None where it comes from an
    unknown position on an axis it moves."""
    lengths: List[Optional[float]] = []
    prev = start
    for p in points:
        if None not in prev and None not in p:
            dx, dy, dz = p[0] - prev[0], p[1] - prev[1], p[2] - prev[2]
            lengths.append(math.sqrt(dx * dx + dy * dy + dz * dz))
        elif any(prev[k] is None and p[k] is not None for k in range(3)):
            lengths.append(None)  # coming from an unknown position: length unknown
        else:
            acc = 0.0
            for k in range(3):
                if p[k] is not None:
                    d = p[k] - prev[k]
                    acc += d * d
            lengths.append(math.sqrt(acc))
        prev = p
    return lengths


class PathWriter:
    """Emits polylines for one compensator: its model, backlash tracker, options, stream
    state and servo lead (seconds per axis, or None)."""

    def __init__(self, model, backlash, options, state, needs, servo_s):
        self.model = model
        self.backlash = backlash
        self.options = options
        self.state = state
        self.needs = needs
        self.servo_s = servo_s
        self.moved = False  # whether the line :meth:`emit` wrote last moves an axis
        self._rounded = [(None, None, None, None)] * 3  # (see fw_after)

    def path(
        self,
        code_text: str,
        start: List[Optional[float]],
        points,
        given,
        e_word,
        tail: List[Word],
        comment: str,
        e_relative: bool,
    ) -> List[str]:
        """Emit the polyline ``start -> points`` (desired machine positions, mm).

        ``tail`` are the line's words other than X/Y/Z in their original order; the first
        piece carries them all, later pieces only their share of ``e_word`` (which is split
        along the path); the last piece writes the ``given`` axes (those the line names)
        even where they do not change. Handles backlash reversals (take-up moves or ramp
        splits), servo lead, limits and output formatting.
        """
        bl = self.backlash
        ramps = bl.any_active and bl.smoothing > 0  # (smoothed take-ups: see polyline)
        if len(points) == 1 and not ramps and self.servo_s is None:
            return self.straight(code_text, start, points[0], given, tail, comment)
        return self.polyline(code_text, start, points, given, e_word, tail, comment, e_relative)

    def polyline(
        self,
        code_text: str,
        start: List[Optional[float]],
        points,
        given,
        e_word,
        tail: List[Word],
        comment: str,
        e_relative: bool,
    ) -> List[str]:
        """:meth:`path` in general: any number of points, smoothed take-ups, servo lead."""
        bl = self.backlash
        st = self.state
        # Smoothed take-ups ramp over the following path: each segment is cut where one
        # finishes. (An absolute E from an unknown E position cannot be split: the ramp then
        # just completes over the whole move, which still ends on the right point.)
        ramps = bl.any_active and bl.smoothing > 0
        lengths = segment_lengths(start, points)
        total_len = sum(lengths) if None not in lengths else 0.0
        edist = EDistribution(e_word, e_relative, st.e_pos, total_len)
        e_unsplittable = e_word is not None and not e_relative and st.e_pos is None
        out: List[str] = []
        pieces = Pieces(out, edist)
        first = True
        s_done = 0.0
        p0 = start
        q0 = self.carriage(p0)
        drives = st.q_drive
        if drives is not None:  # drives that are not at the command of p0 (state.py)
            q0 = tuple(q if d is None else d for q, d in zip(q0, drives))
            st.q_drive = None
        last_idx = len(points) - 1
        tol = self.options.chord_tol_mm
        for idx, p1 in enumerate(points):
            seg_len = lengths[idx]
            q1 = self.carriage(p1)
            if bl.any_active:
                self.reversals(p0, q0, q1, seg_len, out, slack=tol if idx else 0.0)
            cuts = (1.0,)
            if ramps and seg_len and not e_unsplittable:
                cuts = self.ramp_cuts(seg_len)
            velocity = None
            if self.servo_s is not None and seg_len and st.feed:
                velocity = tuple(
                    0.0 if p1[k] is None else (p1[k] - p0[k]) / seg_len * st.feed / 60.0
                    for k in range(3)
                )
            f_prev = 0.0
            for f in cuts:
                if f < 1.0:
                    p = lerp(p0, p1, f)
                    q = lerp(q0, q1, f)
                else:
                    p, q = p1, q1
                sub_len = (f - f_prev) * seg_len if seg_len is not None else 0.0
                last = idx == last_idx and f == 1.0
                mark = edist.mark()
                e_text = None
                if e_word is not None:
                    e_text = edist.take(s_done + sub_len, last)
                if first:
                    words = [e_text if w is e_word else w.text for w in tail]
                else:
                    words = [e_text] if e_text is not None else []
                line = self.emit(
                    code_text,
                    p,
                    q,
                    given if last else (),
                    words,
                    comment,
                    sub_len,
                    velocity,
                    keep_empty=True,
                    slack=0.0 if last else tol,
                )
                if pieces.add(line, self.moved, words, e_text, last, mark):
                    first = False
                    comment = ""
                if ramps:
                    bl.advance(sub_len)
                s_done += sub_len
                f_prev = f
            p0, q0 = p1, q1
        if drives is not None:  # a drive this move does not command stays where it was
            kept = tuple(d if q is None else None for q, d in zip(q0, drives))
            st.q_drive = None if kept == (None, None, None) else kept
        return out

    def straight(
        self, code_text: str, start, end, given, tail: List[Word], comment: str
    ) -> List[str]:
        """:meth:`path` for a polyline of one segment, ``start -> end`` (desired machine
        positions, mm), where no take-up ramps and no servo lead applies (every G0/G1 of
        such a model): the same lines. Nothing cuts the segment, so it is written in one
        piece, which takes the words of ``tail`` as written (the E word whole, as the
        last piece of a split E takes it), preceded by a take-up move where an axis
        reverses."""
        st = self.state
        seg_len = segment_lengths(start, (end,))[0]
        q0 = self.carriage(start)
        drives = st.q_drive
        if drives is not None:  # drives that are not at the command of start (state.py)
            q0 = tuple(q if d is None else d for q, d in zip(q0, drives))
            st.q_drive = None
        q1 = self.carriage(end)
        out: List[str] = []
        if self.backlash.any_active:
            self.reversals(start, q0, q1, seg_len, out)
        words = [w.text for w in tail]
        travel = seg_len if seg_len is not None else 0.0
        out.append(
            self.emit(code_text, end, q1, given, words, comment, travel, None, keep_empty=True)
        )
        if drives is not None:  # a drive this move does not command stays where it was
            kept = tuple(d if q is None else None for q, d in zip(q1, drives))
            st.q_drive = None if kept == (None, None, None) else kept
        return out

    def reversals(
        self, p0, q0, q1, seg_len: Optional[float], out: List[str], slack: float = 0.0
    ) -> None:
        """The backlash reversals of the segment from ``p0`` (desired, mm) whose carriage
        commands go from ``q0`` to ``q1`` (mm; ``seg_len`` None: it comes from an unknown
        position, whose axes start with no direction): without smoothing, a take-up move to
        the segment's start with the new offsets is appended to ``out`` (unless it changes
        nothing at the output resolution). ``slack`` (mm): see :meth:`limit` (the start of
        a segment inside a polyline is a chord end, not a point the source writes)."""
        bl = self.backlash
        if seg_len is None:
            bl.reset([k for k in range(3) if q0[k] is None])
        if bl.detect_reversals(q0, q1, q0) and bl.smoothing == 0:
            takeup = self.emit("G1", p0, q0, (), [], "", 0.0, None, slack=slack)
            if takeup is not None:
                out.append(takeup)
                self.state.report.takeup_moves += 1

    def ramp_cuts(self, seg_len: float) -> List[float]:
        """Fractions (0..1, the last 1.0) where a segment of ``seg_len`` mm is cut: where a
        smoothed take-up ramping on it finishes."""
        bl = self.backlash
        cuts = [1.0]
        for k in range(3):
            rem = bl.ramp_remaining(k)
            if rem is not None and 1e-9 < rem < seg_len - 1e-9:
                cuts.append(rem / seg_len)
        return sorted(set(cuts))

    def carriage(self, p) -> Tuple[Optional[float], Optional[float], Optional[float]]:
        """Geometric command q (mm) for desired p; None where q needs an unknown axis."""
        if None not in p:
            return self.model.inverse(p)
        q = self.model.inverse([v if v is not None else 0.0 for v in p])
        return tuple(None if any(p[j] is None for j in self.needs[k]) else q[k] for k in range(3))

    def limit(self, k: int, p: float, c: float, slack: float = 0.0) -> float:
        """Apply the limits policy to axis k's command ``c`` (mm) for desired ``p`` (mm).

        The travel is the limits, widened to a point the source itself puts past them (the
        printer's travel really ends there: compensation neither pushes past it nor pulls it
        in); ``slack`` (mm, >= 0) is how far such a point may be pulled in all the same: 0
        for a point the source writes, the chord tolerance for one on the way between two
        (an arc's chord end near its apex: the firmware never goes there). ``clamp`` and
        ``error`` keep the command inside, rounded toward the inside at the output
        resolution; ``warn`` counts and sends it. Each hit is counted with its shortfall
        (um: how much of the correction is lost, or how far past the travel under ``warn``).
        """
        opts = self.options
        lo, hi = opts.limits[2 * k], opts.limits[2 * k + 1]
        st = self.state
        rep = st.report
        inside = lo <= p <= hi
        if not inside:
            if p != st.m[k]:
                rep.source_outside += 1
            if p < lo:
                lo = min(lo, p + slack)
            else:
                hi = max(hi, p - slack)
        if c < lo or c > hi:
            rep.limit_hits += 1
            short = (lo - c if c < lo else c - hi) * 1000.0
            if short > rep.limit_worst_um:
                rep.limit_worst_um = short
                rep.limit_worst_axis = AXIS_LETTERS[k]
            if len(rep.limit_examples) < 20:
                rep.limit_examples.append((st.lineno, AXIS_LETTERS[k], round(c, 6)))
            if opts.policy == "error" and inside:
                raise LimitError(
                    f"compensated {AXIS_LETTERS[k]}={c:.4f} mm is outside the "
                    f"limits {lo:g}..{hi:g} mm",
                    st.lineno,
                )
            if opts.policy != "warn":
                c = min(max(c, lo), hi)
        if opts.policy != "warn":
            c = self.inward(k, c, lo, hi)
        return c

    def inward(self, k: int, c: float, lo: float, hi: float) -> float:
        """Axis ``k``'s command ``c`` (mm) moved by whole output steps until its written text
        lies within ``lo..hi`` (mm): rounding toward the inside (a limit of 90.4598 is
        written 90.459, not 90.46). The firmware compares the number on the line."""
        st = self.state
        u = MM_PER_INCH if st.inches else 1.0
        dec = self.options.decimals + (2 if st.inches else 0)
        g = st.g[k]
        step = 10.0**-dec
        for _ in range(3):
            x = float(fmt((c + g) / u, dec))
            v = x * u - g
            if v > hi:
                c = (x - step) * u - g
            elif v < lo:
                c = (x + step) * u - g
            else:
                break
        return c

    def fw_after(self, k: int, c: float, u: float, dec: int):
        """Axis ``k`` commanded to ``c`` (mm, carriage frame), without changing the state:
        (its word on the line, whether it changed, the firmware coordinate (mm) and its text
        after the move). Absolute output writes the rounded coordinate; relative output the
        difference of the rounded coordinates, so rounding never accumulates. ``u``: mm per
        output unit, ``dec``: output decimals.

        An axis often stays where it was (Z through a layer, the other axes around a
        take-up): the last coordinate rounded is kept per axis, with its text and the number
        that text reads back as."""
        st = self.state
        value = (c + st.g[k]) / u
        last = self._rounded[k]
        if last[0] == value and last[1] == dec:
            text, rounded = last[2], last[3]
        else:
            text = fmt(value, dec)
            rounded = float(text)
            self._rounded[k] = (value, dec, text, rounded)
        if st.absolute:
            old_text = st.fw_text[k]
            if old_text is None and st.fw[k] is not None:
                old_text = fmt(st.fw[k] / u, dec)
            return text, text != old_text, rounded * u, text
        old = st.fw[k]
        if old is None:  # cannot happen: relative moves need known axes
            raise CompensationError("relative move from an unknown position", st.lineno)
        delta = fmt(rounded - old / u, dec)
        return delta, delta.strip("0.") != "", old + float(delta) * u, None

    def emit(
        self,
        code_text: str,
        p,
        q,
        write_axes,
        words: List[str],
        comment: str,
        travel: float,
        velocity,
        keep_empty: bool = False,
        slack: float = 0.0,
    ) -> Optional[str]:
        """Format one output move to desired position ``p`` (mm; carriage commands ``q``, mm)
        and update the stream state: per axis the command gets its take-up offset (at
        ``travel`` mm into the move while a take-up ramps) and servo lead (``velocity``,
        mm/s per axis, or None), the limits policy, and is written where its text changes
        or the axis is in ``write_axes``. :attr:`moved` says whether it moves an axis.

        Returns None when nothing would be written and ``keep_empty`` is false (a take-up
        too small to show at the output resolution). ``slack``: see :meth:`limit`.
        """
        st = self.state
        opts = self.options
        u = MM_PER_INCH if st.inches else 1.0
        dec = opts.decimals + (2 if st.inches else 0)
        bl = self.backlash
        offsets = bl.offsets(q, travel) if bl.any_active else None
        lim = opts.limits
        max_corr = st.report.max_correction_um
        fw = st.fw
        moved = False
        parts = [code_text]
        for k in range(3):
            c = q[k]
            if c is None:
                continue
            if offsets is not None:
                c += offsets[k]
            if velocity is not None:
                c += self.servo_s[k] * velocity[k]
            if lim is not None:
                c = self.limit(k, p[k], c, slack)
            corr = abs(c - p[k]) * 1000.0
            if corr > max_corr[k]:
                max_corr[k] = corr
            before = fw[k]
            word, changed, fw[k], st.fw_text[k] = self.fw_after(k, c, u, dec)
            if fw[k] != before:
                moved = True
            if k in write_axes or changed:
                parts.append(AXIS_LETTERS[k] + word)
        m = st.m
        for k in range(3):
            if p[k] is not None:
                m[k] = p[k]
        self.moved = moved
        if len(parts) == 1 and not words and not keep_empty:
            return None
        parts += words
        out = " ".join(parts)
        if comment:
            out += " " + comment
        return out
