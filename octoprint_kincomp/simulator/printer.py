"""A printer with known ("true") errors and a virtual ballbar. All output is SIMULATED.

The printer executes G-code like a firmware (:class:`~.sim.machine.FirmwareInterpreter`) and
moves the way its planner makes it move (``firmware/planner.py``: trapezoidal velocity with
acceleration, junction speeds, full stops at ``M400``/``G4``, per-axis feed caps; the former
constant-speed motion only when the truth asks for ``"motion": "constant_speed"``). Its trace
records the planner settings the program's header states (what a capture for that program
carries: the firmware and limits it was planned for), else the truth's ``motion``. The printer
moves with the truth's ``motion`` when the truth states one (a printer that may differ from
what the program was planned for: a fault the motion checks must see); a truth without one is
the printer whose firmware and limits the program's header records (a clean printer runs its
programs as planned: the plugin plans them from that printer's own M115/M503 answer), else
:class:`MotionSettings`' defaults. Then, per
axis and in this order: optional stepper quantisation (the commanded position rounded to whole
steps), a first-order servo lag ``T`` acting on the planned motion (the drive is ``v*T``
behind at steady speed), the play of the drive (backlash, possibly different along the axis),
reversal spikes (an extra lag decaying with the path travelled after each reversal), cyclic
error, and finally the HTM kinematic model of the true errors (squareness, scale,
straightness ...).

The virtual ballbar has its pivot where the printer really puts the commanded centre (plus a
set-up offset) and samples ``reading = |nozzle - pivot| - L`` (mm, positive = longer) at
``sample_rate_hz`` with Gaussian noise, plus an optional thermal drift of the bar (um/min,
positive = the bar grows, linear in time from the program's start). ``L`` is the nominal
radius plus the bar's own length error (unknown to an uncalibrated bar).

Faults for the trust checks (issue 23), all off by default: the printer's own limits that the
trace's metadata does not record (``hidden_max_feed_mm_min``, ``hidden_max_accel_mm_s2``: an
axis capped below what the program's plan assumes), a speed factor (``speed_factor_pct``, as
``M220 S``; an ``M220 S`` line in the program sets it from there on), glitches (``glitches``:
isolated samples off by ``amplitude_um``), and play in the motors of a CoreXY
(``corexy_motor_backlash_um``: motor A drives X+Y, motor B X-Y; the carriage lags half the play
of each motor along that motor's direction).

Faults of issue 34, all off by default too: the sensor's gain and sign (``sensor_gain``,
``sensor_sign``: -1 reports extension as negative; the truth document's ``sensor``), the CW and
CCW labels swapped in the trace (``swap_labels``: the rows keep their times and angles), and
the firmware's own compensation during the test (``firmware_compensation``: its commands, as
``M852 I0.00115 J-0.00078 K0.00048; M425 X0.028 Y0.02 Z0.01 F1``; Marlin's ``skew()`` moves the
target before planning, M425 adds an axis's play over the first block after it reverses),
which the trace records as the plugin would when ``record_firmware``. A plane key or radius
written wrongly into a trace is an edit of its metadata (the tests do that). A compensated
program's header record of how it was compensated (``; ballbar compensation_*``) goes into
the trace's metadata, as a logger that copies the header would.

Units: mm, s; lags in ms, play and noise in um, drift in um/min, steps per mm.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..calibration.ballbar.formats import AngleTrace, NativeTrace
from ..calibration.ballbar.program import (
    END_MARKER,
    RUN_MARKER,
    ProgramError,
    run_angles,
    spec_from_program,
)
from ..calibration.ballbar.timing import nominal_positions
from ..core.kinematics import KinematicModel
from ..core.marker import BALLBAR_RECORD_KEYS, MARKER_SCAN_LINES
from ..core.messages import Msg
from ..core.params import AXES, Params, ParamsError
from ..firmware.compensation import FirmwareCompensation
from ..firmware.planner import MotionSettings, Plan, plan_program, program_blocks_of
from .play import Play

SIMULATED_LABEL = "SIMULATED data (KinComp printer + ballbar simulator), not a measurement"
MOTION_KEYS = MotionSettings.KEYS + ("constant_speed",)  # (a simulator-only switch)


@dataclass
class Truth:
    """The simulated printer's true errors and motion (see the module docstring)."""

    errors: Params = field(default_factory=Params)
    servo_lag_ms: Dict[str, float] = field(default_factory=lambda: dict.fromkeys(AXES, 0.0))
    cyclic: Dict[str, Tuple[float, float, float]] = field(default_factory=dict)
    spike_um: float = 0.0
    spike_decay_mm: float = 3.0
    noise_um: float = 0.0
    setup_offset_um: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    bar_length_error_um: float = 0.0
    sample_rate_hz: float = 500.0
    seed: int = 1
    # None: the firmware and limits the program was planned for (its header), else the
    # defaults (see the module docstring)
    motion: Optional[MotionSettings] = None
    steps_per_mm: Dict[str, float] = field(default_factory=dict)  # empty: no quantisation
    bar_drift_um_per_min: float = 0.0
    speed_factor_pct: float = 100.0
    hidden_max_feed_mm_min: Dict[str, float] = field(default_factory=dict)
    hidden_max_accel_mm_s2: Dict[str, float] = field(default_factory=dict)
    glitches: Tuple[int, float] = (0, 0.0)  # (count, amplitude_um)
    corexy_motor_backlash_um: Dict[str, float] = field(default_factory=dict)  # "a", "b"
    corexy_motor_scale_ppm: Dict[str, float] = field(default_factory=dict)  # "a", "b"
    # issue 34: the sensor's gain and sign (-1: extension reported as negative), the CW/CCW
    # labels swapped in the trace, the firmware's own compensation during the test (its
    # commands, e.g. "M852 I0.00115; M425 X0.028 Y0.02 F1") and whether the trace records
    # it (as the plugin does)
    sensor_gain: float = 1.0
    sensor_sign: float = 1.0
    swap_labels: bool = False
    firmware_compensation: str = ""
    record_firmware: bool = False

    def motion_for(self, spec=None) -> MotionSettings:
        """The planner settings the printer runs ``spec``'s program with (hidden caps aside):
        the truth's ``motion``, else those the program was planned for, else the defaults."""
        if self.motion is not None:
            return self.motion
        stated = getattr(spec, "motion", None)
        return (MotionSettings.from_metadata(stated) if stated else None) or MotionSettings()

    def printer_motion(self, spec=None) -> MotionSettings:
        """The motion the printer really has: :meth:`motion_for` with the hidden caps."""
        m = self.motion_for(spec)
        if not (self.hidden_max_feed_mm_min or self.hidden_max_accel_mm_s2):
            return m
        feed = dict(m.max_feed_mm_min)
        for a, v in self.hidden_max_feed_mm_min.items():
            feed[a] = min(float(v), feed.get(a, math.inf))
        acc = dict(m.max_accel_mm_s2 or {})
        for a, v in self.hidden_max_accel_mm_s2.items():
            acc[a] = min(float(v), acc.get(a, math.inf))
        return m.with_(max_feed_mm_min=feed, max_accel_mm_s2=acc or None)

    @staticmethod
    def from_dict(d: dict) -> Truth:
        if not isinstance(d, dict):
            raise ParamsError("", Msg("truth must be a JSON object"))
        if "errors" not in d:  # a plain params document: errors only
            return Truth(errors=Params.from_dict(d))
        allowed = {
            "errors",
            "servo_lag_ms",
            "cyclic",
            "reversal_spikes",
            "noise_um",
            "setup_offset_um",
            "bar_length_error_um",
            "sample_rate_hz",
            "seed",
            "steps_per_mm",
            "bar_drift_um_per_min",
            "speed_factor_pct",
            "hidden_max_feed_mm_min",
            "hidden_max_accel_mm_s2",
            "glitches",
            "corexy_motor_backlash_um",
            "corexy_motor_scale_ppm",
            "sensor",
            "swap_labels",
            "firmware_compensation",
            "record_firmware",
        } | set(MOTION_KEYS)
        for k in d:
            if k not in allowed:
                raise ParamsError(
                    k, Msg("unknown key (allowed: %(allowed)s)", allowed=", ".join(sorted(allowed)))
                )
        t = Truth(errors=Params.from_dict(d["errors"]))
        t.servo_lag_ms = {a: float(d.get("servo_lag_ms", {}).get(a, 0.0)) for a in AXES}
        for a, c in d.get("cyclic", {}).items():
            t.cyclic[a] = (
                float(c["amplitude_um"]),
                float(c["pitch_mm"]),
                float(c.get("phase_deg", 0.0)),
            )
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
        stated = {k: d[k] for k in MOTION_KEYS if k in d}
        t.motion = MotionSettings.from_dict(stated) if stated else None
        for a, v in (d.get("steps_per_mm") or {}).items():
            if a not in AXES:
                raise ParamsError(f"steps_per_mm.{a}", Msg("unknown axis (allowed: x, y, z)"))
            v = float(v)
            if not (0.0 < v <= 1e6):
                raise ParamsError(f"steps_per_mm.{a}", Msg("must be within 0..1000000"))
            t.steps_per_mm[a] = v
        t.bar_drift_um_per_min = float(d.get("bar_drift_um_per_min", 0.0))
        if not (abs(t.bar_drift_um_per_min) <= 1000.0):
            raise ParamsError("bar_drift_um_per_min", Msg("must be within -1000..1000"))
        t.speed_factor_pct = float(d.get("speed_factor_pct", 100.0))
        if not (10.0 <= t.speed_factor_pct <= 999.0):
            raise ParamsError("speed_factor_pct", Msg("must be within 10..999"))
        for key in ("hidden_max_feed_mm_min", "hidden_max_accel_mm_s2"):
            for a, v in (d.get(key) or {}).items():
                if a not in AXES or not float(v) > 0:
                    raise ParamsError(f"{key}.{a}", Msg("an axis (x, y, z) and a positive number"))
                getattr(t, key)[a] = float(v)
        g = d.get("glitches") or {}
        t.glitches = (int(g.get("count", 0)), float(g.get("amplitude_um", 0.0)))
        for m, v in (d.get("corexy_motor_backlash_um") or {}).items():
            if m not in ("a", "b"):
                raise ParamsError(f"corexy_motor_backlash_um.{m}", Msg("a motor: a or b"))
            t.corexy_motor_backlash_um[m] = float(v)
        for m, v in (d.get("corexy_motor_scale_ppm") or {}).items():
            if m not in ("a", "b"):
                raise ParamsError(f"corexy_motor_scale_ppm.{m}", Msg("a motor: a or b"))
            t.corexy_motor_scale_ppm[m] = float(v)
        _sensor_faults(t, d)
        return t

    @staticmethod
    def load(path: str) -> Truth:
        with open(path, encoding="utf-8") as f:
            try:
                return Truth.from_dict(json.load(f))
            except json.JSONDecodeError as exc:
                raise ParamsError(
                    "",
                    Msg(
                        "not valid JSON (%(error)s at line %(line)s)",
                        error=exc.msg,
                        line=exc.lineno,
                    ),
                ) from None


