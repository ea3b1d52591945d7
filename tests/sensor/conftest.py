"""Shared fixtures of the sensor tests: continuous streams from the ballbar simulator (all
SIMULATED), as a live sensor would send them: junk before the program (mounting the bar),
the runs, and junk after (unmounting)."""

import numpy as np
import pytest

from octoprint_kincomp.calibration.ballbar.analysis import analyse
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.simulator.closed_loop import compensate_text
from octoprint_kincomp.simulator.printer import paper_truth, simulate_program


class SimStream:
    """The simulator's trace as one stream: ``t`` (s), ``r`` (mm), ``trace`` (offline).
    ``params``: the program goes out compensated with them (a re-test)."""

    def __init__(self, spec, truth, pre_s=6.0, post_s=3.0, seed=5, params=None):
        self.spec = spec
        if params is None:
            self.trace = simulate_program(generate(spec), truth)
        else:
            text = compensate_text(generate(spec, params_hash=params.hash()), params)
            self.trace = simulate_program(text, truth, spec, "")
        rows = sorted(self.trace.rows, key=lambda row: row[1])
        t = np.array([row[1] for row in rows])
        r = np.array([row[2] for row in rows])
        fs = truth.sample_rate_hz
        rng = np.random.default_rng(seed)
        tp = t[0] - np.arange(int(pre_s * fs), 0, -1) / fs
        # the bar is mounted 2 s before the program's first dwell: before that it rests at
        # its spring's full length, then it is wiggled into the cups
        rp = np.where(tp < t[0] - 2.0, 3.2, r[0] + 0.3 * np.sin(8 * (tp - t[0])))
        rp[tp >= t[0] - 1.5] = r[0]
        rp = rp + rng.normal(0, 5e-4, len(tp))
        te = t[-1] + np.arange(1, int(post_s * fs) + 1) / fs
        re = np.where(te < t[-1] + 1.0, r[-1], 3.2) + rng.normal(0, 5e-4, len(te))
        self.t = np.concatenate([tp, t, te])
        self.r = np.concatenate([rp, r, re])
        self.first_run_sample = len(tp)
        self.last_run_sample = len(tp) + len(t)
        self._offline = None

    def offline(self):
        """The analysis of the simulator's own trace (computed once)."""
        if self._offline is None:
            self._offline = analyse(self.trace)["diagnostics"]
        return self._offline


def same_result(trace, offline, square=0.5, ppm=0.5, ms=0.01, um=0.3):
    """``trace`` analysed gives the ``offline`` diagnostics within the tolerances."""
    da = analyse(trace)["diagnostics"]
    assert abs(da["squareness_um_per_m"] - offline["squareness_um_per_m"]) <= square
    assert abs(da["scale_mismatch_ppm"] - offline["scale_mismatch_ppm"]) <= ppm
    assert abs(da["servo_mismatch_ms"] - offline["servo_mismatch_ms"]) <= ms
    for k, v in offline["backlash_um"].items():
        assert abs(da["backlash_um"][k] - v) <= um, k
    return da


@pytest.fixture(scope="session")
def xy_stream():
    return SimStream(TestSpec(), paper_truth(noise_um=0.5))


@pytest.fixture(scope="session")
def xz_stream():
    from octoprint_kincomp.core.params import Params
    from octoprint_kincomp.simulator.printer import Truth

    truth = Truth(
        errors=Params.from_dict(
            {"squareness_um_per_m": {"xz": 300.0}, "scale_ppm": {"x": 120.0, "z": -80.0}}
        ),
        servo_lag_ms={"x": 0.0, "y": 0.0, "z": 1.0},
        noise_um=0.5,
    )
    return SimStream(TestSpec(plane="XZ", centre=(110, 110, 100), dwell_s=2.0), truth)
