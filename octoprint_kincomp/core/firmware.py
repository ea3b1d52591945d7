"""Firmware-side equivalents of a KinComp parameter set, for users who prefer them.

Sign conventions (see :mod:`params`): KinComp squareness ``xy`` (um/m) equals Marlin's
``M852 I`` and Klipper's skew factor times 1e6; RepRapFirmware ``M556`` uses the opposite sign
and deviations in mm over a length ``S``. Scale ``s`` (ppm, positive = travels too far) means
Marlin steps/mm must be divided by ``1 + s*1e-6``, Klipper's ``rotation_distance`` multiplied by
it, and RepRapFirmware's ``M579`` factor set to ``1 / (1 + s*1e-6)``.

Firmware backlash compensation takes one value per axis; KinComp's per-side or
position-dependent values are reduced to their mean there (said in the output).
"""

from __future__ import annotations

import math
from typing import Dict, List

from .messages import Msg
from .params import AXES, Params

M556_LENGTH_MM = 100.0


def klipper_skew_lengths(factor: float):
    """(AC, BD, AD) lengths that Klipper's ``SET_SKEW`` turns back into ``factor``.

    A rhombus with side AD = 70.71068 mm whose angle at A is ``90 deg - atan(factor)``.
    """
    alpha = math.pi / 2 - math.atan(factor)
    ac = 100.0 * math.sqrt(1.0 + math.cos(alpha))
    bd = 100.0 * math.sqrt(1.0 - math.cos(alpha))
    ad = 100.0 / math.sqrt(2.0)
    return ac, bd, ad


def klipper_skew_factor(ac: float, bd: float, ad: float) -> float:
    """Skew factor from printed diagonals AC, BD and side AD (Klipper/Marlin formula)."""
    side = math.sqrt(2 * ac * ac + 2 * bd * bd - 4 * ad * ad) / 2.0
    return math.tan(math.pi / 2 - math.acos((ac * ac - side * side - ad * ad) / (2 * side * ad)))


def _n(value: float, decimals: int) -> str:
    """Fixed-point text without a negative zero."""
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text


def _mean_backlash_mm(params: Params, axis: str) -> float:
    pts = params.backlash[axis].points
    return sum(um for _, um in pts) / len(pts) * 1e-3


def equivalents(params: Params) -> Dict[str, List[str]]:
    """Firmware command lines per firmware family: ``marlin``, ``klipper``, ``reprapfirmware``."""
    sq = params.squareness_um_per_m
    f = {k: sq[k] * 1e-6 for k in sq}
    scale = {a: params.scale_ppm[a] * 1e-6 for a in AXES}
    bl = {a: _mean_backlash_mm(params, a) for a in AXES}
    per_side = [a for a in AXES if len(params.backlash[a].points) > 1
                and not params.backlash[a].is_constant]
    frac = params.backlash_fraction
    smooth = params.backlash_smoothing_mm

    marlin = [f"M852 I{_n(f['xy'], 6)} J{_n(f['xz'], 6)} K{_n(f['yz'], 6)}"
              " ; skew factors (SKEW_CORRECTION_GCODE)"]
    marlin.append(
        f"M425 X{_n(bl['x'], 4)} Y{_n(bl['y'], 4)} Z{_n(bl['z'], 4)} F{frac:.2f} S{smooth:.2f}"
        " ; backlash (BACKLASH_GCODE)"
    )
    marlin.append(
        "; M92: multiply the current steps/mm by "
        + " ".join(f"{a.upper()}{1.0 / (1.0 + scale[a]):.6f}" for a in AXES)
    )

    klipper = []
    for pair in ("xy", "xz", "yz"):
        ac, bd, ad = klipper_skew_lengths(f[pair])
        klipper.append(f"{pair.upper()}={ac:.5f},{bd:.5f},{ad:.5f}")
    klipper = ["SET_SKEW " + " ".join(klipper)]
    klipper.append(
        "# rotation_distance: multiply the current value by "
        + " ".join(f"{a.upper()}{1.0 + scale[a]:.6f}" for a in AXES)
    )
    klipper.append("# Klipper has no mainline backlash compensation")

    s = M556_LENGTH_MM
    rrf = [
        f"M556 S{s:g} X{_n(-f['xy'] * s, 5)} Y{_n(-f['yz'] * s, 5)} Z{_n(-f['xz'] * s, 5)}"
        " ; orthogonal axis compensation (opposite sign)",
        "M579 " + " ".join(f"{a.upper()}{1.0 / (1.0 + scale[a]):.6f}" for a in AXES)
        + " ; axis scale factors",
        f"M425 X{_n(bl['x'], 4)} Y{_n(bl['y'], 4)} Z{_n(bl['z'], 4)} ; backlash",
    ]
    notes = []
    if per_side:
        notes.append(Msg(
            "Backlash differs along %(axes)s: firmware takes one value per axis, the mean is "
            "shown.", axes=", ".join(a.upper() for a in per_side)))
    return {"marlin": marlin, "klipper": klipper, "reprapfirmware": rrf, "notes": notes}


def format_equivalents(params: Params) -> str:
    eq = equivalents(params)
    out = []
    for title, key in (("Marlin", "marlin"), ("Klipper", "klipper"),
                       ("RepRapFirmware", "reprapfirmware")):
        out.append(f"# {title}")
        out.extend(eq[key])
    for note in eq["notes"]:
        out.append(f"# note: {note}")
    return "\n".join(out) + "\n"
