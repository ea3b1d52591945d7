"""A simulated print of the artifact and simulated caliper readings. All output is SIMULATED.

Each measurement's nominal ``from``/``to`` points go through the printer's true kinematic error
model (:class:`~..core.kinematics.KinematicModel`, commanded -> actual), the printed part then
shrinks isotropically by ``shrinkage`` (fraction, 0.005 = 0.5 %), and the caliper reads the
distance plus (outside) or minus (inside) the wall thickness along the measuring direction (a
line width ``line_width_mm`` for vertical walls, ``line_width_mm * |n_h|`` for 45 deg walls),
with Gaussian noise ``noise_um`` (1 sigma) and rounded to ``resolution_mm``.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence

import numpy as np

from ..calibration.artifact.program import Measurement
from ..core.kinematics import KinematicModel
from ..core.params import Params


def true_spans(
    measurements: Sequence[Measurement],
    errors: Params,
    shrinkage: float = 0.0,
    line_width_mm: float = 0.45,
    compensated_with: Optional[Params] = None,
) -> Dict[str, float]:
    """The noise-free reading of every measurement (mm) on the simulated printer
    (``compensated_with``: the parameters KinComp compensated the print with)."""
    model = KinematicModel(errors)
    comp = KinematicModel(compensated_with) if compensated_with is not None else None

    def printed(p):
        return np.array(model.forward(comp.inverse(p) if comp else p))

    out = {}
    for m in measurements:
        a, b = printed(m.start), printed(m.end)
        d = float(np.linalg.norm(b - a)) * (1.0 - shrinkage)
        nh = math.hypot(*m.direction[:2])
        out[m.id] = d + m.sign * line_width_mm * nh
    return out


def simulate_readings(
    measurements: Sequence[Measurement],
    errors: Params,
    shrinkage: float = 0.0,
    line_width_mm: float = 0.45,
    noise_um: float = 10.0,
    repeats: int = 3,
    resolution_mm: float = 0.01,
    rng: Optional[np.random.Generator] = None,
    compensated_with: Optional[Params] = None,
) -> Dict[str, List[float]]:
    """``{"<id>": [reading_mm, ...]}`` as a user with calipers would type it."""
    rng = rng if rng is not None else np.random.default_rng(1)
    spans = true_spans(measurements, errors, shrinkage, line_width_mm, compensated_with)
    out = {}
    for m in measurements:
        vals = spans[m.id] + rng.normal(0.0, noise_um * 1e-3, repeats)
        out[m.id] = [round(round(v / resolution_mm) * resolution_mm, 6) for v in vals]
    return out
