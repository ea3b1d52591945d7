"""Test helpers: run the compensator line by line and replay its output on a simulated printer."""

from __future__ import annotations

import math
from typing import List, Sequence, Tuple

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.kinematics import KinematicModel
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Home, Move
from octoprint_kincomp.simulator.play import Play


def compensate_groups(params: Params, lines: Sequence[str], options: Options = None):
    """[(input line, [output lines])] using one Compensator."""
    comp = make_compensator(params, options)
    groups = []
    for line in lines:
        out = comp.process(line)
        groups.append((line, [line] if out is line else list(out)))
    return comp, groups


def desired_positions(lines: Sequence[str], **kw) -> List[Tuple[float, float, float]]:
    """Machine position after each input line on an ideal printer."""
    fw = FirmwareInterpreter(**kw)
    pos = []
    for line in lines:
        fw.execute(line)
        pos.append(tuple(fw.machine))
    return pos


class Printer:
    """A printer with true errors: firmware executor + play (backlash) + kinematic errors."""

    def __init__(self, truth: Params, **kw):
        self.fw = FirmwareInterpreter(**kw)
        self.model = KinematicModel(truth)
        self.play = Play(truth)

    def run_line(self, line: str):
        """Actual nozzle positions (mm) at the end of each commanded segment of ``line``."""
        out = []
        self.events = self.fw.execute(line)  # (what the line commanded, for the caller)
        for ev in self.events:
            if isinstance(ev, Home):
                self.play.reset(ev.axes)
            if isinstance(ev, Move):
                for k in range(3):
                    if self.play.pos[k] is None:
                        # A play not moved since homing sits in its middle where the drive
                        # starts (sampling only segment ends would put it at the first end,
                        # hiding the lag of a first move that needs no take-up line).
                        self.play.carriage(k, ev.start[k])
                y = [self.play.carriage(k, ev.end[k]) for k in range(3)]
                out.append(self.model.forward(y))
        return out

    def actual(self):
        y = [
            self.play.pos[k] if self.play.pos[k] is not None else self.fw.machine[k]
            for k in range(3)
        ]
        return self.model.forward(y)


def dist(a, b) -> float:
    return math.sqrt(sum((a[k] - b[k]) ** 2 for k in range(3)))


def dist_to_polyline(p, pts) -> float:
    """Shortest distance from p to the polyline through pts (mm)."""
    import numpy as np

    P = np.asarray(pts, dtype=float)
    a, b = P[:-1], P[1:]
    ab = b - a
    ap = np.asarray(p, dtype=float) - a
    L2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", ab, ap) / np.where(L2 == 0, 1, L2), 0.0, 1.0)
    closest = a + t[:, None] * ab
    return float(np.min(np.linalg.norm(closest - np.asarray(p), axis=1)))


def printed(truth: Params, groups) -> Printer:
    """A printer with the errors of ``truth`` after running every output line of
    ``groups`` ([(input line, [output lines])], as compensate_groups gives them)."""
    printer = Printer(truth)
    for _, outs in groups:
        for o in outs:
            printer.run_line(o)
    return printer


def zero_length_extrusions(groups, **kw) -> List[Tuple[str, str]]:
    """(input line, output line) for every output move of ``groups`` ([(input line, [output
    lines])]) that extrudes (or, of several lines, carries a feed alone) without moving,
    where the input move had length: a firmware extrudes a blob in place (issue 28)."""
    fw_in = FirmwareInterpreter(**kw)
    fw_out = FirmwareInterpreter(**kw)
    found = []
    for line, outs in groups:
        had_length = any(
            isinstance(ev, Move) and dist(ev.start, ev.end) > 0 for ev in fw_in.execute(line)
        )
        for o in outs:
            if had_length and still_extruding(o, fw_out.execute(o), len(outs)):
                found.append((line, o))
    return found


def still_extruding(out_line: str, events, n_out: int) -> bool:
    """Whether the output line ``out_line`` (one of ``n_out`` written for an input move of
    some length; ``events``: what it commanded) extrudes without moving, or is one of
    several lines and carries a feed alone."""
    moves = [ev for ev in events if isinstance(ev, Move)]
    if not moves or any(dist(ev.start, ev.end) != 0 for ev in moves):
        return False
    words = out_line.split(";")[0].split()[1:]
    feed_alone = n_out > 1 and bool(words) and all(w[0] == "F" for w in words)
    return any(ev.e != 0 for ev in moves) or feed_alone
