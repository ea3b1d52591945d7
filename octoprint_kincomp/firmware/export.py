"""Firmware-side equivalents of a KinComp parameter set, for users who prefer them.

Sign conventions (see :mod:`params`): KinComp squareness ``xy`` (um/m) equals Marlin's
``M852 I`` and Klipper's skew factor times 1e6; RepRapFirmware ``M556`` uses the opposite sign
and deviations in mm over a length ``S``. Scale ``s`` (ppm, positive = travels too far) means
Marlin steps/mm must be divided by ``1 + s*1e-6``, Klipper's ``rotation_distance`` multiplied by
it, and RepRapFirmware's ``M579`` factor set to ``1 / (1 + s*1e-6)``.

Firmware backlash compensation takes one value per axis; KinComp's per-side or
position-dependent values are reduced to their mean there (said in the output).

:func:`equivalents` gives one-line equivalents per firmware (the command line's default
output) and, under ``export``, the ready-to-paste blocks of :func:`export`: per firmware the
sections to put where (Klipper printer.cfg, console, start and end G-code; Marlin terminal
commands stored with ``M500``; a RepRapFirmware config.g snippet) and notes on what the
firmware cannot take. Section titles and notes are translatable messages (JSON form
``{"text", "template", "params"}``, see :func:`messages.as_dict`); the blocks themselves are
firmware text and stay English.
"""

from __future__ import annotations

import math
from typing import Any, Dict, List, NamedTuple, Optional, Sequence

from ..core.messages import Msg, as_dict
from ..core.params import AXES, PLANE_PAIRS, Params
from ..core.version import HOMEPAGE, VERSION

M556_LENGTH_MM = 100.0
KLIPPER_PROFILE = "kincomp"  # the SKEW_PROFILE the export creates and loads
FIRMWARES = ("klipper", "marlin", "reprapfirmware")
FIRMWARE_NAMES = {"klipper": "Klipper", "marlin": "Marlin", "reprapfirmware": "RepRapFirmware"}
COMMENT = {"klipper": "#", "marlin": ";", "reprapfirmware": ";"}  # comment mark of each
# where the documentation explains the export (the settings page links it)
FIRMWARE_HELP_URL = HOMEPAGE + "/blob/main/docs/firmware-export.md"


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


def _per_side_axes(params: Params) -> List[str]:
    """Axes whose backlash varies along the axis (firmware gets their mean)."""
    return [
        a for a in AXES if len(params.backlash[a].points) > 1 and not params.backlash[a].is_constant
    ]


def _per_side_note(axes: Sequence[str]) -> Msg:
    return Msg(
        "Backlash differs along %(axes)s: firmware takes one value per axis, the mean is shown.",
        axes=", ".join(a.upper() for a in axes),
    )


def equivalents(params: Params) -> Dict[str, Any]:
    """Firmware command lines per firmware family: ``marlin``, ``klipper``, ``reprapfirmware``
    (one line per command, the command line's default output), ``notes``, the ready-to-paste
    ``export`` (:func:`export_json`) and ``about`` (KinComp's version and homepage)."""
    sq = params.squareness_um_per_m
    f = {k: sq[k] * 1e-6 for k in sq}
    scale = {a: params.scale_ppm[a] * 1e-6 for a in AXES}
    bl = {a: _mean_backlash_mm(params, a) for a in AXES}
    per_side = _per_side_axes(params)
    frac = params.backlash_fraction
    smooth = params.backlash_smoothing_mm

    marlin = [
        f"M852 I{_n(f['xy'], 6)} J{_n(f['xz'], 6)} K{_n(f['yz'], 6)}"
        " ; skew factors (SKEW_CORRECTION_GCODE)"
    ]
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
        "M579 "
        + " ".join(f"{a.upper()}{1.0 / (1.0 + scale[a]):.6f}" for a in AXES)
        + " ; axis scale factors",
        f"M425 X{_n(bl['x'], 4)} Y{_n(bl['y'], 4)} Z{_n(bl['z'], 4)} ; backlash",
    ]
    notes = []
    if per_side:
        notes.append(_per_side_note(per_side))
    return {
        "marlin": marlin,
        "klipper": klipper,
        "reprapfirmware": rrf,
        "notes": notes,
        "export": export_json(params),
        "about": {
            "version": VERSION,
            "homepage": HOMEPAGE,
            "firmware_help": FIRMWARE_HELP_URL,
        },
    }


def format_equivalents(params: Params) -> str:
    eq = equivalents(params)
    out = []
    for title, key in (
        ("Marlin", "marlin"),
        ("Klipper", "klipper"),
        ("RepRapFirmware", "reprapfirmware"),
    ):
        out.append(f"# {title}")
        out.extend(eq[key])
    for note in eq["notes"]:
        out.append(f"# note: {note}")
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------
# ready-to-paste export


