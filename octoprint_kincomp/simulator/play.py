"""The physical backlash of a simulated printer: a play of width ``b(q)`` per axis (um, from
the backlash tables of the true errors). The model the compensator's take-ups assume
(``core/backlash.py``): a drive moving in +direction has its carriage ``b/2`` behind it."""

from __future__ import annotations

from typing import List, Optional, Sequence

from ..core.params import AXES, Params


class Play:
    """The physical backlash of a printer (simulator side): a play of width ``b(q)`` per axis.

    ``carriage(k, u)`` returns where the carriage of axis k is when its drive has been moved
    to ``u`` (mm): the carriage stays put until the drive has crossed the play, then follows it
    ``b(y)/2`` behind, ``b`` taken at the carriage position ``y`` (as the compensator does).
    After :meth:`reset` the carriage sits in the middle of the play, which is
    the state the compensator assumes after homing (direction unknown, offset 0).
    """

    def __init__(self, params: Params):
        self.tables = [params.backlash[a] for a in AXES]
        self.pos: List[Optional[float]] = [None, None, None]

    def reset(self, axes: Sequence[int] = (0, 1, 2)) -> None:
        for k in axes:
            self.pos[k] = None

    def carriage(self, k: int, u: float) -> float:
        y = self.pos[k]
        if y is None:
            y = u
        else:
            table = self.tables[k]
            lo = u - table.um_at(y) * 5e-4
            hi = u + table.um_at(y) * 5e-4
            if y < lo or y > hi:
                # The carriage is dragged along; the play width is that at the carriage
                # position, y = u -/+ b(y)/2 (solved by a few fixed-point steps).
                sign = 1.0 if y < lo else -1.0
                for _ in range(4):
                    y = u - sign * table.um_at(y) * 5e-4
        self.pos[k] = y
        return y
