"""A printer with known ("true") errors and a virtual ballbar. All output is SIMULATED.

The printer executes G-code with :class:`~..machine.FirmwareInterpreter` at constant speed
(each move at its feed, no acceleration: a stated simplification), then applies, per axis and
in this order: a first-order servo lag ``T`` (the drive follows the command, ``v*T`` behind at
steady speed), the play of the drive (backlash, possibly different along the axis), reversal
spikes (an extra lag decaying with the path travelled after each reversal), cyclic error, and
finally the HTM kinematic model of the true errors (squareness, scale, straightness ...).

The virtual ballbar has its pivot where the printer really puts the commanded centre (plus a
set-up offset) and samples ``reading = |nozzle - pivot| - L`` (mm, positive = longer) at
``sample_rate_hz`` with Gaussian noise. ``L`` is the nominal radius plus the bar's own length
error (unknown to an uncalibrated bar).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Dict, Iterable, Tuple

import numpy as np

from ..core.backlash import Play
from ..core.kinematics import KinematicModel
from ..core.machine import Dwell, FirmwareInterpreter, Move
from ..core.messages import Msg
from ..core.params import AXES, Params, ParamsError
from .formats import NativeTrace
from .program import END_MARKER, RUN_MARKER, ProgramError, spec_from_program

SIMULATED_LABEL = "SIMULATED data (KinComp printer + ballbar simulator), not a measurement"


@dataclass
class Truth:
    """The simulated printer's true errors (see the module docstring for the physics)."""

    errors: Params = field(default_factory=Params)
    servo_lag_ms: Dict[str, float] = field(default_factory=lambda: {a: 0.0 for a in AXES})
    cyclic: Dict[str, Tuple[float, float, float]] = field(default_factory=dict)
    spike_um: float = 0.0
    spike_decay_mm: float = 3.0
    noise_um: float = 0.0
    setup_offset_um: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    bar_length_error_um: float = 0.0
    sample_rate_hz: float = 500.0
    seed: int = 1

    @staticmethod
    def from_dict(d: dict) -> "Truth":
        if not isinstance(d, dict):
            raise ParamsError("", Msg("truth must be a JSON object"))
        if "errors" not in d:  # a plain params document: errors only
            return Truth(errors=Params.from_dict(d))
        allowed = {"errors", "servo_lag_ms", "cyclic", "reversal_spikes", "noise_um",
                   "setup_offset_um", "bar_length_error_um", "sample_rate_hz", "seed"}
        for k in d:
            if k not in allowed:
                raise ParamsError(k, Msg("unknown key (allowed: %(allowed)s)",
                                         allowed=", ".join(sorted(allowed))))
        t = Truth(errors=Params.from_dict(d["errors"]))
        t.servo_lag_ms = {a: float(d.get("servo_lag_ms", {}).get(a, 0.0)) for a in AXES}
        for a, c in d.get("cyclic", {}).items():
            t.cyclic[a] = (float(c["amplitude_um"]), float(c["pitch_mm"]),
                           float(c.get("phase_deg", 0.0)))
        sp = d.get("reversal_spikes", {})
        t.spike_um = float(sp.get("amplitude_um", 0.0))
        t.spike_decay_mm = float(sp.get("decay_mm", 3.0))
        t.noise_um = float(d.get("noise_um", 0.0))
        so = d.get("setup_offset_um", {})
        t.setup_offset_um = tuple(float(so.get(a, 0.0)) for a in AXES)
        t.bar_length_error_um = float(d.get("bar_length_error_um", 0.0))
        t.sample_rate_hz = float(d.get("sample_rate_hz", 500.0))
        t.seed = int(d.get("seed", 1))
        if not (10 <= t.sample_rate_hz <= 20000):
            raise ParamsError("sample_rate_hz", Msg("must be within 10..20000"))
        return t

    @staticmethod
    def load(path: str) -> "Truth":
        with open(path, encoding="utf-8") as f:
            try:
                return Truth.from_dict(json.load(f))
            except json.JSONDecodeError as exc:
                raise ParamsError("", Msg("not valid JSON (%(error)s at line %(line)s)",
                                          error=exc.msg, line=exc.lineno))