class Section(NamedTuple):
    """One block to paste: ``key`` (stable id), ``title`` (where it goes), ``text``."""

    key: str
    title: Msg
    text: str


class Export(NamedTuple):
    """What one firmware can take: its sections, and notes on what it cannot take."""

    firmware: str
    sections: List[Section]
    notes: List[Msg]


def _sig(value: float, digits: int = 7) -> str:
    """Fixed-point text with ``digits`` significant digits, trailing zeros dropped (steps/mm,
    rotation_distance: 7 digits resolve 0.1 ppm of a value of 10 to 999)."""
    if value == 0.0:
        return "0"
    decimals = max(0, digits - 1 - int(math.floor(math.log10(abs(value)))))
    text = f"{value:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def _factor(value: float) -> str:
    """A scale factor near 1 with 7 decimals (0.1 ppm)."""
    return f"{value:.7f}"


def _ppm(params: Params, axis: str) -> str:
    return f"{axis.upper()} {params.scale_ppm[axis]:+.1f} ppm"


def _header(comment: str) -> str:
    """The block's first line: who wrote it (no parameter hash: the values follow, and the
    web UI shows no hashes, issue 35)."""
    return f"{comment} KinComp {VERSION} firmware export"


def _skew_factors(params: Params) -> Dict[str, float]:
    return {k: params.squareness_um_per_m[k] * 1e-6 for k in PLANE_PAIRS}


def _scaled_axes(params: Params) -> List[str]:
    return [a for a in AXES if params.scale_ppm[a] != 0.0]


def _common_notes(params: Params, firmware: str) -> List[Msg]:
    """Notes every firmware shares: what only KinComp can apply, CoreXY scale."""
    notes = []
    extra = [a for a in AXES if any(v != 0.0 for c in params.axis_errors[a].values() for v in c)]
    if extra or any(params.nozzle_offset_mm[a] != 0.0 for a in AXES):
        notes.append(
            Msg(
                "The full axis error terms and the nozzle offset have no "
                "firmware equivalent: only KinComp applies them."
            )
        )
    if params.has_servo_precomp:
        notes.append(
            Msg("The servo pre-compensation has no firmware equivalent: only KinComp applies it.")
        )
    if (
        params.kinematics == "corexy"
        and firmware != "reprapfirmware"
        and {"x", "y"} & set(_scaled_axes(params))
    ):
        notes.append(
            Msg(
                "CoreXY: the X and Y steps/mm (rotation_distance) belong to the A and "
                "B motors, so only a scale common to X and Y can be set there; keep "
                "KinComp for a difference between them."
            )
        )
    return notes


def _nothing(params: Params, sections: List[Section], firmware: str) -> List[Msg]:
    if sections:
        return []
    skew = any(_skew_factors(params)[k] != 0.0 for k in PLANE_PAIRS)
    if not (skew or _scaled_axes(params) or params.has_backlash):
        return [Msg("Nothing to export: squareness, scale and backlash are all zero.")]
    return [
        Msg(
            "Nothing to export to %(firmware)s: it cannot take any of these corrections.",
            firmware=FIRMWARE_NAMES[firmware],
        )
    ]


def _klipper(params: Params, rotation_distance: Optional[Sequence[float]]) -> Export:
    f = _skew_factors(params)
    sections: List[Section] = []
    notes: List[Msg] = []
    if any(f[k] != 0.0 for k in PLANE_PAIRS):
        lengths = []
        for pair in PLANE_PAIRS:
            ac, bd, ad = klipper_skew_lengths(f[pair])
            lengths.append(f"{pair.upper()}={ac:.5f},{bd:.5f},{ad:.5f}")
        sections += [
            Section(
                "printer_cfg",
                Msg("printer.cfg: add this section, then restart Klipper"),
                _header("#") + "\n[skew_correction]",
            ),
            Section(
                "console",
                Msg(
                    "Console, once: set the skew, save it as a profile and "
                    "write it to printer.cfg (SAVE_CONFIG restarts Klipper)"
                ),
                "SET_SKEW "
                + " ".join(lengths)
                + f"\nSKEW_PROFILE SAVE={KLIPPER_PROFILE}\nSAVE_CONFIG",
            ),
            Section(
                "start_gcode",
                Msg(
                    "Start G-code (slicer or start macro): after homing "
                    "and after any purge or wipe near the bed's edges"
                ),
                f"SKEW_PROFILE LOAD={KLIPPER_PROFILE}",
            ),
            Section("end_gcode", Msg("End G-code"), "SET_SKEW CLEAR=1"),
        ]
    scaled = _scaled_axes(params)
    if scaled:
        lines = []
        if rotation_distance is not None:
            title = Msg(
                "printer.cfg: the new rotation_distance of these stepper sections "
                "(replace the current value)"
            )
            for a in scaled:
                old = rotation_distance[AXES.index(a)]
                new = old * (1.0 + params.scale_ppm[a] * 1e-6)
                lines += [
                    f"[stepper_{a}]",
                    f"rotation_distance: {_sig(new)}  # was {_sig(old)}; {_ppm(params, a)}",
                ]
        else:
            title = Msg("printer.cfg: multiply each stepper's rotation_distance by its factor")
            for a in scaled:
                lines.append(
                    f"# [stepper_{a}] rotation_distance * "
                    f"{_factor(1.0 + params.scale_ppm[a] * 1e-6)}  ({_ppm(params, a)})"
                )
        sections.append(Section("scale", title, "\n".join(lines)))
        notes.append(
            Msg(
                "Klipper has no per-axis scale correction: the scale goes into each "
                "stepper's rotation_distance, new = current × (1 + scale in ppm × 1e-6)."
            )
        )
    if params.has_backlash:
        notes.append(
            Msg(
                "Klipper has no backlash compensation: keep KinComp on for the "
                "backlash alone (with its squareness and scale set to 0 once Klipper "
                "does them), or reduce the play mechanically (belt tension, "
                "anti-backlash nuts)."
            )
        )
    return Export(
        "klipper",
        sections,
        _nothing(params, sections, "klipper") + notes + _common_notes(params, "klipper"),
    )