def _sensor_faults(t: Truth, d: dict) -> None:
    """The issue-34 keys of a truth document: ``sensor`` {gain, sign}, ``swap_labels``,
    ``firmware_compensation`` (commands), ``record_firmware``."""
    sensor = d.get("sensor") or {}
    t.sensor_gain = float(sensor.get("gain", 1.0))
    t.sensor_sign = float(sensor.get("sign", 1.0))
    if not (0.5 <= t.sensor_gain <= 2.0) or t.sensor_sign not in (1.0, -1.0):
        raise ParamsError("sensor", Msg("gain within 0.5..2, sign 1 or -1"))
    t.swap_labels = bool(d.get("swap_labels", False))
    t.firmware_compensation = str(d.get("firmware_compensation") or "")
    t.record_firmware = bool(d.get("record_firmware", False))


def paper_truth(**overrides) -> Truth:
    """The Ultimaker of Keaveney et al. 2018, Table 1, for a 100 mm circle about (110, 110).

    Squareness -3638.6 um/m, scale X -451.7 ppm, Y +287 ppm, backlash X 4.4/37.4 um at the
    +X/-X ends, Y 11.3/5.4 um at the +Y/-Y ends, servo mismatch 0.62 ms (X lags more).
    """
    t = Truth(
        errors=Params.from_dict(
            {
                "squareness_um_per_m": {"xy": -3638.6},
                "scale_ppm": {"x": -451.7, "y": 287.0},
                "backlash": {
                    "x": [{"at_mm": 10.0, "um": 37.4}, {"at_mm": 210.0, "um": 4.4}],
                    "y": [{"at_mm": 10.0, "um": 5.4}, {"at_mm": 210.0, "um": 11.3}],
                },
            }
        ),
        servo_lag_ms={"x": 0.62, "y": 0.0, "z": 0.0},
    )
    for k, v in overrides.items():
        setattr(t, k, v)
    return t