def paper_truth(**overrides) -> Truth:
    """The Ultimaker of Keaveney et al. 2018, Table 1, for a 100 mm circle about (110, 110).

    Squareness -3638.6 um/m, scale X -451.7 ppm, Y +287 ppm, backlash X 4.4/37.4 um at the
    +X/-X ends, Y 11.3/5.4 um at the +Y/-Y ends, servo mismatch 0.62 ms (X lags more).
    """
    t = Truth(
        errors=Params.from_dict({
            "squareness_um_per_m": {"xy": -3638.6},
            "scale_ppm": {"x": -451.7, "y": 287.0},
            "backlash": {"x": [{"at_mm": 10.0, "um": 37.4}, {"at_mm": 210.0, "um": 4.4}],
                         "y": [{"at_mm": 10.0, "um": 5.4}, {"at_mm": 210.0, "um": 11.3}]},
        }),
        servo_lag_ms={"x": 0.62, "y": 0.0, "z": 0.0},
    )
    for k, v in overrides.items():
        setattr(t, k, v)
    return t


class _Timeline:
    """Piecewise-linear commanded position u(t) of a program at constant speed per move."""

    def __init__(self, events: Iterable, start: Tuple[float, float, float]):
        times = [0.0]
        pts = [tuple(start)]
        lines = [0]
        t = 0.0
        for ev in events:
            if isinstance(ev, Move):
                length = math.dist(ev.start, ev.end)
                if length == 0.0:
                    continue
                if math.dist(ev.start, pts[-1]) > 1e-12:  # position jumped (homing, ...)
                    times.append(t)
                    pts.append(tuple(ev.start))
                    lines.append(ev.lineno)
                t += length / (ev.feed / 60.0)
                times.append(t)
                pts.append(tuple(ev.end))
                lines.append(ev.lineno)
            elif isinstance(ev, Dwell):
                t += ev.seconds
                times.append(t)
                pts.append(pts[-1])
                lines.append(ev.lineno)
        self.t = np.array(times)
        self.p = np.array(pts)
        self.line = np.array(lines)
        self.duration = t

    def at(self, ts: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(ts, self.t, self.p[:, k]) for k in range(3)], axis=1)

    def line_at(self, ts: np.ndarray) -> np.ndarray:
        idx = np.searchsorted(self.t, ts, side="right")
        return self.line[np.clip(idx, 0, len(self.line) - 1)]


def _servo(u: np.ndarray, dt: float, lag_s: float) -> np.ndarray:
    """First-order lag of a sampled, piecewise-linear input (exact between samples)."""
    if lag_s <= 0:
        return u.copy()
    a = math.exp(-dt / lag_s)
    y = np.empty_like(u)
    y[0] = u[0]
    d = np.diff(u) / dt  # slope of each interval
    yy = u[0]
    for n in range(len(u) - 1):
        tv = lag_s * d[n]
        yy = u[n + 1] - tv + (yy - u[n] + tv) * a
        y[n + 1] = yy
    return y