def _marlin(params: Params, steps_per_mm: Optional[Sequence[float]]) -> Export:
    f = _skew_factors(params)
    lines = [_header(";")]
    options: List[str] = []
    notes: List[Msg] = []
    if any(f[k] != 0.0 for k in PLANE_PAIRS):
        words = [f"I{_n(f['xy'], 7)}"]
        options += ["SKEW_CORRECTION", "SKEW_CORRECTION_GCODE"]
        if f["xz"] != 0.0 or f["yz"] != 0.0:
            words += [f"J{_n(f['xz'], 7)}", f"K{_n(f['yz'], 7)}"]
            options.append("SKEW_CORRECTION_FOR_Z")
        lines.append("M852 " + " ".join(words) + " ; skew factors")
    if params.has_backlash:
        bl = {a: _mean_backlash_mm(params, a) for a in AXES}
        lines.append(
            f"M425 F{params.backlash_fraction:.3f} S{params.backlash_smoothing_mm:.2f} "
            + " ".join(f"{a.upper()}{_n(bl[a], 4)}" for a in AXES)
            + " ; backlash mm, F fraction, S smoothing mm"
        )
        options += ["BACKLASH_COMPENSATION", "BACKLASH_GCODE"]
        if params.backlash_smoothing_mm > 0.0:
            options.append("BACKLASH_SMOOTHING_MM")
        if _per_side_axes(params):
            notes.append(_per_side_note(_per_side_axes(params)))
    scaled = _scaled_axes(params)
    if scaled and steps_per_mm is not None:
        old = {a: steps_per_mm[AXES.index(a)] for a in scaled}
        lines.append(
            "M92 "
            + " ".join(
                f"{a.upper()}{_sig(old[a] / (1.0 + params.scale_ppm[a] * 1e-6))}" for a in scaled
            )
            + " ; steps/mm for the scale, was "
            + " ".join(f"{a.upper()}{_sig(old[a])}" for a in scaled)
        )
    elif scaled:
        lines.append(
            "; M92: multiply the current steps/mm by "
            + " ".join(
                f"{a.upper()}{_factor(1.0 / (1.0 + params.scale_ppm[a] * 1e-6))}" for a in scaled
            )
        )
        notes.append(
            Msg(
                "Marlin has no per-axis scale correction: the scale goes into the "
                "steps/mm (M92), new = current / (1 + scale in ppm × 1e-6)."
            )
        )
    sections: List[Section] = []
    if len(lines) > 1:
        lines.append("M500 ; store in EEPROM")
        options.append("EEPROM_SETTINGS")
        sections.append(
            Section(
                "terminal",
                Msg(
                    "Send to the printer (OctoPrint's terminal); "
                    "M500 keeps the values over a restart"
                ),
                "\n".join(lines),
            )
        )
        notes.insert(
            0,
            Msg(
                "Marlin must be built with %(options)s (Configuration.h and Configuration_adv.h).",
                options=", ".join(options),
            ),
        )
    return Export(
        "marlin",
        sections,
        _nothing(params, sections, "marlin") + notes + _common_notes(params, "marlin"),
    )


