"""Moves (G0/G1 and G2/G3): from a line's words to the desired machine path, which the path
writer turns into compensated lines, or, when a position the move needs is unknown, the line
as written with the head's new position still tracked (a position is never invented).

A move needs every axis whose command it changes: under skew a Y-only move also moves X, so
X must be known. Arcs are written as arcs (``core/arcpath.py``) or linearised into chords
within ``chord_tol_mm`` (mm) with a chord end wherever a carriage command reverses (so
backlash take-ups land exactly there).
"""

from __future__ import annotations

import math
from typing import List, Optional, Sequence, Tuple

from . import arcs
from .gcode import Word
from .gcode_table import classify

MM_PER_INCH = 25.4
AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


class MoveHandler:
    """The move lines of one compensator (shares its state, model, tracker and writer)."""

    def __init__(self, comp):
        self.comp = comp
        self.state = comp.state
        self.model = comp.model
        self.backlash = comp.backlash
        self.writer = comp.writer
        self.options = comp.options
        self._needed = {}  # (see needed)

    # -- shared --------------------------------------------------------------------------
    def targets(self, words: Sequence[Word]):
        """(given axes, desired machine target with None for unknown) of a move's words."""
        st = self.state
        u = MM_PER_INCH if st.inches else 1.0
        m, offset, lost, absolute = st.m, st.w, st.frame_lost, st.absolute
        target = list(m)
        given = []
        for w in words:
            k = AXIS_INDEX.get(w.letter)
            if k is None:
                continue
            given.append(k)
            if lost[k]:
                continue  # target stays unknown (None) until G28
            if absolute:
                target[k] = w.value * u - offset[k]
            elif m[k] is not None:
                target[k] = m[k] + w.value * u
        return given, target

    def needed(self, given: Sequence[int]) -> frozenset:
        """The axes whose position a move naming ``given`` needs: those it names and every
        axis the commands it changes depend on (under XY skew a Y move changes X's command,
        which depends on X). Depends on the model only: worked out once per set of axes."""
        key = tuple(given)
        need = self._needed.get(key)
        if need is None:
            comp = self.comp
            need = set(given)
            for j in given:
                for k in comp.moved_by[j]:
                    need |= comp.needs[k]
            need = self._needed[key] = frozenset(need)
        return need

    def track_e(self, e_word: Optional[Word], e_relative: Optional[bool] = None) -> None:
        """Absolute E position (the program's E units) for splitting absolute-E moves, kept
        as Marlin keeps it: an absolute E word sets it, a relative one (M83, or G91 while
        G90/G91 govern E) adds to it, so after M83, G91 moves and G90 (E absolute again) the
        next absolute E is split from the summed position (issue 28). Unknown (None) until
        ``G92 E`` or an absolute E word defines it; a relative E from an unknown position
        leaves it unknown. ``e_relative``: whether E is relative now (None: ask the
        compensator)."""
        if e_word is None:
            return
        st = self.state
        if e_relative is None:
            e_relative = self.comp.e_relative
        if not e_relative:
            st.e_pos = e_word.value
        elif st.e_pos is not None:
            st.e_pos = st.e_pos + e_word.value

    def untouched(self, given, words, line: str):
        """Pass a move through as written and keep tracking where the head went."""
        st = self.state
        known_before = [v is not None for v in st.m]
        rep = st.report
        rep.untouched_unknown += 0 if self.comp.passthrough else 1
        passthrough = self.comp.passthrough
        if not passthrough:
            q_before = self.writer.carriage(st.m)
            if st.q_drive is not None:
                q_before = [q if d is None else d for q, d in zip(q_before, st.q_drive)]
        u = MM_PER_INCH if st.inches else 1.0
        c_before = [None if v is None else v - st.g[k] for k, v in enumerate(st.fw)]
        new_m = list(st.m)
        for w in words:
            k = "XYZ".find(w.letter)
            if k < 0:
                continue
            if st.frame_lost[k]:
                continue
            if st.absolute:
                new_m[k] = w.value * u - st.w[k]
                st.fw[k] = w.value * u
            elif st.m[k] is not None:
                new_m[k] = st.m[k] + w.value * u
                st.fw[k] += w.value * u
            st.fw_text[k] = None
        bl = self.backlash
        if bl.any_active:
            bl.observe(c_before, [None if v is None else v - st.g[k] for k, v in enumerate(st.fw)])
            for k in given:
                if not known_before[k] and st.fw[k] is not None:
                    bl.place(k, st.fw[k] - st.g[k])
        st.m = new_m
        st.q_drive = None if passthrough else self._drives_after(given, q_before)
        e = next((w for w in words if w.letter == "E"), None)
        self.track_e(e)
        return line

    def _drives_after(self, given, q_before):
        """``StreamState.q_drive`` after a move passed as written: an axis the line names is
        where the line put its drive (firmware coordinate, no take-up offset on it: its
        geometric command is that minus the offset of its direction); an axis it does not
        name stays where its drive was (``q_before``, mm), offset and direction kept. Where
        that equals the command of the new desired position nothing is recorded."""
        st = self.state
        bl = self.backlash
        q_after = self.writer.carriage(st.m)
        stays = []
        for k in range(3):
            if k in given:
                if st.frame_lost[k] or st.fw[k] is None:
                    d = None
                else:
                    c = st.fw[k] - st.g[k]
                    d = c - bl.target(k, c)
            else:
                d = q_before[k]
                if d is None and st.fw[k] is not None:
                    c = st.fw[k] - st.g[k]
                    d = c - bl.target(k, c)
            stays.append(None if d is None or q_after[k] == d else float(d))
        return None if stays == [None, None, None] else tuple(stays)

    # -- G0/G1 ---------------------------------------------------------------------------
    def linear(self, cmd, words: List[Word], line: str):
        st = self.state
        comp = self.comp
        given, target = self.targets(words)
        e_word = f_word = None
        tail = []  # the words other than X/Y/Z, in their order
        for w in words:
            if w.letter == "E":
                e_word = w
            elif w.letter == "F":
                f_word = w
            if w.letter not in "XYZ":
                tail.append(w)
        if f_word is not None:
            st.feed = f_word.value * (MM_PER_INCH if st.inches else 1.0)
        e_relative = comp.e_relative
        if not given:
            self.track_e(e_word, e_relative)
            return line
        if (
            comp.passthrough
            or (None in target and any(target[k] is None for k in self.needed(given)))
            or (not st.absolute and any(st.m[k] is None for k in given))
        ):
            return self.untouched(given, words, line)
        out = self.writer.path(
            cmd.code_text,
            list(st.m),
            [tuple(target)],
            given,
            e_word,
            tail,
            cmd.comment,
            e_relative,
        )
        self.track_e(e_word, e_relative)
        st.report.moves_compensated += 1
        if 0 not in given and 1 not in given:
            out = xy_apart(out, cmd.code_text)
        return out

    # -- G2/G3 ---------------------------------------------------------------------------
    def arc(self, cmd, words: List[Word], line: str):
        st = self.state
        comp = self.comp
        clockwise = classify(cmd.kind, cmd.number, cmd.sub).value  # (G2: True)
        plane = st.plane
        ia, ib, il, la, lb = arcs.PLANES[plane]
        wd = {w.letter: w for w in words}
        given, target = self.targets(words)
        e_word = wd.get("E")
        f_word = wd.get("F")
        u = MM_PER_INCH if st.inches else 1.0
        if f_word is not None:
            st.feed = f_word.value * u
        turns_w = wd.get("P")
        turns = int(turns_w.value) if turns_w is not None else 0
        plane_axes = {ia, ib} | set(given)
        need = self.needed(sorted(plane_axes))
        # The linear axis is interpolated along the chords (helix), so it must be known too:
        # an XY arc from an unknown Z crashed in linearise (None - None).
        if comp.passthrough or any(st.m[k] is None for k in need | plane_axes | {il}):
            return self.untouched(given, words, line)
        offs = (
            wd[la].value * u if la in wd else None,
            wd[lb].value * u if lb in wd else None,
        )
        radius = wd["R"].value * u if "R" in wd else None
        start = tuple(st.m)
        end = tuple(target)
        tol = self.options.chord_tol_mm
        writer = comp.arc_writer
        try:
            ca, cb = arcs.centre_from_words(
                start, end, plane, offs, radius, clockwise, st.ij_absolute
            )
            if st.ij_absolute:
                ca -= st.w[ia]
                cb -= st.w[ib]
            arc = arcs.Arc(start, end, plane, ca, cb, clockwise, turns)
            arcs.segment_angle(max(arc.r0, arc.r1), tol)  # (raises for a huge radius)
            keep = writer.usable() and writer.inside_limits(arc)
            if keep:
                cuts = arc.cuts(writer.breaks[plane])
                keep = writer.monotone(arc, cuts)
            if not keep:
                pts = arcs.linearise(
                    start, end, plane, ca, cb, clockwise, tol, turns, self.extreme_angles(plane)
                )
        except arcs.ArcError:
            comp.malformed(line)
            return self.untouched(given, words, line)
        if comp.pure_translation and not st.ij_absolute and turns == 0:
            out = self.writer.path(
                cmd.code_text,
                list(start),
                [end],
                given,
                None,
                [w for w in words if w.letter not in "XYZ"],
                cmd.comment,
                comp.e_relative,
            )
            st.report.moves_compensated += 1
            st.report.arcs_kept += 1
            self.track_e(e_word)
            return out
        if e_word is not None and not comp.e_relative and st.e_pos is None:
            # Absolute extrusion from an unknown E: the split cannot be computed.
            return self.untouched(given, words, line)
        tail = [w for w in words if w.letter not in "XYZIJKRP"]
        rep = st.report
        if keep:
            out = writer.write(
                cmd.code_text,
                arc,
                cuts,
                clockwise,
                given,
                e_word,
                tail,
                cmd.comment,
                comp.e_relative,
            )
        else:
            out = self.writer.path(
                "G1", list(start), pts, given, e_word, tail, cmd.comment, comp.e_relative
            )
            rep.arcs_linearised += 1
            rep.arc_segments += len(pts)
        self.track_e(e_word)
        rep.moves_compensated += 1
        return out

    def extreme_axes(self, plane: int) -> Tuple[Tuple[int, float], ...]:
        """(command axis, arc angle in rad) where that axis' carriage command reaches an
        extreme (reverses) on a circle in ``plane``: for ``q = A_inv m`` each command axis k
        is ``A_inv[k, a] r cos t + A_inv[k, b] r sin t + const``, extreme at
        ``atan2(A_inv[k, b], A_inv[k, a])`` (mod pi). Without errors these are the quadrants.
        """
        ia, ib, _, _, _ = arcs.PLANES[plane]
        Ai = self.model.A_inv
        return tuple(
            (k, math.atan2(Ai[k, ib], Ai[k, ia])) for k in range(3) if Ai[k, ia] or Ai[k, ib]
        )

    def extreme_angles(self, plane: int) -> Tuple[float, ...]:
        """The angles of :meth:`extreme_axes` (chord ends are placed there)."""
        return tuple(phi for _, phi in self.extreme_axes(plane))


def xy_apart(lines: List[str], code_text: str) -> List[str]:
    """The lines of a move whose source names neither X nor Y (``G1 Z5 E15 F200``, a Z hop),
    with the X/Y correction carried by a move of its own before each line that also carries
    Z or other words: the source line keeps its class in every firmware (Klipper checks a
    move with X/Y and E against ``max_extrude_cross_section``, one without as extrude-only;
    Marlin and RepRapFirmware apply F to the Z length). The path is the same polyline, its
    X/Y part first; the end point is the same."""
    out = []
    head = code_text + " "
    for line in lines:
        if not line.startswith(head):
            out.append(line)
            continue
        body, sep, comment = line[len(head) :].partition(";")
        toks = body.split()
        xy = [t for t in toks if t[0] in "XY"]
        rest = [t for t in toks if t[0] not in "XY"]
        if not xy or not rest:
            out.append(line)
            continue
        out.append(head + " ".join(xy))
        out.append(head + " ".join(rest) + (" " + sep + comment if sep else ""))
    return out
