"""The route without a ballbar: parameters from measured printed artifacts.

* Squareness from a printed square (Klipper/Marlin calibration object): diagonals AC and BD and
  the side AD, corner A towards the plane's origin (A--D along the first axis)::

        B-------C
       /       /
      A-------D      -> first axis

  ``factor = tan(pi/2 - angle at A)`` with the side AB from the parallelogram law; positive
  factor = AC is the long diagonal = the printed angle at A is acute = KinComp squareness > 0
  (actual A grows with B), in um/m = factor * 1e6. Print it with compensation off, or use the
  result as a residual (current + measured).
* Scale from measured vs nominal lengths along an axis: ``s = (measured/nominal - 1) * 1e6``
  ppm (positive = the axis travels too far). Use inner and outer spans (or their mean) so the
  extrusion width cancels; material shrinkage shows up here too.
"""

from __future__ import annotations

import math
from typing import Dict, Iterable, Sequence, Tuple

from ...core.messages import Msg
from ...core.params import Params
from ...firmware.export import klipper_skew_factor
from ..ballbar.model import Geometry
from ..findings import info
from ..proposal import propose_params
from ..result import result_document


class ArtifactError(ValueError):
    pass


NOT_PARALLELOGRAM = Msg("these lengths cannot form a parallelogram (check AC, BD, AD)")


def squareness_from_diagonals(ac: float, bd: float, ad: float) -> float:
    """KinComp squareness (um/m) from printed diagonals AC, BD and side AD (mm)."""
    for name, v in (("AC", ac), ("BD", bd), ("AD", ad)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ArtifactError(Msg("%(name)s must be a positive length in mm", name=name))
    if 2 * ac * ac + 2 * bd * bd - 4 * ad * ad <= 0:
        raise ArtifactError(NOT_PARALLELOGRAM)
    try:
        f = klipper_skew_factor(ac, bd, ad)
    except ValueError:
        raise ArtifactError(NOT_PARALLELOGRAM) from None
    return f * 1e6


def scale_from_lengths(pairs: Iterable[Tuple[float, float]]) -> Dict[str, float]:
    """Mean scale error (ppm) and its standard error from (nominal, measured) mm pairs."""
    vals = []
    for nominal, measured in pairs:
        if not (
            nominal > 0 and measured > 0 and math.isfinite(nominal) and math.isfinite(measured)
        ):
            raise ArtifactError(Msg("lengths must be positive numbers in mm"))
        vals.append((measured / nominal - 1.0) * 1e6)
    if not vals:
        raise ArtifactError(Msg("give at least one nominal/measured pair"))
    mean = sum(vals) / len(vals)
    if len(vals) > 1:
        var = sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)
        sem = math.sqrt(var / len(vals))
    else:
        sem = None
    return {"scale_ppm": mean, "standard_error_ppm": sem, "n": len(vals)}


def diagnostics_from_artifact(
    plane: str,
    ac: float,
    bd: float,
    ad: float,
    lengths: Dict[str, Sequence[Tuple[float, float]]] = None,
) -> dict:
    """A diagnostics dict (analysis keys) from artifact measurements.

    ``lengths`` maps axis letters ("x", ...) to (nominal, measured) pairs; absolute scales
    come out as ``scale_ppm`` per axis (a printed part measures absolute length).
    """
    diag = {
        "plane": plane.upper(),
        "squareness_um_per_m": squareness_from_diagonals(ac, bd, ad),
        "source": "printed artifact",
    }
    if lengths:
        diag["scale_ppm"] = {
            ax.lower(): scale_from_lengths(p)["scale_ppm"] for ax, p in lengths.items()
        }
    return diag


def artifact_findings(diag: Dict[str, object]) -> list:
    """What a printed-artifact result checked: nothing of the motion, and its precision is
    the caliper's (a 100 mm square resolves about 100-200 um/m of squareness)."""
    return [
        info(
            "artifact.hand_measured",
            Msg(
                "Measured by hand on a printed part: KinComp cannot check the motion or the noise "
                "behind these lengths; the print's shrinkage and the caliper's error (10-20 µm on "
                "a 100 mm square: 100-200 µm/m of squareness) are in the result."
            ),
            Msg(
                "Measure each length three times and use the mean; print the largest square the "
                "bed allows."
            ),
        )
    ]


def analyse_diagonals(
    plane: str,
    ac: float,
    bd: float,
    ad: float,
    lengths: Dict[str, Sequence[Tuple[float, float]]],
    current: Params,
) -> dict:
    """The result document (``calibration/result.py``) of a printed square's diagonals and
    measured lengths (see :func:`diagnostics_from_artifact`), printed with ``current`` in
    force: the proposal is ``current`` plus what was measured."""
    diag = diagnostics_from_artifact(plane, ac, bd, ad, lengths)
    notes: list = []
    params = propose_params(diag, Geometry(plane.upper(), 0.0, None, None), current, notes)
    found = artifact_findings(diag) + [info("proposal.note", n) for n in notes]
    return result_document(diag, params, found, notes)
