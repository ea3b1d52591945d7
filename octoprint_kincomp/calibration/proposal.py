"""From fitted errors (residuals of one test) to a KinComp parameter set.

Linear terms are composed exactly: the machine the test saw is ``A_res`` (residual scale and
squareness, unit upper-triangular alignment times diagonal scale); with compensation ``A_cur``
active the true machine is ``A_res @ A_cur``, split back into alignment and scale. Backlash is
the residual step plus the share of the current backlash that was applied, per end of the
circle. Servo mismatch goes to the first axis of the plane (only differences are measurable).
"""

from __future__ import annotations

import datetime as _dt
from typing import Dict, List

import numpy as np

from ..core.messages import Msg, error_message
from ..core.params import AXES, Params, ParamsError
from .ballbar.formats import TraceError
from .ballbar.model import Geometry


def alignment_matrix(params: Params) -> np.ndarray:
    """``S @ D`` of a parameter set: actual = (S @ D) commanded (the affine part)."""
    sq = params.squareness_um_per_m
    S = np.array([[1, sq["xy"] * 1e-6, sq["xz"] * 1e-6], [0, 1, sq["yz"] * 1e-6], [0, 0, 1]])
    D = np.diag([1 + params.scale_ppm[k] * 1e-6 for k in AXES])
    return S @ D


def split_alignment(A_true: np.ndarray, d: Dict[str, object]) -> None:
    """Write ``A_true`` = alignment x scale into params document ``d``. (Absurd inputs give
    non-finite values here, silently: :func:`checked_params` refuses them, naming the field.)"""
    Dn = np.diag(A_true)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        Sn = A_true / Dn[None, :]
    d["squareness_um_per_m"] = {"xy": Sn[0, 1] * 1e6, "xz": Sn[0, 2] * 1e6, "yz": Sn[1, 2] * 1e6}
    d["scale_ppm"] = {k: (Dn[i] - 1) * 1e6 for i, k in enumerate(AXES)}


def checked_params(d: Dict[str, object]) -> Params:
    try:
        return Params.from_dict(d)
    except ParamsError as exc:
        raise TraceError(
            Msg(
                "the proposed parameters are out of range (%(error)s); errors "
                "this large are implausible: check the set-up and the "
                "measurement",
                error=error_message(exc),
            )
        ) from None


def proposal_meta(
    source: str, simulated: bool, plane: str, current: Params, firmware=None
) -> Dict[str, object]:
    """The proposal's record: where it comes from, and (``firmware``: a
    ``firmware.compensation.FirmwareCompensation`` whose state is known or active) the
    firmware's compensation it was measured with: it holds only what that left over
    (``service/printing/firmware_watch.py`` reads it back)."""
    out: Dict[str, object] = {
        "source": source + (" (SIMULATED data)" if simulated else ""),
        "plane": plane,
        "date": _dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "based_on": current.hash(),
    }
    if firmware is not None:
        fw = firmware.to_dict()
        out["firmware"] = {k: fw[k] for k in ("known", "skew", "backlash", "scale", "text")}
    return out


def propose_params(
    diag: Dict[str, object], geom: Geometry, current: Params, notes: List[str], firmware=None
) -> Params:
    """Current parameters updated with the residual errors of one test (see module doc);
    ``firmware``: the firmware's compensation during the test (recorded in the meta)."""
    a, b = geom.axes
    d = current.to_dict()
    # Linear part: compose the residual machine with the current model exactly, then split it
    # back into alignment (unit upper triangular) times scale (diagonal).
    A_cur = alignment_matrix(current)
    alpha = float(diag.get("squareness_um_per_m") or 0.0) * 1e-6
    ds = float(diag.get("scale_mismatch_ppm") or 0.0) * 1e-6
    sm = float(diag.get("mean_scale_ppm") or 0.0) * 1e-6
    sA, sB = sm + ds / 2, sm - ds / 2
    A_res = np.eye(3)
    A_res[a, a] = 1 + sA
    A_res[b, b] = 1 + sB
    absolute = diag.get("scale_ppm")  # per-axis absolute scales (printed artifacts)
    if isinstance(absolute, dict):
        for k, letter in enumerate(AXES):
            if absolute.get(letter) is not None:
                A_res[k, k] = 1 + float(absolute[letter]) * 1e-6
    A_res[a, b] = alpha * A_res[b, b]
    with np.errstate(invalid="ignore", over="ignore"):  # (refused below when not finite)
        A_true = A_res @ A_cur
    split_alignment(A_true, d)
    # Backlash: true = residual step + what was applied, per end of the circle.
    bl = diag.get("backlash_um")
    if isinstance(bl, dict) and bl:
        frac = current.backlash_fraction if current.has_backlash else 0.0
        for ax, tag in ((a, "a"), (b, "b")):
            plus = bl.get(f"{tag}_plus")
            minus = bl.get(f"{tag}_minus")
            if plus is None and minus is None:
                continue
            plus = minus if plus is None else plus
            minus = plus if minus is None else minus
            table = current.backlash[AXES[ax]]
            if geom.centre is not None and geom.radius:
                lo = geom.centre[ax] - geom.radius
                hi = geom.centre[ax] + geom.radius
                vals = (
                    max(0.0, minus + frac * table.um_at(lo)),
                    max(0.0, plus + frac * table.um_at(hi)),
                )
                d["backlash"][AXES[ax]] = [
                    {"at_mm": lo, "um": vals[0]},
                    {"at_mm": hi, "um": vals[1]},
                ]
            else:
                mean_cur = sum(um for _, um in table.points) / len(table.points)
                d["backlash"][AXES[ax]] = max(0.0, (plus + minus) / 2 + frac * mean_cur)
                notes.append(
                    Msg(
                        "Backlash of %(axis)s set to the mean of both ends: the "
                        "test centre is unknown.",
                        axis=AXES[ax].upper(),
                    )
                )
            if min(plus, minus) < -0.5 and frac > 0 and not table.is_zero:
                notes.append(
                    Msg(
                        "Negative residual backlash on %(axis)s: the current value "
                        "over-compensates.",
                        axis=AXES[ax].upper(),
                    )
                )
        if current.backlash_fraction == 0:
            d["backlash"]["fraction"] = 1.0
        elif current.backlash_fraction < 1.0:
            notes.append(
                Msg(
                    "Backlash values are the measured lost motion; the fraction "
                    "stays at %(fraction)s, so %(fraction)s of it is taken up (set "
                    "the fraction to 1 for all of it).",
                    fraction=f"{current.backlash_fraction:g}",
                )
            )
    # Servo lag: mismatch assigned to the first axis of the plane.
    dT = diag.get("servo_mismatch_ms")
    if dT is not None:
        applied = current.servo_lag_ms if current.servo_precomp else dict.fromkeys(AXES, 0.0)
        lag = dict(applied)
        lag[AXES[a]] = applied[AXES[a]] + float(dT)
        d["servo_lag_ms"] = lag
        d["servo_precomp"] = current.servo_precomp
    d["meta"] = proposal_meta(
        str(diag.get("source") or "ballbar analysis"),
        bool(diag.get("simulated")),
        geom.plane,
        current,
        firmware,
    )
    return checked_params(d)