def tuned_truth(**overrides) -> Truth:
    """A well-tuned printer: squareness 40 um/m, scale X +30, Y -20 ppm, backlash 3/2 um
    (X/Y), servo lag X 0.1 ms."""
    t = Truth(
        errors=Params.from_dict(
            {
                "squareness_um_per_m": {"xy": 40.0},
                "scale_ppm": {"x": 30.0, "y": -20.0},
                "backlash": {"x": 3.0, "y": 2.0},
            }
        ),
        servo_lag_ms={"x": 0.1, "y": 0.0, "z": 0.0},
    )
    for k, v in overrides.items():
        setattr(t, k, v)
    return t


def volume_truth(**overrides) -> Truth:
    """The paper's machine extended to the whole volume (issue 12): squareness xy -3638.6,
    xz +800, yz -500 um/m; scale X -451.7, Y +287, Z +150 ppm; backlash X 37.4/4.4 um at the
    -X/+X ends (x = 10/210 mm), Y 5.4/11.3 at -Y/+Y, Z 8 um; servo lag X 0.62 ms, Z 0.3 ms."""
    t = paper_truth()
    t.errors = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -3638.6, "xz": 800.0, "yz": -500.0},
            "scale_ppm": {"x": -451.7, "y": 287.0, "z": 150.0},
            "backlash": {
                "x": [{"at_mm": 10.0, "um": 37.4}, {"at_mm": 210.0, "um": 4.4}],
                "y": [{"at_mm": 10.0, "um": 5.4}, {"at_mm": 210.0, "um": 11.3}],
                "z": 8.0,
            },
        }
    )
    t.servo_lag_ms = {"x": 0.62, "y": 0.0, "z": 0.3}
    for k, v in overrides.items():
        setattr(t, k, v)
    return t


