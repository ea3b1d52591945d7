"""Backlash state machine: per-axis travel direction and the take-up offset to command.

Physical model (the simulator's play, ``simulator/play.py``, is the same): an axis with
lost motion ``b`` (um) behaves like a play of width ``b``; while the drive moves in
+direction the carriage lags ``b/2`` behind it, while it moves in -direction the carriage is
``b/2`` ahead. ``b`` may depend on the axis position (the ballbar's per-side values), so the
lag is ``b(q)/2`` at the current position.

Compensation therefore commands ``offset = dir * fraction * b(q) / 2`` (mm) on top of the
geometric correction, where ``dir`` is the direction the axis is travelling (+1/-1; 0 when
unknown, e.g. at start or after homing). On a reversal ``dir`` flips and the offset changes by
``fraction * b(q)``: the take-up. It is applied either at once (the caller emits a take-up move
before the reversing move) or ramped linearly over the next ``smoothing_mm`` of path length.
A carriage command that retreats by more than ``deadband_mm`` from the farthest command
reached in the current direction (the *anchor*) is a reversal. The deadband is a hysteresis
around that anchor, not a per-move threshold, so steps below it can never add up to an untaken
reversal (per-move, a slow creep of tiny steps, e.g. an X command drifting with Z under XZ
skew, could). It is a twentieth of the drive's step (:func:`deadband_for`: 0.625 um at 80
steps/mm, the default when the printer's step size is not known): a retreat that small
mostly moves the drive by no step at all
(the firmware rounds positions to steps), and taking it up as a reversal costs a take-up, a
sliver to the extreme and a take-up back (issue 28: a BambuStudio helix gave three needless
lines for an X retreat of 7 nm). Left untaken, such a retreat leaves the carriage at most the
deadband from where it should be. Every reversal that G-code at 3 decimals can express (1 um)
stays above it and is taken up, since a drive that retreats by less than the play leaves the
carriage behind. With no direction yet (start, after homing) the anchor is where the drive
was last put (the home position after G28).
"""

from __future__ import annotations

from typing import List, Mapping, Optional, Sequence, Tuple

from .params import AXES, Params
from .state import BacklashState

DEFAULT_STEPS_PER_MM = 80.0  # a typical belt-driven X/Y (16 microsteps, 20-tooth GT2)
DEADBAND_STEPS = 0.05  # the deadband in full steps of the drive


def deadband_for(steps_per_mm: float) -> float:
    """The reversal deadband (mm) of a drive with ``steps_per_mm`` (steps per mm, > 0):
    :data:`DEADBAND_STEPS` of its step (0.625 um at 80, 0.5 um at 100 steps/mm)."""
    return DEADBAND_STEPS / steps_per_mm


def deadband_steps(steps: Mapping[str, float]) -> Optional[float]:
    """The one steps-per-mm value the deadband is derived from, given the drives' steps
    per mm by axis (``x``, ``y``, ``z``): the finer of X and Y (the smaller deadband);
    None when neither is given. Z is left out: its lead screw (400 steps/mm and more) would
    make the deadband a fifth of the X/Y one, and a Z retreat below the X/Y deadband is
    still under a quarter of a Z step."""
    planar = [float(v) for a, v in steps.items() if a in ("x", "y")]
    return max(planar) if planar else None


# Without the printer's step size: that of a typical belt-driven X/Y at 80 steps/mm, 0.625 um.
# A printer with finer drives (160 steps/mm at 32 microsteps) moves a step for a retreat of
# 0.625 um more often: give its steps/mm (Options.steps_per_mm) and the deadband follows.
DEFAULT_DEADBAND_MM = deadband_for(DEFAULT_STEPS_PER_MM)


def reversal(
    d: int, a: Optional[float], q: float, q_from: float, deadband: float
) -> Tuple[int, Optional[float]]:
    """The reversal rule, once for every Python path: an axis travelling in direction ``d``
    (+1/-1, 0 unknown) with anchor ``a`` (mm; None: unknown, the move's start ``q_from``
    is taken) is commanded to ``q`` (mm). Returns (the new direction if this is a reversal,
    else 0; the anchor after the point). On a reversal the anchor is ``q``."""
    if d > 0:
        if q >= a:
            return 0, q
        return (-1, q) if q < a - deadband else (0, a)
    if d < 0:
        if q <= a:
            return 0, q
        return (1, q) if q > a + deadband else (0, a)
    if a is None:
        a = q_from
    if q > a + deadband:
        return 1, q
    if q < a - deadband:
        return -1, q
    return 0, a


