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


DEMO_SHRINKAGE = 0.003  # the demo's plastic shrinks 0.3 %
DEMO_NOISE_UM = 10.0


def demo_readings(
    text: str,
    errors: Params,
    compensated_with: Optional[Params] = None,
    rng: Optional[np.random.Generator] = None,
) -> Dict[str, List[float]]:
    """SIMULATED readings of the artifact program ``text`` as demo mode's printer (true
    errors ``errors``, KinComp compensating it with ``compensated_with``, None when off)
    would have printed it and a user read it: 0.3 % shrinkage, the program's line width, 10
    um caliper noise, 0.01 mm rounding, as many readings per measurement as the program asks
    for (``; kincomp artifact repeats:``, 3 without)."""
    from ..calibration.artifact.program import read_measurements, read_program_info

    info = read_program_info(text)
    try:
        width = float(info.get("line_width_mm", "0.45"))
        repeats = max(1, min(3, int(info.get("repeats", "3"))))
    except ValueError:
        width, repeats = 0.45, 3
    return simulate_readings(
        read_measurements(text),
        errors,
        shrinkage=DEMO_SHRINKAGE,
        line_width_mm=width,
        noise_um=DEMO_NOISE_UM,
        repeats=repeats,
        rng=rng if rng is not None else np.random.default_rng(),
        compensated_with=compensated_with,
    )
