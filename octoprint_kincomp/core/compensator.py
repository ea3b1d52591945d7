"""The streaming compensator: G-code line in, compensated line(s) out, O(1) memory.

One engine serves the OctoPrint queuing hook, the upload preprocessor and the command line.

Frames (all in mm internally):

* logical ``L``: what the program writes (after G20 inch conversion);
* desired machine position ``m = L - w`` where ``w`` is the program's G92 offset: the homed
  frame in which the calibration holds;
* commanded machine position ``c = inverse(m) + backlash offset (+ servo lead)``;
* firmware coordinate ``fw = c + g`` where ``g`` is the firmware's own G92 offset. This is what
  is written on the output lines (divided by 25.4 in G20 mode).

With all-zero parameters ``c == m`` and ``g == w``, so ``fw == L`` and every line passes
unchanged. G92 lines are never rewritten; their effect is tracked in ``w`` and ``g``.

A move is compensated when every axis it needs has a known position; otherwise it passes
untouched and is counted in the report (``untouched_unknown``). Homing (G28) makes the homed
axes known at ``home_mm``; probing and other commands that move the head on their own make
positions unknown again; tool changes too (hotend offsets).

Absent other information the firmware frame is taken as the homed frame (``g == 0``): an
absolute move from an unknown position has a known target. A G92 on an axis whose position is
unknown shifts the firmware frame by an unknown amount, so that axis' frame is *lost*: its
absolute coordinates no longer give machine positions until G28 (or G92.1, which drops the
offsets) restores it; a position is never invented.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

from ..engines import kernel as _kernel
from . import arcs
from .backlash import DEFAULT_DEADBAND_MM, BacklashTracker
from .gcode import Word, decimals_of, fmt, parse_command, parse_words
from .kinematics import KinematicModel, changes_nothing
from .params import AXES, Params

AXIS_LETTERS = ("X", "Y", "Z")
MM_PER_INCH = 25.4
POLICIES = ("warn", "clamp", "error")

# G/M codes after which the head is somewhere we cannot know: probing, leveling, parking,
# nozzle cleaning, restore-saved-position, Bambu's probe move.
INVALIDATING_G = frozenset({12, 27, 29, 30, 31, 32, 33, 34, 35, 38, 61, 80, 380, 425})
INVALIDATING_M = frozenset({48})

_FAST_PREFIXES = frozenset({"G1 ", "G0 "})
# The per-line fast path reads a line by its shape: the line with the number characters
# deleted, e.g. "G1 X12.5 Y-3 E0.41" -> "G X Y E". Accepted shapes: an optional F, then X, Y,
# Z, E, F in this order, single spaces. A number then consists of [0-9.+-] only, and on that
# alphabet float() accepts exactly the grammar of gcode.parse_words (anything else raises and
# the general path reports the line); lines of more than 96 characters take the general
# path, so no number reaches gcode.MAX_WORD_VALUE.
_NUMBER_BYTES = b"0123456789.+-"
_FAST_MAX_LEN = 96


def word_shapes(letters: str):
    """Every shape a fast path reads for words ``letters`` in this order, each one present or
    not: (present flags, token index of each letter in ``line.split(" ")`` (0: absent), the
    shape: the code and the letters with the numbers deleted, e.g. b"G X Y E")."""
    for mask in range(1 << len(letters)):
        on = [bool(mask >> i & 1) for i in range(len(letters))]
        idx, n = [], 1
        for present in on:
            idx.append(n if present else 0)
            n += present
        key = " ".join(["G"] + [c for c, present in zip(letters, on) if present]).encode()
        yield on, idx, key


def _fast_shapes() -> Dict[bytes, tuple]:
    """shape -> (token index of X, Y, Z, E, F (0: absent), given axes, index of the first
    token after X/Y/Z, F comes first)."""
    shapes = {}
    for on, idx, key in word_shapes("FXYZEF"):  # F first, X, Y, Z, E, F after
        if on[0] and on[5]:
            continue  # two F words: malformed, the general path reports it
        after_xyz = 1 + on[0] + on[1] + on[2] + on[3]
        shapes[key] = (idx[1], idx[2], idx[3], idx[4], idx[0] or idx[5],
                       (on[1], on[2], on[3]), after_xyz, on[0])
    return shapes


_SHAPES = _fast_shapes()


class CompensationError(RuntimeError):
    """A line could not be compensated (the caller must not send the move uncompensated)."""

    def __init__(self, message: str, lineno: Optional[int] = None):
        self.lineno = lineno
        super().__init__(f"line {lineno}: {message}" if lineno else message)


class LimitError(CompensationError):
    """Policy ``error``: a compensated point falls outside the machine limits."""


@dataclass
class Options:
    """Engine options that are not part of the machine model.

    ``limits``: (x0, x1, y0, y1, z0, z1) mm in the homed machine frame, or None;
    ``policy``: what happens when compensation pushes a point outside the limits: ``warn``
    (count it, send it), ``clamp`` (clamp the commanded point onto the limit) or ``error``
    (raise :class:`LimitError`). Points the program itself places outside are never altered.
    """

    chord_tol_mm: float = 0.01
    limits: Optional[Tuple[float, float, float, float, float, float]] = None
    policy: str = "warn"
    decimals: int = 3
    home_mm: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    deadband_mm: float = DEFAULT_DEADBAND_MM
    g90_influences_extruder: bool = True

    def __post_init__(self):
        if self.policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}")
        if not (1e-5 <= self.chord_tol_mm <= 1.0):
            raise ValueError("chord_tol_mm must be within 0.00001..1 mm")
        if not (3 <= self.decimals <= 8):
            raise ValueError("decimals must be within 3..8")
        if self.limits is not None:
            lim = tuple(float(v) for v in self.limits)
            if len(lim) != 6 or any(not math.isfinite(v) for v in lim):
                raise ValueError("limits needs six finite numbers x0,x1,y0,y1,z0,z1")
            if lim[0] >= lim[1] or lim[2] >= lim[3] or lim[4] >= lim[5]:
                raise ValueError("limits must be given as min,max pairs with min < max")
            self.limits = lim


@dataclass
class Report:
    """What the compensator did (dry-run report). Corrections in um."""

    lines: int = 0
    moves: int = 0
    moves_compensated: int = 0
    untouched_unknown: int = 0
    malformed: int = 0
    malformed_examples: List[Tuple[int, str]] = field(default_factory=list)
    arcs_linearised: int = 0
    arc_segments: int = 0
    takeup_moves: int = 0
    lines_out: int = 0
    max_correction_um: Dict[str, float] = field(
        default_factory=lambda: {a: 0.0 for a in AXES}
    )
    limit_hits: int = 0
    limit_examples: List[Tuple[int, str, float]] = field(default_factory=list)
    source_outside: int = 0

    def to_dict(self) -> dict:
        return {
            "lines": self.lines,
            "lines_out": self.lines_out,
            "moves": self.moves,
            "moves_compensated": self.moves_compensated,
            "untouched_unknown_position": self.untouched_unknown,
            "malformed": self.malformed,
            "malformed_examples": [list(x) for x in self.malformed_examples],
            "arcs_linearised": self.arcs_linearised,
            "arc_segments": self.arc_segments,
            "backlash_takeup_moves": self.takeup_moves,
            "max_correction_um": {a: round(v, 3) for a, v in self.max_correction_um.items()},
            "limit_hits": self.limit_hits,
            "limit_examples": [list(x) for x in self.limit_examples],
            "source_outside_limits": self.source_outside,
        }


class _EDist:
    """Splits one E word over sub-segments by path length, keeping the total exact."""

    __slots__ = ("word", "relative", "e0", "total_len", "decimals", "scale", "units",
                 "units_done")

    def __init__(self, word: Optional[Word], relative: bool, e0: Optional[float],
                 total_len: float):
        self.word = word
        self.relative = relative
        self.e0 = e0
        self.total_len = total_len
        if word is not None:
            self.decimals = max(decimals_of(word.text), 5)
            self.scale = 10 ** self.decimals
            if relative:
                self.units = round(word.value * self.scale)
                self.units_done = 0

    def take(self, s_end: float, last: bool) -> Optional[str]:
        w = self.word
        if w is None:
            return None
        if last:
            if not self.relative or self.units_done == 0:
                return w.text  # the whole E word in one piece: exactly as written
            return "E" + fmt((self.units - self.units_done) / self.scale, self.decimals)
        f = s_end / self.total_len if self.total_len > 0 else 1.0
        if self.relative:
            upto = round(self.units * f)
            part = upto - self.units_done
            self.units_done = upto
            return "E" + fmt(part / self.scale, self.decimals)
        return "E" + fmt(self.e0 + (w.value - self.e0) * f, self.decimals)


def _um_function(table) -> Callable[[float], float]:
    """``table.um_at`` (um at a carriage position, mm), specialised for the common tables:
    the same arithmetic, without the generic table walk (the fast paths call it per point)."""
    pts = table.points
    if table.is_constant:
        v = pts[0][1]
        return lambda q: v
    if len(pts) == 2:
        (p0, v0), (p1, v1) = pts

        def two_points(q: float) -> float:
            if q <= p0:
                return v0
            if q >= p1:
                return v1
            return (v1 - v0) / (p1 - p0) * (q - p0) + v0
        return two_points
    return table.um_at


def _lerp(a, b, f):
    return tuple(None if a[k] is None or b[k] is None else a[k] + (b[k] - a[k]) * f
                 for k in range(3))


class Compensator:
    """Streaming G-code compensator (see the module docstring for frames and conventions).

    ``process(line)`` takes one line without its line ending and returns either the very same
    string object (unchanged) or a list of replacement lines (possibly one).
    """

    def __init__(self, params: Params, options: Optional[Options] = None):
        self.params = params
        self.options = options or Options()
        self.model = KinematicModel(params)
        self.backlash = BacklashTracker(params, self.options.deadband_mm)
        self.servo_s = (
            [params.servo_lag_ms[a] * 1e-3 for a in AXES] if params.has_servo_precomp else None
        )
        self.passthrough = changes_nothing(params)
        self.pure_translation = (
            self.model.is_translation and not self.backlash.any_active and not self.servo_s
        )
        inv_coupling = self._inverse_coupling()
        # needs[k]: axes whose position the command for axis k depends on (incl. k).
        self.needs = tuple(
            frozenset({k} | {j for j in range(3) if inv_coupling[k][j]}) for k in range(3)
        )
        # moved_by[j]: command axes that change when axis j moves (incl. j).
        self.moved_by = tuple(
            frozenset({j} | {k for k in range(3) if inv_coupling[k][j]}) for j in range(3)
        )
        self.report = Report()
        self.lineno = 0
        # The per-line fast path covers plain absolute G0/G1 lines of affine models without
        # smoothing or servo lead; everything else takes the general path. Tests prove that
        # both give the same output (set fast_lines = False to force the general path).
        self.fast_lines = (not self.passthrough and self.model.is_affine
                           and self.backlash.smoothing == 0 and self.servo_s is None)
        # policy "error": lines are processed so that a refused one changes nothing
        self._guarded = self.options.policy == "error" and self.options.limits is not None
        self._fmt = "%." + str(self.options.decimals) + "f"
        self._fmt_in = "%." + str(self.options.decimals + 2) + "f"
        self._half = self.backlash.half
        self._Ai = self.model._Ainv_rows
        self._b = self.model._b_t
        self._affine = tuple(v for row in self._Ai for v in row) + tuple(self._b)
        self._bl_axes = tuple(k for k in range(3) if self.backlash.active[k])
        self._um_at = tuple(_um_function(self.backlash.tables[k]) if self.backlash.active[k]
                            else None for k in range(3))
        # the fast path compiled, where it was built (kernel.py); None: _fast_line
        self._kernel = _kernel.for_compensator(self)
        self.reset()

    def _inverse_coupling(self):
        m = self.model
        if m.is_affine:
            Ai = m.A_inv
            return [[k != j and Ai[k, j] != 0.0 for j in range(3)] for k in range(3)]
        return [[m.coupling[k][j] or m.coupling[j][k] for j in range(3)] for k in range(3)]

    # -- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the power-on state: positions unknown, G90, G21, M82, G17."""
        self.m: List[Optional[float]] = [None, None, None]
        self.fw: List[Optional[float]] = [None, None, None]
        self.fw_text: List[Optional[str]] = [None, None, None]
        self.w = [0.0, 0.0, 0.0]
        self.g = [0.0, 0.0, 0.0]
        self.frame_lost = [False, False, False]  # G92 on an unknown axis (module doc)
        self.absolute = True
        self.e_absolute_mode: Optional[bool] = None  # M82/M83 override, None = follow G90/91
        self.inches = False
        self.plane = 17
        self.ij_absolute = False
        self.e_pos: Optional[float] = None
        self.feed: Optional[float] = None  # mm/min
        self.tool: Optional[int] = None
        self.backlash.reset()
        self._qm = None
        self._lim_hit = [True, True, True]

    def adopt_state(self, other: "Compensator") -> None:
        """Continue from ``other``'s modal state and positions (a parameter change in the
        middle of a stream). Desired positions do not depend on the model and the firmware
        coordinates are what the firmware holds, so the new model simply applies from the
        next move on; backlash directions carry over for axes active in both."""
        self.m = list(other.m)
        self.fw = list(other.fw)
        self.fw_text = list(other.fw_text)
        self.w = list(other.w)
        self.g = list(other.g)
        self.frame_lost = list(other.frame_lost)
        self.absolute = other.absolute
        self.e_absolute_mode = other.e_absolute_mode
        self.inches = other.inches
        self.plane = other.plane
        self.ij_absolute = other.ij_absolute
        self.e_pos = other.e_pos
        self.feed = other.feed
        self.tool = other.tool
        self.lineno = other.lineno
        for k in range(3):
            if self.backlash.active[k] and other.backlash.active[k]:
                # the anchor is a geometric command: the same frame under either model
                self.backlash.dir[k] = other.backlash.dir[k]
                self.backlash.anchor[k] = other.backlash.anchor[k]
        self._qm = None
        self._lim_hit = [True, True, True]

    def invalidate(self, axes: Sequence[int] = (0, 1, 2)) -> None:
        """Forget the position of ``axes`` (their next move must re-establish it)."""
        for k in axes:
            self.m[k] = None
            self.fw[k] = None
            self.fw_text[k] = None
        self.backlash.reset(axes)

    @property
    def known(self) -> Tuple[bool, bool, bool]:
        return tuple(v is not None for v in self.m)

    @property
    def e_relative(self) -> bool:
        if self.e_absolute_mode is not None:
            return not self.e_absolute_mode
        return not self.absolute if self.options.g90_influences_extruder else False

    # -- entry point ---------------------------------------------------------------------
    def process(self, line: str) -> Union[str, List[str]]:
        if self._guarded:
            return self._process_guarded(line)
        kernel = self._kernel
        if kernel is not None and self.fast_lines:
            out = kernel.line(self, line)  # (it checks what the condition below checks)
            if out is not None:
                return out
        elif self.fast_lines and line[:3] in _FAST_PREFIXES and self.absolute and \
                None not in self.m:
            out = self._fast_line(line)
            if out is not None:
                return out
        self._qm = None
        self._lim_hit = [True, True, True]
        self.lineno += 1
        rep = self.report
        rep.lines += 1
        stripped = line.lstrip()
        if not stripped or stripped[0] not in "GgMmTtNn":
            rep.lines_out += 1
            return line
        cmd = parse_command(line)
        if cmd is None:
            rep.lines_out += 1
            return line
        out = self._dispatch(cmd, line)
        if out is line:
            rep.lines_out += 1
            return line
        rep.lines_out += len(out)
        indent = line[: len(line) - len(stripped)]
        if indent:
            out = [indent + o for o in out]
        return out

    _STATE = ("m", "fw", "fw_text", "w", "g", "e_pos", "feed", "_qm", "_lim_hit")
    _BACKLASH_STATE = ("dir", "anchor", "ramp_from", "ramp_done", "ramping")

    def _process_guarded(self, line: str) -> Union[str, List[str]]:
        """``process`` for the limits policy ``error``: a line refused with LimitError leaves
        the state as it was before the line, so a stream that does not send it can go on
        from there (the print resumed after the pause) with every position still known. A
        caller that sends it as written anyway must forget the positions (see queue)."""
        bl = self.backlash
        saved = [list(v) if isinstance(v, list) else v
                 for v in (getattr(self, a) for a in self._STATE)]
        saved_bl = [list(getattr(bl, a)) for a in self._BACKLASH_STATE]
        self._guarded = False
        try:
            return self.process(line)
        except LimitError:
            for a, v in zip(self._STATE, saved):
                setattr(self, a, v)
            for a, v in zip(self._BACKLASH_STATE, saved_bl):
                setattr(bl, a, v)
            raise
        finally:
            self._guarded = True

    # -- per-line fast path (same semantics as _linear_move for the lines it accepts) -------
    def _fast_line(self, line: str):
        """Compensate a plain ``G0``/``G1`` line; None when the line needs the general path.

        Accepted: ``G0``/``G1``, one space before each word, X/Y/Z words (in that order; an F
        may come first) and then E/F words, no comment, no duplicates; absolute mode with
        every axis known. The arithmetic is written out in the same order as the general
        path (inverse, backlash offset, limits, formatting) so the text is identical. An axis
        whose command did not move since the previous fast-path point is not reformatted
        (its text cannot have changed); the general path clears that cache on every line.
        """
        if len(line) > _FAST_MAX_LEN:
            return None
        shape = _SHAPES.get(line.encode("utf-8", "surrogatepass").translate(None, _NUMBER_BYTES))
        if shape is None:
            return None
        ix, iy, iz, ie, i_f, given, after_xyz, f_first = shape
        parts = line.split(" ")
        m = self.m
        try:  # every number first: a malformed one leaves the line to the general path
            vx = float(parts[ix][1:]) if ix else None
            vy = float(parts[iy][1:]) if iy else None
            vz = float(parts[iz][1:]) if iz else None
            ve = float(parts[ie][1:]) if ie else None
            vf = float(parts[i_f][1:]) if i_f else None
        except ValueError:
            return None
        u = MM_PER_INCH if self.inches else 1.0
        if vf is not None:
            self.feed = vf * u
        if ve is not None:
            # absolute mode here: E is relative only under M83
            self.e_pos = None if self.e_absolute_mode is False else ve
        self.lineno += 1
        rep = self.report
        rep.lines += 1
        rep.moves += 1
        if after_xyz == 1 + f_first:  # no X/Y/Z word
            rep.lines_out += 1
            return line
        code = parts[0]
        # the E/F words after X/Y/Z, as written (the first " E" or " F" starts them: the
        # X/Y/Z numbers before hold no letters)
        if ie:
            tail = line[line.index(" E", 3):]
        elif i_f and not f_first:
            tail = line[line.index(" F", 3):]
        else:
            tail = ""
        if f_first:
            tail = " " + parts[1] + tail
        w = self.w
        px = vx * u - w[0] if ix else m[0]
        py = vy * u - w[1] if iy else m[1]
        pz = vz * u - w[2] if iz else m[2]
        a00, a01, a02, a10, a11, a12, a20, a21, a22, b0, b1, b2 = self._affine
        x, y, z = px - b0, py - b1, pz - b2
        q1 = (a00 * x + a01 * y + a02 * z, a10 * x + a11 * y + a12 * z,
              a20 * x + a21 * y + a22 * z)
        q0 = self._qm
        if q0 is None:
            x, y, z = m[0] - b0, m[1] - b1, m[2] - b2
            q0 = (a00 * x + a01 * y + a02 * z, a10 * x + a11 * y + a12 * z,
                  a20 * x + a21 * y + a22 * z)
        redo = self._lim_hit[:]  # axes that must be re-evaluated even if unmoved
        out = None
        if self._bl_axes:
            bl = self.backlash
            dirs = bl.dir
            anchor = bl.anchor
            db = bl.deadband
            rev = False
            for k in self._bl_axes:
                # BacklashTracker.turn, inlined (the hook's hot path)
                q = q1[k]
                d = dirs[k]
                a = anchor[k]
                if d > 0:
                    if q >= a:
                        anchor[k] = q
                        continue
                    if q >= a - db:
                        continue
                    d = -1
                elif d < 0:
                    if q <= a:
                        anchor[k] = q
                        continue
                    if q <= a + db:
                        continue
                    d = 1
                else:
                    if a is None:
                        a = anchor[k] = q0[k]
                    if q > a + db:
                        d = 1
                    elif q < a - db:
                        d = -1
                    else:
                        continue
                dirs[k] = d
                anchor[k] = q
                rev = redo[k] = True
            if rev:
                # only reversed axes (and axes at a limit) can change their text here
                take = self._fast_point("G1", m, q0, (False, False, False), q0, redo)
                if take is not None:
                    out = [take]
                    rep.takeup_moves += 1
        p1 = (px, py, pz)
        text = self._fast_point(code, p1, q1, given, q0, redo)
        self.m = [px, py, pz]
        self._qm = q1
        if tail:
            text += tail
        rep.moves_compensated += 1
        if out is None:
            rep.lines_out += 1
            return [text]
        out.append(text)
        rep.lines_out += 2
        return out

    def _arc_points_fast(self, start, points, given, e_word, tail, comment) -> List[str]:
        """The chords of a linearised arc, exactly as _path writes them, on the fast path's
        arithmetic (absolute mode, affine model, no smoothing or servo lead)."""
        out: List[str] = []
        rep = self.report
        bl = self.backlash
        inv = self.model.inverse
        prev = start
        lengths = []
        for p in points:
            lengths.append(math.sqrt(sum((p[k] - prev[k]) ** 2 for k in range(3))))
            prev = p
        edist = _EDist(e_word, self.e_relative, self.e_pos, sum(lengths))
        p0 = tuple(start)
        q0 = inv(p0)
        s_done = 0.0
        last = len(points) - 1
        no_axes = (False, False, False)
        given = tuple(k in given for k in range(3))
        for idx, p1 in enumerate(points):
            q1 = inv(p1)
            redo = self._lim_hit[:]
            if self._bl_axes:
                rev = False
                for k in self._bl_axes:
                    new = bl.turn(k, q0[k], q1[k])
                    if new:
                        bl.dir[k] = new
                        bl.anchor[k] = q1[k]
                        rev = redo[k] = True
                if rev:
                    take = self._fast_point("G1", p0, q0, no_axes, q0, redo)
                    if take is not None:
                        out.append(take)
                        rep.takeup_moves += 1
            s_done += lengths[idx]
            if e_word is not None:
                e_text = edist.take(s_done, idx == last)
            if idx == 0:
                words = [e_text if w is e_word else w.text for w in tail]
            else:
                words = [e_text] if e_word is not None else []
            text = self._fast_point("G1", p1, q1, given if idx == last else no_axes, q0, redo)
            line = text if text is not None else "G1"
            if words:
                line += " " + " ".join(words)
            if idx == 0 and comment:
                line += " " + comment
            out.append(line)
            self.m = [p1[0], p1[1], p1[2]]
            p0, q0 = p1, q1
        self._qm = None
        return out

    def _fast_point(self, code: str, p, q, given, q_prev=None, redo=None) -> Optional[str]:
        """The text of one output point exactly as _emit writes it (None: nothing to write).

        With ``q_prev``, an axis that is not given, whose command equals ``q_prev`` and that
        is not in ``redo`` keeps its text and is skipped.
        """
        rep = self.report
        lim = self.options.limits
        u = MM_PER_INCH if self.inches else 1.0
        fmt_ = self._fmt_in if self.inches else self._fmt
        fw_text = self.fw_text
        fwv = self.fw
        g = self.g
        lim_hit = self._lim_hit
        dirs = self.backlash.dir
        um_at = self._um_at
        half = self._half
        max_corr = rep.max_correction_um
        parts = [code]
        for k in (0, 1, 2):
            c = q[k]
            if q_prev is not None and not given[k] and c == q_prev[k] and not redo[k]:
                continue
            d = dirs[k]
            if d:
                um = um_at[k]
                if um is not None:
                    c += d * half * um(c)
            if lim is not None:
                before = rep.limit_hits
                c = self._limit(k, p[k], c)
                lim_hit[k] = rep.limit_hits != before
            else:
                lim_hit[k] = False
            corr = abs(c - p[k]) * 1000.0
            if corr > max_corr[AXES[k]]:
                max_corr[AXES[k]] = corr
            text = fmt_ % ((c + g[k]) / u)
            if text[0] == "-" and not text.strip("-0."):
                text = text[1:]
            old = fw_text[k]
            if text == old:
                # fw_text set means fw == float(fw_text) * u already: nothing to store
                if given[k]:
                    parts.append(AXIS_LETTERS[k] + text)
                continue
            if given[k] or old is not None or text != fmt(
                    fwv[k] / u, self.options.decimals + (2 if self.inches else 0)):
                parts.append(AXIS_LETTERS[k] + text)
            fwv[k] = float(text) * u
            fw_text[k] = text
        if len(parts) == 1:
            return None
        return " ".join(parts)

    def _malformed(self, line: str) -> str:
        rep = self.report
        rep.malformed += 1
        if len(rep.malformed_examples) < 20:
            rep.malformed_examples.append((self.lineno, line[:80]))
        return line

    def _dispatch(self, cmd, line: str):
        kind, num, sub = cmd.kind, cmd.number, cmd.sub
        if kind == "G":
            if num <= 3 and sub is None:
                self.report.moves += 1
                words = parse_words(cmd.body)
                if words is None:
                    return self._malformed(line)
                if num <= 1:
                    return self._linear_move(cmd, words, line)
                return self._arc_move(cmd, words, line)
            if sub is None:
                if num == 90:
                    self.absolute = True
                    if self.options.g90_influences_extruder:
                        self.e_absolute_mode = None
                elif num == 91:
                    self.absolute = False
                    if self.options.g90_influences_extruder:
                        self.e_absolute_mode = None
                elif num in (20, 21):
                    self.inches = num == 20
                    self.fw_text = [None, None, None]
                elif num in (17, 18, 19):
                    self.plane = num
                elif num == 92:
                    return self._set_position(cmd, line)
                elif num == 28:
                    return self._home(cmd, line)
                elif num in INVALIDATING_G:
                    self.invalidate()
            else:
                if num == 90 and sub == 1:
                    self.ij_absolute = True
                elif num == 91 and sub == 1:
                    self.ij_absolute = False
                elif num == 92 and sub == 1:
                    self._reset_offsets()
                elif num in INVALIDATING_G:
                    self.invalidate()
            return line
        if kind == "M":
            if num == 82 and sub is None:
                self.e_absolute_mode = True
            elif num == 83 and sub is None:
                self.e_absolute_mode = False
            elif num in INVALIDATING_M:
                self.invalidate()
            return line
        # T<n>: tool change; hotend offsets may shift the logical frame, so forget positions.
        if num != self.tool:
            self.tool = num
            self.invalidate()
        return line

    # -- non-motion state ----------------------------------------------------------------
    @property
    def unit(self) -> float:
        return MM_PER_INCH if self.inches else 1.0

    def _set_position(self, cmd, line: str) -> str:
        words = parse_words(cmd.body)
        if words is None:
            return self._malformed(line)
        u = self.unit
        given = {w.letter: w.value for w in words}
        if not any(k in given for k in ("X", "Y", "Z", "E")):
            given = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        for k, letter in enumerate(AXIS_LETTERS):
            if letter not in given:
                continue
            v = given[letter] * u
            if self.m[k] is None:
                # where the axis is in the machine frame is not known, so neither is the
                # new offset between the firmware frame and the machine frame
                self.frame_lost[k] = True
                self.fw[k] = None
                self.fw_text[k] = None
                self.backlash.reset((k,))
                continue
            c = self.fw[k] - self.g[k]
            self.w[k] = v - self.m[k]
            self.g[k] = v - c
            self.fw[k] = v
            self.fw_text[k] = None
        if "E" in given:
            self.e_pos = given["E"]
        return line

    def _reset_offsets(self) -> None:
        # G92.1 drops the offsets; the head does not move, so the desired machine position m
        # stays where it is (adding w to it made the next move drive the axes the program
        # did not mention to m + w). Only the firmware coordinate loses the firmware offset.
        for k in range(3):
            if self.m[k] is not None:
                self.fw[k] -= self.g[k]
                self.fw_text[k] = None
            self.w[k] = 0.0
            self.g[k] = 0.0
            self.frame_lost[k] = False  # the firmware frame is the native one again

    def _home(self, cmd, line: str) -> str:
        words = parse_words(cmd.body, allow_bare=True)
        letters = {w.letter for w in words} if words is not None else set()
        axes = [k for k, a in enumerate(AXIS_LETTERS) if a in letters] or [0, 1, 2]
        home = self.options.home_mm
        for k in axes:
            self.m[k] = float(home[k])
            self.fw[k] = float(home[k])
            self.fw_text[k] = None
            self.w[k] = 0.0
            self.g[k] = 0.0
            self.frame_lost[k] = False
            # the drive is at the home command, which under skew is not inverse(home): the
            # first move's reversal is judged from there
            self.backlash.place(k, float(home[k]))
        return line

    # -- moves ---------------------------------------------------------------------------
    def _targets(self, words: Sequence[Word]):
        """(given axes, desired machine target with None for unknown) of a move's words."""
        u = self.unit
        target = list(self.m)
        given = []
        for w in words:
            k = "XYZ".find(w.letter)
            if k < 0:
                continue
            given.append(k)
            if self.frame_lost[k]:
                continue  # target stays unknown (None) until G28
            if self.absolute:
                target[k] = w.value * u - self.w[k]
            elif self.m[k] is not None:
                target[k] = self.m[k] + w.value * u
        return given, target

    def _needed(self, given: Sequence[int]) -> set:
        need = set(given)
        for j in given:
            for k in self.moved_by[j]:
                need |= self.needs[k]
        return need

    def _linear_move(self, cmd, words: List[Word], line: str):
        given, target = self._targets(words)
        e_word = next((w for w in words if w.letter == "E"), None)
        f_word = next((w for w in words if w.letter == "F"), None)
        if f_word is not None:
            self.feed = f_word.value * self.unit
        if not given:
            self._track_e(e_word)
            return line
        need = self._needed(given)
        known_before = self.known
        if self.passthrough or any(target[k] is None for k in need) or (
            not self.absolute and any(self.m[k] is None for k in given)
        ):
            return self._untouched(given, target, words, known_before, line)
        start = list(self.m)
        tail = [w for w in words if w.letter not in "XYZ"]
        out = self._path(cmd.code_text, start, [tuple(target)], given, e_word, tail,
                         cmd.comment)
        self._track_e(e_word)
        self.report.moves_compensated += 1
        return out

    def _track_e(self, e_word: Optional[Word]) -> None:
        """Absolute E position for splitting absolute-E arcs. Relative extrusion is not
        summed (float sums of millions of moves mean little): the position becomes unknown
        until ``G92 E`` or an absolute E move defines it again."""
        if e_word is None:
            return
        self.e_pos = None if self.e_relative else e_word.value

    def _untouched(self, given, target, words, known_before, line: str, e_word=None):
        """Pass a move through as written and keep tracking where the head went."""
        self.report.untouched_unknown += 0 if self.passthrough else 1
        u = self.unit
        c_before = [None if v is None else v - self.g[k] for k, v in enumerate(self.fw)]
        new_m = list(self.m)
        for w in words:
            k = "XYZ".find(w.letter)
            if k < 0:
                continue
            if self.frame_lost[k]:
                continue
            if self.absolute:
                new_m[k] = w.value * u - self.w[k]
                self.fw[k] = w.value * u
            elif self.m[k] is not None:
                new_m[k] = self.m[k] + w.value * u
                self.fw[k] += w.value * u
            self.fw_text[k] = None
        if self.backlash.any_active:
            self.backlash.observe(c_before, [None if v is None else v - self.g[k]
                                             for k, v in enumerate(self.fw)])
            for k in given:
                if not known_before[k] and self.fw[k] is not None:
                    self.backlash.place(k, self.fw[k] - self.g[k])
        self.m = new_m
        e = next((w for w in words if w.letter == "E"), None)
        self._track_e(e)
        return line

    def _arc_move(self, cmd, words: List[Word], line: str):
        clockwise = cmd.number == 2
        plane = self.plane
        ia, ib, il, la, lb = arcs.PLANES[plane]
        wd = {w.letter: w for w in words}
        given, target = self._targets(words)
        e_word = wd.get("E")
        f_word = wd.get("F")
        if f_word is not None:
            self.feed = f_word.value * self.unit
        turns_w = wd.get("P")
        turns = int(turns_w.value) if turns_w is not None else 0
        plane_axes = {ia, ib} | set(given)
        need = self._needed(sorted(plane_axes))
        known_before = self.known
        # The linear axis is interpolated along the chords (helix), so it must be known too:
        # an XY arc from an unknown Z crashed in linearise (None - None).
        if self.passthrough or any(self.m[k] is None for k in need | plane_axes | {il}):
            return self._untouched(given, target, words, known_before, line)
        u = self.unit
        offs = (
            wd[la].value * u if la in wd else None,
            wd[lb].value * u if lb in wd else None,
        )
        radius = wd["R"].value * u if "R" in wd else None
        start = tuple(self.m)
        end = tuple(target)
        try:
            ca, cb = arcs.centre_from_words(start, end, plane, offs, radius, clockwise,
                                            self.ij_absolute)
            if self.ij_absolute:
                ca -= self.w[ia]
                cb -= self.w[ib]
            pts = arcs.linearise(start, end, plane, ca, cb, clockwise,
                                 self.options.chord_tol_mm, turns, self._extreme_angles(plane))
        except arcs.ArcError:
            self._malformed(line)
            return self._untouched(given, target, words, known_before, line)
        if self.pure_translation and not self.ij_absolute and turns == 0:
            out = self._path(cmd.code_text, list(start), [end], given, None,
                             [w for w in words if w.letter not in "XYZ"], cmd.comment)
            self.report.moves_compensated += 1
            self._track_e(e_word)
            return out
        if e_word is not None and not self.e_relative and self.e_pos is None:
            # Absolute extrusion from an unknown E: the split cannot be computed.
            return self._untouched(given, target, words, known_before, line)
        tail = [w for w in words if w.letter not in "XYZIJKRP"]
        if self.fast_lines and self.absolute:
            out = self._arc_points_fast(list(start), pts, given, e_word, tail, cmd.comment)
        else:
            out = self._path("G1", list(start), pts, given, e_word, tail, cmd.comment)
        self._track_e(e_word)
        self.report.arcs_linearised += 1
        self.report.arc_segments += len(pts)
        self.report.moves_compensated += 1
        return out

    def _extreme_angles(self, plane: int) -> Tuple[float, ...]:
        """Arc angles at which a carriage command reaches an extreme (reverses).

        For the command ``q = A_inv m`` on a circle in ``plane`` each command axis k is
        ``A_inv[k, a] r cos t + A_inv[k, b] r sin t + const``: extreme at
        ``atan2(A_inv[k, b], A_inv[k, a])`` (mod pi). Without errors these are the quadrants.
        """
        ia, ib, _, _, _ = arcs.PLANES[plane]
        Ai = self.model.A_inv
        return tuple(
            math.atan2(Ai[k, ib], Ai[k, ia]) for k in range(3) if Ai[k, ia] or Ai[k, ib]
        )

    # -- the core: a polyline of desired points -> output lines -------------------------
    def _path(self, code_text: str, start: List[Optional[float]], points, given, e_word,
              tail: List[Word], comment: str) -> List[str]:
        """Emit the polyline ``start -> points`` (desired machine positions, mm).

        ``tail`` are the line's words other than X/Y/Z in their original order; the first
        piece carries them all, later pieces only their share of ``e_word`` (which is split
        along the path). Handles backlash reversals (take-up moves or ramp splits), servo lead,
        limits and output formatting.
        """
        bl = self.backlash
        prev = start
        lengths: List[Optional[float]] = []
        for p in points:
            if any(prev[k] is None and p[k] is not None for k in range(3)):
                lengths.append(None)  # coming from an unknown position: length unknown
            else:
                lengths.append(math.sqrt(sum(
                    (p[k] - prev[k]) ** 2 for k in range(3) if p[k] is not None
                )))
            prev = p
        total_len = sum(lengths) if None not in lengths else 0.0
        edist = _EDist(e_word, self.e_relative, self.e_pos, total_len)
        out: List[str] = []
        first = True
        s_done = 0.0
        p0 = start
        q0 = self._carriage(p0)
        n_points = len(points)
        for idx, p1 in enumerate(points):
            seg_len = lengths[idx]
            q1 = self._carriage(p1)
            write_axes = set(given) if idx == n_points - 1 else set()
            if bl.any_active:
                if seg_len is None:
                    bl.reset([k for k in range(3) if q0[k] is None])
                # Reversals are decided on the carriage command: under skew an axis can be
                # driven back and forth although its desired coordinate does not change.
                rev = bl.detect_reversals(q0, q1, q0)
                if rev and bl.smoothing == 0:
                    takeup = self._emit("G1", p0, q0, set(), [], "", 0.0, None)
                    if takeup is not None:
                        out.append(takeup)
                        self.report.takeup_moves += 1
            # Sub-segment split points where smoothed take-ups finish.
            cuts = [1.0]
            # (An absolute E from an unknown E position cannot be split: the ramp then just
            # completes over the whole move, which still ends on the right point.)
            if bl.any_active and seg_len and not (
                e_word is not None and not self.e_relative and self.e_pos is None
            ):
                for k in range(3):
                    rem = bl.ramp_remaining(k)
                    if rem is not None and 1e-9 < rem < seg_len - 1e-9:
                        cuts.append(rem / seg_len)
                cuts = sorted(set(cuts))
            f_prev = 0.0
            velocity = None
            if self.servo_s is not None and seg_len and self.feed:
                velocity = tuple(
                    0.0 if p1[k] is None else (p1[k] - p0[k]) / seg_len * self.feed / 60.0
                    for k in range(3)
                )
            for f in cuts:
                if f < 1.0:
                    p = _lerp(p0, p1, f)
                    q = _lerp(q0, q1, f)
                else:
                    p, q = p1, q1
                sub_len = (f - f_prev) * seg_len if seg_len is not None else 0.0
                e_text = None
                if e_word is not None:
                    e_text = edist.take(s_done + sub_len, idx == n_points - 1 and f == 1.0)
                if first:
                    words = [e_text if w is e_word else w.text for w in tail]
                    first = False
                else:
                    words = [e_text] if e_text is not None else []
                out.append(self._emit(code_text, p, q, write_axes if f == 1.0 else (),
                                      words, comment, sub_len, velocity, keep_empty=True))
                comment = ""
                if bl.any_active:
                    bl.advance(sub_len)
                s_done += sub_len
                f_prev = f
            p0, q0 = p1, q1
        return out

    def _carriage(self, p) -> Tuple[Optional[float], Optional[float], Optional[float]]:
        """Geometric command q (mm) for desired p; None where q needs an unknown axis."""
        if None not in p:
            return self.model.inverse(p)
        q = self.model.inverse([v if v is not None else 0.0 for v in p])
        return tuple(
            None if any(p[j] is None for j in self.needs[k]) else q[k] for k in range(3)
        )

    def _limit(self, k: int, p: float, c: float) -> float:
        """Apply the limits policy to axis k's command ``c`` (mm) for desired ``p`` (mm)."""
        lo, hi = self.options.limits[2 * k], self.options.limits[2 * k + 1]
        rep = self.report
        if lo <= p <= hi:
            if c < lo or c > hi:
                rep.limit_hits += 1
                if len(rep.limit_examples) < 20:
                    rep.limit_examples.append((self.lineno, AXIS_LETTERS[k], round(c, 6)))
                if self.options.policy == "error":
                    raise LimitError(
                        f"compensated {AXIS_LETTERS[k]}={c:.4f} mm is outside the "
                        f"limits {lo:g}..{hi:g} mm", self.lineno)
                if self.options.policy == "clamp":
                    c = min(max(c, lo), hi)
        elif p != self.m[k]:
            rep.source_outside += 1
        return c

    def _emit(self, code_text: str, p, q, write_axes, words: List[str], comment: str,
              travel: float, velocity, keep_empty: bool = False) -> Optional[str]:
        """Format one output move to desired position ``p`` and update the tracked state.

        Returns None when nothing would be written and ``keep_empty`` is false (a take-up
        too small to show at the output resolution).
        """
        bl = self.backlash
        u = self.unit
        dec = self.options.decimals + (2 if self.inches else 0)
        lim = self.options.limits
        axes_text = []
        rep = self.report
        for k in range(3):
            if q[k] is None:
                continue
            c = q[k]
            if bl.any_active:
                c += bl.offset(k, q[k], travel)
            if velocity is not None:
                c += self.servo_s[k] * velocity[k]
            if lim is not None:
                c = self._limit(k, p[k], c)
            corr = abs(c - p[k]) * 1000.0
            if corr > rep.max_correction_um[AXES[k]]:
                rep.max_correction_um[AXES[k]] = corr
            fw = c + self.g[k]
            text = fmt(fw / u, dec)
            if self.absolute:
                old_text = self.fw_text[k]
                if old_text is None and self.fw[k] is not None:
                    old_text = fmt(self.fw[k] / u, dec)
                if k in write_axes or text != old_text:
                    axes_text.append(AXIS_LETTERS[k] + text)
                self.fw[k] = float(text) * u
                self.fw_text[k] = text
            else:
                old = self.fw[k]
                if old is None:  # cannot happen: relative moves need known axes
                    raise CompensationError("relative move from an unknown position",
                                            self.lineno)
                delta = fmt(float(text) - old / u, dec)
                if k in write_axes or delta.strip("0.") != "":
                    axes_text.append(AXIS_LETTERS[k] + delta)
                self.fw[k] = old + float(delta) * u
                self.fw_text[k] = None
        for k in range(3):
            if p[k] is not None:
                self.m[k] = p[k]
        if not axes_text and not words and not keep_empty:
            return None
        parts = [code_text] + axes_text + words
        out = " ".join(parts)
        if comment:
            out += " " + comment
        return out