class BacklashTracker:
    """Take-up offsets (mm) for the three axes, from the backlash parameters and the
    direction state ``state`` (a :class:`~.state.BacklashState`, part of the stream state
    that the engines share; a fresh one if not given)."""

    def __init__(
        self,
        params: Params,
        state: Optional[BacklashState] = None,
        deadband_mm: float = DEFAULT_DEADBAND_MM,
    ):
        self.tables = [params.backlash[a] for a in AXES]
        self.half = params.backlash_fraction * 1e-3 / 2.0  # um -> mm, half on each side
        self.active = [
            params.backlash_fraction > 0 and not params.backlash[a].is_zero for a in AXES
        ]
        self.any_active = any(self.active)
        self.active_axes = tuple(k for k in range(3) if self.active[k])
        self.smoothing = params.backlash_smoothing_mm
        self.deadband = deadband_mm
        self.s = state if state is not None else BacklashState()

    # -- state -------------------------------------------------------------------------
    @property
    def dir(self) -> List[int]:
        """Per axis: +1/-1 the direction of travel, 0 unknown (see BacklashState)."""
        return self.s.dir

    @property
    def anchor(self) -> List[Optional[float]]:
        return self.s.anchor

    def reset(self, axes: Sequence[int] = (0, 1, 2)) -> None:
        """Forget the direction of ``axes`` (start, homing, position lost)."""
        for k in axes:
            self.s.forget(k)

    def target(self, k: int, q: float) -> float:
        """Settled offset (mm) of axis k at carriage position q for the current direction."""
        d = self.s.dir[k]
        if not self.active[k] or d == 0:
            return 0.0
        return d * self.half * self.tables[k].um_at(q)

    def offset(self, k: int, q: float, extra_travel: float = 0.0) -> float:
        """Offset (mm) to command for axis k at carriage position q, ``extra_travel`` mm of
        path into the current move (used while a smoothed take-up is ramping)."""
        tgt = self.target(k, q)
        s = self.s
        if not s.ramping[k]:
            return tgt
        f = (s.ramp_done[k] + extra_travel) / self.smoothing
        if f >= 1.0:
            return tgt
        return s.ramp_from[k] + (tgt - s.ramp_from[k]) * f

    def offsets(self, q: Sequence[Optional[float]], extra_travel: float = 0.0) -> List[float]:
        """:meth:`offset` of each axis (mm) at carriage positions ``q`` (mm), 0.0 for an
        axis without backlash or whose position is unknown (None)."""
        out = [0.0, 0.0, 0.0]
        ramping = self.s.ramping
        for k in self.active_axes:
            qk = q[k]
            if qk is not None:
                out[k] = self.offset(k, qk, extra_travel) if ramping[k] else self.target(k, qk)
        return out

    def ramp_remaining(self, k: int) -> Optional[float]:
        """Path length (mm) left until axis k's smoothed take-up is complete, or None."""
        s = self.s
        if not s.ramping[k]:
            return None
        return max(0.0, self.smoothing - s.ramp_done[k])

    # -- updates -----------------------------------------------------------------------
    def turn(self, k: int, q_from: float, q: float) -> int:
        """New direction (+1/-1) if axis k's carriage command reverses on its way to ``q``
        (mm), else 0 (see :func:`reversal`). Without a reversal the anchor follows the
        command; on a reversal the caller sets ``dir[k]`` and ``anchor[k] = q``."""
        s = self.s
        new, s.anchor[k] = reversal(s.dir[k], s.anchor[k], q, q_from, self.deadband)
        if new:  # (the caller decides what a reversal does; the anchor is its business)
            s.anchor[k] = q
        return new

    def detect_reversals(
        self, p0: Sequence[float], p1: Sequence[float], q0: Sequence[float], ramp: bool = True
    ) -> List[int]:
        """Axes whose carriage command reverses on the move p0 -> p1 (mm, geometric
        commands), see :meth:`turn`. With smoothing (and ``ramp``) a take-up starts ramping
        from the offset in force at the move start (carriage position ``q0``).
        """
        reversed_axes = []
        s = self.s
        for k in range(3):
            if not self.active[k]:
                continue
            a, b = p0[k], p1[k]
            if a is None or b is None:
                continue
            new = self.turn(k, a, b)
            if new:
                start_offset = self.offset(k, q0[k])
                s.dir[k] = new
                s.anchor[k] = b
                reversed_axes.append(k)
                s.ramping[k] = False
                if ramp and self.smoothing > 0:
                    s.ramping[k] = True
                    s.ramp_from[k] = start_offset
                    s.ramp_done[k] = 0.0
        return reversed_axes

    def place(self, k: int, c: float) -> None:
        """The drive of axis k was put at ``c`` (mm) by something other than a compensated
        move (homing, G92 defining an unknown axis): direction unknown, anchored there."""
        self.s.forget(k)
        self.s.anchor[k] = c

    def advance(self, travel: float) -> None:
        """Account ``travel`` mm of path length for ramping take-ups."""
        s = self.s
        for k in range(3):
            if s.ramping[k]:
                s.ramp_done[k] += travel
                if s.ramp_done[k] >= self.smoothing - 1e-12:
                    s.ramping[k] = False

    def observe(self, c0: Sequence[Optional[float]], c1: Sequence[Optional[float]]) -> None:
        """Track direction on a move passed through uncompensated (drive commands c0 -> c1,
        mm, no take-up offset on them; no ramping). The anchor is kept in the geometric frame
        of compensated moves: the drive position minus the offset of the direction. It is
        set to where the move ends (not the farthest point): such moves are rare and their
        start may itself be uncertain, so the hysteresis restarts there."""
        s = self.s
        for k in range(3):
            if not self.active[k] or c0[k] is None or c1[k] is None:
                continue
            new = self.turn(k, c0[k] - self.target(k, c0[k]), c1[k] - self.target(k, c1[k]))
            if new:
                s.dir[k] = new
                s.ramping[k] = False
            s.anchor[k] = c1[k] - self.target(k, c1[k])


def hysteresis(q: List[float], d: int, a: Optional[float], q_start: float, db: float):
    """:func:`reversal` along the commands ``q`` of one axis (mm) from direction ``d`` and
    anchor ``a``, without changing a tracker: (direction after each point, reversal at each
    point, last anchor). The file engine uses it where it cannot decide by steps."""
    dirs, revs = [], []
    for x in q:
        new, a = reversal(d, a, x, q_start, db)
        if new:
            d = new
        dirs.append(d)
        revs.append(new != 0)
    return dirs, revs, a