def _lagging(q: np.ndarray, play_mm: float) -> np.ndarray:
    """A position that follows ``q`` through a dead band of ``play_mm`` (starting centred)."""
    out = np.empty_like(q)
    c = float(q[0]) if len(q) else 0.0
    half = play_mm / 2
    for i, x in enumerate(q.tolist()):
        if x - c > half:
            c = x - half
        elif c - x > half:
            c = x + half
        out[i] = c
    return out


def _corexy_motors(
    drive: np.ndarray, play_um: Dict[str, float], scale_ppm: Dict[str, float]
) -> np.ndarray:
    """X and Y after CoreXY motors A (X+Y) and B (X-Y): each motor's belt scale (ppm, a
    belt stretched or tensioned differently: its travel is ``1 + s`` times the command) and
    play (um of the motor's travel)."""
    ma = (drive[:, 0] + drive[:, 1]) * (1 + scale_ppm.get("a", 0.0) * 1e-6)
    mb = (drive[:, 0] - drive[:, 1]) * (1 + scale_ppm.get("b", 0.0) * 1e-6)
    if play_um.get("a"):
        ma = _lagging(ma, play_um["a"] * 1e-3)
    if play_um.get("b"):
        mb = _lagging(mb, play_um["b"] * 1e-3)
    out = drive.copy()
    out[:, 0] = (ma + mb) / 2
    out[:, 1] = (ma - mb) / 2
    return out