def _reprapfirmware(params: Params) -> Export:
    f = _skew_factors(params)
    s = M556_LENGTH_MM
    lines = [_header(";")]
    notes: List[Msg] = []
    if any(f[k] != 0.0 for k in PLANE_PAIRS):
        lines.append(
            f"M556 S{s:g} X{_n(-f['xy'] * s, 5)} Y{_n(-f['yz'] * s, 5)} "
            f"Z{_n(-f['xz'] * s, 5)} ; axis compensation, RepRapFirmware's sign"
        )
        notes.append(
            Msg(
                "M556 takes the deviation in mm over S mm with the opposite sign of "
                "KinComp's squareness (X: XY, Y: YZ, Z: ZX)."
            )
        )
    if _scaled_axes(params):
        lines.append(
            "M579 "
            + " ".join(
                f"{a.upper()}{_factor(1.0 / (1.0 + params.scale_ppm[a] * 1e-6))}" for a in AXES
            )
            + " ; axis scale factors"
        )
    if params.has_backlash:
        frac = params.backlash_fraction
        bl = {a: frac * _mean_backlash_mm(params, a) for a in AXES}
        largest = max(bl.values())
        spread = params.backlash_smoothing_mm
        # S: the spread in multiples of the backlash, 1..100 (the ratio bounded before
        # rounding: a tiny backlash must not make it overflow)
        factor = (
            1
            if spread <= 0.0 or largest <= 0.0
            else int(round(min(100.0, max(1.0, spread / largest))))
        )
        lines.append(
            "M425 "
            + " ".join(f"{a.upper()}{_n(bl[a], 4)}" for a in AXES)
            + f" S{factor} ; backlash mm, taken up over S * the backlash"
        )
        notes.append(
            Msg(
                "M425 needs RepRapFirmware 3.5 or later. It spreads each take-up over "
                "S times the backlash: S%(s)s spreads it over %(mm)s mm on the axis "
                "with the most backlash (KinComp: %(smoothing)s mm).",
                s=factor,
                mm=f"{factor * largest:.2f}",
                smoothing=f"{spread:.2f}",
            )
        )
        if frac != 1.0:
            notes.append(
                Msg(
                    "M425 has no fraction: the backlash shown already is %(fraction)s "
                    "of the measured one.",
                    fraction=f"{frac:g}",
                )
            )
        if _per_side_axes(params):
            notes.append(_per_side_note(_per_side_axes(params)))
    sections = []
    if len(lines) > 1:
        sections.append(
            Section(
                "config_g",
                Msg(
                    "config.g: add these lines (sent in the "
                    "console they apply until the next restart)"
                ),
                "\n".join(lines),
            )
        )
    return Export(
        "reprapfirmware",
        sections,
        _nothing(params, sections, "reprapfirmware")
        + notes
        + _common_notes(params, "reprapfirmware"),
    )


def export(
    params: Params,
    steps_per_mm: Optional[Sequence[float]] = None,
    rotation_distance: Optional[Sequence[float]] = None,
) -> Dict[str, Export]:
    """The ready-to-paste blocks per firmware (``klipper``, ``marlin``, ``reprapfirmware``).

    ``steps_per_mm`` (Marlin) and ``rotation_distance`` (Klipper, mm) are the printer's
    current X, Y, Z values: with them the scale is given as the new values, without them as
    factors. Deterministic: the same parameters give the same text."""
    for name, values in (("steps_per_mm", steps_per_mm), ("rotation_distance", rotation_distance)):
        if values is not None and (
            len(values) != 3 or not all(math.isfinite(v) and v > 0.0 for v in values)
        ):
            raise ValueError(f"{name}: three positive numbers (X, Y, Z) expected")
    return {
        "klipper": _klipper(params, rotation_distance),
        "marlin": _marlin(params, steps_per_mm),
        "reprapfirmware": _reprapfirmware(params),
    }


def export_json(params: Params, **current) -> Dict[str, Dict[str, Any]]:
    """:func:`export` as JSON for the browser: per firmware ``name``, ``comment``,
    ``sections`` [{key, title, text}] and ``notes``, messages as :func:`messages.as_dict`."""
    return {
        fw: {
            "name": FIRMWARE_NAMES[fw],
            "comment": COMMENT[fw],
            "sections": [
                {"key": s.key, "title": as_dict(s.title), "text": s.text} for s in ex.sections
            ],
            "notes": [as_dict(n) for n in ex.notes],
        }
        for fw, ex in export(params, **current).items()
    }


def format_export(params: Params, firmwares: Sequence[str] = FIRMWARES, **current) -> str:
    """The export as text (the command line's ``firmware --format``): per firmware a title,
    each section's title as a comment above its text, the notes as comments."""
    blocks = export(params, **current)
    out: List[str] = []
    for fw in firmwares:
        ex, c = blocks[fw], COMMENT[fw]
        if out:
            out.append("")
        out.append(f"{c} ==== {FIRMWARE_NAMES[fw]} ({FIRMWARE_HELP_URL}) ====")
        for section in ex.sections:
            out += ["", f"{c} -- {section.title}", section.text]
        if ex.notes:
            out.append("")
        out += [f"{c} note: {note}" for note in ex.notes]
    return "\n".join(out) + "\n"