class Simulator:
    """Runs a program on the true printer and samples the virtual ballbar."""

    def __init__(self, truth: Truth):
        self.truth = truth
        self.model = KinematicModel(truth.errors)

    def actual_path(self, ts: np.ndarray, timeline: _Timeline) -> np.ndarray:
        """Actual nozzle positions (mm) at times ``ts``."""
        tr = self.truth
        dt = float(ts[1] - ts[0]) if len(ts) > 1 else 1.0
        u = timeline.at(ts)
        drive = np.stack(
            [_servo(u[:, k], dt, tr.servo_lag_ms.get(AXES[k], 0.0) * 1e-3) for k in range(3)],
            axis=1)
        play = Play(tr.errors)
        carriage = np.empty_like(drive)
        for k in range(3):
            y = [play.carriage(k, v) for v in drive[:, k].tolist()]
            carriage[:, k] = y
        if tr.spike_um:
            carriage += self._spikes(drive)
        for a, (amp, pitch, phase) in tr.cyclic.items():
            k = AXES.index(a)
            carriage[:, k] += amp * 1e-3 * np.sin(
                2 * math.pi * carriage[:, k] / pitch + math.radians(phase))
        return self.model.forward_many(carriage)

    def _spikes(self, drive: np.ndarray) -> np.ndarray:
        """Extra lag after each reversal of each axis, decaying with the path travelled since.

        ``spike_um`` is the amplitude, ``spike_decay_mm`` the path length (mm of tool travel)
        over which it falls to 1/e; the lag pushes the carriage back against its new direction.
        """
        tr = self.truth
        out = np.zeros_like(drive)
        amp = tr.spike_um * 1e-3
        step = np.linalg.norm(np.diff(drive, axis=0), axis=1)
        path = np.concatenate([[0.0], np.cumsum(step)])
        for k in range(3):
            d = np.diff(drive[:, k])
            direction = 0.0
            since = None
            for n in range(1, len(drive)):
                s = d[n - 1]
                if abs(s) > 1e-12:
                    s = 1.0 if s > 0 else -1.0
                    if s != direction:
                        if direction != 0:
                            since = path[n - 1]
                        direction = s
                if since is not None:
                    travel = path[n] - since
                    if travel > 20 * tr.spike_decay_mm:
                        since = None
                    else:
                        out[n, k] = -direction * amp * math.exp(-travel / tr.spike_decay_mm)
        return out

    def run_program(self, text: str, spec=None, prog_hash: str = "") -> NativeTrace:
        """Simulate a KinComp ballbar program; returns the native time-series trace.

        ``text`` may be the program as sent to a printer (comments stripped, line numbers,
        compensated): runs are found by their ``M117`` markers; then ``spec`` (the test that
        was generated) must be given.
        """
        if spec is None:
            spec, prog_hash = spec_from_program(text)
        lines = [_strip_number(ln) for ln in text.splitlines()]
        run_starts = []
        end_line = len(lines)
        for i, ln in enumerate(lines):
            body = ln.split(";", 1)[0].strip()
            if body.startswith("M117 " + RUN_MARKER):
                run_starts.append((i + 1, body.split()[-1].lower()))
            elif body.startswith("M117 " + END_MARKER):
                end_line = i + 1
        if not run_starts:
            raise ProgramError(Msg("no ballbar runs found (no 'M117 Ballbar run' markers)"))
        fw = FirmwareInterpreter(start=spec.centre)
        events = list(fw.run(lines))
        timeline = _Timeline(events, spec.centre)
        tr = self.truth
        fs = tr.sample_rate_hz
        ts = np.arange(0.0, timeline.duration + 1e-9, 1.0 / fs)
        actual = self.actual_path(ts, timeline)
        centre_actual = np.array(self.model.forward(spec.centre))
        pivot = centre_actual + np.array(tr.setup_offset_um) * 1e-3
        length = spec.radius_mm + tr.bar_length_error_um * 1e-3
        reading = np.linalg.norm(actual - pivot, axis=1) - length
        rng = np.random.default_rng(tr.seed)
        if tr.noise_um:
            reading = reading + rng.normal(0.0, tr.noise_um * 1e-3, size=reading.shape)
        line_of = timeline.line_at(ts)
        rows = []
        for idx, (ln, direction) in enumerate(run_starts):
            nxt = run_starts[idx + 1][0] if idx + 1 < len(run_starts) else end_line
            sel = (line_of > ln) & (line_of < nxt)
            for t, r in zip(ts[sel].tolist(), reading[sel].tolist()):
                rows.append((direction, t, r))
        meta = dict(spec.metadata())
        meta["sample_rate_hz"] = f"{fs:g}"
        meta["program_hash"] = prog_hash
        meta["source"] = SIMULATED_LABEL
        meta["simulated"] = "true"
        return NativeTrace(meta=meta, rows=rows)


def simulate_program(text: str, truth: Truth, spec=None, prog_hash: str = "") -> NativeTrace:
    return Simulator(truth).run_program(text, spec, prog_hash)


def _strip_number(line: str) -> str:
    """Drop an ``N<n> ... *<cs>`` wrapper (lines as they were sent to a printer)."""
    s = line.strip()
    if s[:1] in ("N", "n"):
        i = 1
        while i < len(s) and s[i].isdigit():
            i += 1
        s = s[i:].lstrip()
        star = s.rfind("*")
        if star >= 0 and s[star + 1:].strip().isdigit():
            s = s[:star].rstrip()
    return s