def _speed_factors(lines: List[str], blocks, initial_pct: float) -> np.ndarray:
    """Per block the speed factor (fraction) in force: ``initial_pct``, then the last
    ``M220 S<pct>`` line before the block (a program may pin it)."""
    sets = []
    for i, ln in enumerate(lines, 1):
        body = ln.split(";", 1)[0].strip().upper()
        if body.startswith("M220"):
            for word in body.split()[1:]:
                if word.startswith("S"):
                    try:
                        sets.append((i, float(word[1:])))
                    except ValueError:
                        pass
    out = np.full(len(blocks.line), initial_pct / 100.0)
    for lineno, pct in sets:
        out[blocks.line > lineno] = pct / 100.0
    return out


def _servo(u: np.ndarray, dt: float, lag_s: float) -> np.ndarray:
    """First-order lag of a sampled input, exact for an input linear between samples.

    The error ``e = y - u`` obeys ``e[n+1] = a e[n] - (1 - a) T du[n]/dt`` with
    ``a = exp(-dt/T)``; it is summed as a convolution truncated where ``a^k < 1e-17``."""
    if lag_s <= 0 or len(u) < 2:
        return u.copy()
    a = math.exp(-dt / lag_s)
    b = -(1.0 - a) * lag_s * np.diff(u) / dt
    m = 1 if a <= 0 else int(math.ceil(math.log(1e-17) / math.log(a)))
    m = max(1, min(m, len(b)))
    e = np.convolve(b, a ** np.arange(m))[: len(b)]
    return u + np.concatenate([[0.0], e])


class Simulator:
    """Runs a program on the true printer and samples the virtual ballbar."""

    def __init__(self, truth: Truth):
        self.truth = truth
        self.model = KinematicModel(truth.errors)

    def actual_path(self, ts: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Actual nozzle positions (mm) at times ``ts`` for commanded positions ``u``."""
        tr = self.truth
        dt = float(ts[1] - ts[0]) if len(ts) > 1 else 1.0
        u = u.copy()
        for a, spm in tr.steps_per_mm.items():
            k = AXES.index(a)
            u[:, k] = np.round(u[:, k] * spm) / spm
        drive = np.stack(
            [_servo(u[:, k], dt, tr.servo_lag_ms.get(AXES[k], 0.0) * 1e-3) for k in range(3)],
            axis=1,
        )
        if tr.corexy_motor_backlash_um or tr.corexy_motor_scale_ppm:
            drive = _corexy_motors(drive, tr.corexy_motor_backlash_um, tr.corexy_motor_scale_ppm)
        play = Play(tr.errors)
        carriage = drive.copy()
        for k in range(3):
            if not tr.errors.backlash[AXES[k]].is_zero:
                carriage[:, k] = [play.carriage(k, v) for v in drive[:, k].tolist()]
        if tr.spike_um:
            carriage += self._spikes(drive)
        for a, (amp, pitch, phase) in tr.cyclic.items():
            k = AXES.index(a)
            carriage[:, k] += (
                amp * 1e-3 * np.sin(2 * math.pi * carriage[:, k] / pitch + math.radians(phase))
            )
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

    def _run(self, text: str, spec, prog_hash: str):
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
        tr = self.truth
        fw = FirmwareCompensation.from_text(tr.firmware_compensation)
        skew = _skew_matrix(fw.skew_um_per_m())
        blocks = program_blocks_of(lines, spec.centre)
        if skew is not None:  # Marlin's skew(): the target moved before planning
            inv = np.linalg.inv(skew)
            blocks.p0, blocks.p1 = blocks.p0 @ inv.T, blocks.p1 @ inv.T
            blocks.end = inv @ blocks.end
        factor = _speed_factors(lines, blocks, tr.speed_factor_pct)
        if np.any(factor != 1.0):
            blocks.feed = np.where(blocks.feed > 0, blocks.feed * factor, blocks.feed)
        plan = blocks.plan(tr.printer_motion(spec))
        fs = tr.sample_rate_hz
        ts = np.arange(0.0, plan.duration + 1e-9, 1.0 / fs)
        u, vel = plan.sample(ts)
        drive = u if not fw.backlash else u + _firmware_backlash(plan, ts, u, fw.backlash_um())
        actual = self.actual_path(ts, drive)
        centre = np.array(spec.centre) if skew is None else np.linalg.inv(skew) @ spec.centre
        centre_actual = np.array(self.model.forward(tuple(centre)))
        pivot = centre_actual + np.array(tr.setup_offset_um) * 1e-3
        length = spec.radius_mm + tr.bar_length_error_um * 1e-3
        reading = np.linalg.norm(actual - pivot, axis=1) - length
        reading = reading + tr.bar_drift_um_per_min * 1e-3 / 60.0 * ts
        reading = tr.sensor_sign * tr.sensor_gain * reading
        if skew is not None:  # the program's own coordinates (what the angle export shows)
            u = u @ skew.T
        rng = np.random.default_rng(tr.seed)
        if tr.noise_um:
            reading = reading + rng.normal(0.0, tr.noise_um * 1e-3, size=reading.shape)
        count, amp = tr.glitches
        if count and amp:
            # isolated wrong samples, spread over the middle of the program (both runs)
            at = np.linspace(0.15, 0.85, count) * len(reading)
            idx = (at + rng.integers(-50, 50, size=count)).astype(int)
            reading[idx] += amp * 1e-3 * np.where(np.arange(count) % 2 == 0, 1.0, -1.0)
        line_of = plan.line_at(ts)
        runs = []
        for idx, (ln, direction) in enumerate(run_starts):
            nxt = run_starts[idx + 1][0] if idx + 1 < len(run_starts) else end_line
            runs.append((direction, np.nonzero((line_of > ln) & (line_of < nxt))[0]))
        meta = dict(spec.metadata())
        meta.update(_compensation_record(lines))
        if tr.record_firmware:
            meta["firmware_compensation"] = fw.text()
        meta["sample_rate_hz"] = f"{fs:g}"
        meta["program_hash"] = prog_hash
        if getattr(spec, "params_hash", None):
            meta["params_hash"] = spec.params_hash
        if not getattr(spec, "motion", None):  # else the program's, as a capture carries it
            meta.update(tr.motion_for(spec).metadata())
        meta["source"] = SIMULATED_LABEL
        meta["simulated"] = "true"
        return spec, meta, plan, ts, u, vel, reading, runs

    def run_program(self, text: str, spec=None, prog_hash: str = "") -> NativeTrace:
        """Simulate a KinComp ballbar program; returns the native time-series trace.

        ``text`` may be the program as sent to a printer (comments stripped, line numbers,
        compensated): runs are found by their ``M117`` markers; then ``spec`` (the test that
        was generated) must be given.
        """
        _, meta, _, ts, _, _, reading, runs = self._run(text, spec, prog_hash)
        rows: List[Tuple[str, float, float]] = []
        for direction, sel in runs:
            label = self._label(direction)
            rows.extend(zip([label] * len(sel), ts[sel].tolist(), reading[sel].tolist()))
        return NativeTrace(meta=meta, rows=rows)

    def _label(self, direction: str) -> str:
        """The run's label in the trace (swapped when the truth says so)."""
        if not self.truth.swap_labels:
            return direction
        return {"cw": "ccw", "ccw": "cw"}[direction]

    def run_program_angle(
        self, text: str, spec=None, prog_hash: str = "", compensated_with: Optional[Params] = None
    ) -> AngleTrace:
        """The same run as an angle-domain trace: each sample on the circle (capture and
        overshoot arcs) at the nominal angle the program commanded at that instant (what
        ballbar software exports). A program that was compensated with ``compensated_with``
        is mapped back to the nominal circle."""
        spec, meta, plan, ts, u, vel, reading, runs = self._run(text, spec, prog_hash)
        rows: List[Tuple[str, float, float]] = []
        for direction, sel in runs:
            nominal = nominal_positions(plan, ts[sel], u[sel], compensated_with)
            theta, on_arc = arc_angles_of(nominal, spec, direction)
            rows.extend(
                zip(
                    [self._label(direction)] * int(on_arc.sum()),
                    theta[on_arc].tolist(),
                    (reading[sel][on_arc] * 1e3).tolist(),
                )
            )
        meta.pop("sample_rate_hz", None)
        return AngleTrace(meta=meta, rows=rows)


def arc_angles_of(
    nominal: np.ndarray, spec, direction: str, tol_mm: float = 0.003
) -> Tuple[np.ndarray, np.ndarray]:
    """Nominal angles (deg, continuous from the run's feed-in angle) of positions (n, 3) and
    whether each is on the circle (not on the radial feed-in/out)."""
    a, b = spec.axes
    da = nominal[:, a] - spec.centre[a]
    db = nominal[:, b] - spec.centre[b]
    theta = np.degrees(np.unwrap(np.arctan2(db, da)))
    if len(theta):
        a0 = run_angles(spec, direction)[0]
        theta = theta + 360.0 * round((a0 - theta[0]) / 360.0)
    on_arc = np.abs(np.hypot(da, db) - spec.radius_mm) < tol_mm
    return theta, on_arc


def simulate_program(text: str, truth: Truth, spec=None, prog_hash: str = "") -> NativeTrace:
    return Simulator(truth).run_program(text, spec, prog_hash)


def simulate_angle_trace(
    text: str,
    truth: Truth,
    spec=None,
    prog_hash: str = "",
    compensated_with: Optional[Params] = None,
) -> AngleTrace:
    return Simulator(truth).run_program_angle(text, spec, prog_hash, compensated_with)


def planned(text: str, truth: Truth, spec=None) -> Plan:
    """The planned motion of a program on the truth's printer (for tests and tools)."""
    if spec is None:
        spec, _ = spec_from_program(text)
    return plan_program(text, spec.centre, truth.motion_for(spec))


def _skew_matrix(skew: Optional[Dict[str, float]]) -> Optional[np.ndarray]:
    """``actual = S @ target`` of a skew in KinComp's keys (um/m); None for none."""
    if not skew or not any(skew.values()):
        return None
    xy, xz, yz = (skew.get(k, 0.0) * 1e-6 for k in ("xy", "xz", "yz"))
    return np.array([[1.0, xy, xz], [0.0, 1.0, yz], [0.0, 0.0, 1.0]])


def _firmware_backlash(plan: Plan, ts: np.ndarray, u: np.ndarray, um: Dict[str, float]):
    """Marlin's M425 (mm, n x 3): on each direction change of an axis its play (``um``) is
    added in the new direction, spread over the block in proportion to its progress."""
    n = len(plan.t0)
    c0 = np.zeros((n, 3))
    dc = np.zeros((n, 3))
    last = [0, 0, 0]
    cur = np.zeros(3)
    for k in range(n):
        c0[k] = cur
        if plan.L[k] <= 0:
            continue
        for ax in range(3):
            d = plan.u[k][ax]
            if abs(d) < 1e-12:
                continue
            sg = 1 if d > 0 else -1
            if last[ax] and sg != last[ax]:
                dc[k, ax] = sg * um.get(AXES[ax], 0.0) * 1e-3
            last[ax] = sg
        cur = cur + dc[k]
    i = plan.block_at(ts)
    s = np.einsum("ij,ij->i", u - plan.p0[i], plan.u[i])
    frac = np.clip(np.where(plan.L[i] > 0, s / np.where(plan.L[i] > 0, plan.L[i], 1.0), 0.0), 0, 1)
    return c0[i] + dc[i] * frac[:, None]


def _compensation_record(lines: List[str]) -> Dict[str, str]:
    """The ``; ballbar compensation_*`` keys a compensated test program's header carries
    (``core/marker.py``): a logger that copies the program's header records them too."""
    out = {}
    for ln in lines[:MARKER_SCAN_LINES]:
        for key in BALLBAR_RECORD_KEYS:
            head = f"; ballbar {key}:"
            if ln.startswith(head):
                out[key] = ln[len(head) :].strip()
    return out


def _strip_number(line: str) -> str:
    """Drop an ``N<n> ... *<cs>`` wrapper (lines as they were sent to a printer)."""
    s = line.strip()
    if s[:1] in ("N", "n"):
        i = 1
        while i < len(s) and s[i].isdigit():
            i += 1
        s = s[i:].lstrip()
        star = s.rfind("*")
        if star >= 0 and s[star + 1 :].strip().isdigit():
            s = s[:star].rstrip()
    return s
