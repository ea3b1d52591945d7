"""Issue 26: every number a params document accepts is finite and within its documented
range, and so is every quantity derived from it (the firmware equivalents and exports, the
compensation): ``backlash.fraction: 1e-310`` was accepted and made every later ``/status``
a 500 (OverflowError in firmware/export.py)."""

import math
import re

import pytest

from octoprint_kincomp.core.params import (
    MAX_BACKLASH_UM,
    MAX_SCALE_PPM,
    MAX_SMOOTHING_MM,
    MAX_SQUARENESS_UM_PER_M,
    Params,
    ParamsError,
)
from octoprint_kincomp.firmware.export import equivalents, export_json, format_export


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"backlash": {"fraction": 1.5}}, "backlash.fraction"),
        ({"backlash": {"x": -1e-310}}, "backlash.x"),
        ({"squareness_um_per_m": {"xy": 1e308}}, "squareness_um_per_m.xy"),
        (
            {"backlash": {"x": [{"at_mm": 1e300, "um": 1.0}, {"at_mm": 5.0, "um": 2.0}]}},
            "backlash.x[0].at_mm",
        ),
        ({"scale_ppm": {"x": True}}, "scale_ppm.x"),
        ({"scale_ppm": {"x": "1"}}, "scale_ppm.x"),
    ],
)
def test_values_outside_their_range_are_refused_naming_the_field(doc, field):
    with pytest.raises(ParamsError) as exc:
        Params.from_dict(doc)
    assert exc.value.field == field


def _numbers(text):
    return [float(m) for m in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]\d+)?", text)]


SMALLEST = 5e-324  # the smallest subnormal
EXTREMES = [0.0, SMALLEST, 1e-310, 1e-9, 1.0]


@pytest.mark.parametrize("tiny", EXTREMES)
@pytest.mark.parametrize("fraction", [0.0, SMALLEST, 1e-310, 1e-4, 1.0])
@pytest.mark.parametrize("smoothing", [0.0, SMALLEST, 1e-310, MAX_SMOOTHING_MM])
def test_every_derived_quantity_stays_finite_at_the_ends_of_the_ranges(tiny, fraction, smoothing):
    for backlash in (tiny, MAX_BACKLASH_UM):
        for other in (tiny, -MAX_SCALE_PPM, MAX_SQUARENESS_UM_PER_M):
            p = Params.from_dict(
                {
                    "squareness_um_per_m": {"xy": other, "xz": tiny, "yz": -tiny},
                    "scale_ppm": {"x": -MAX_SCALE_PPM if other < 0 else tiny, "y": tiny},
                    "backlash": {
                        "x": backlash,
                        "y": tiny,
                        "fraction": fraction,
                        "smoothing_mm": smoothing,
                    },
                }
            )
            eq = equivalents(p)
            text = "\n".join(eq["marlin"] + eq["klipper"] + eq["reprapfirmware"])
            text += format_export(p) + str(export_json(p))
            assert "inf" not in text.lower() and "nan" not in text.lower(), text
            assert all(math.isfinite(v) for v in _numbers(text))
            assert len(p.hash()) == 12


@pytest.mark.parametrize("tiny", [SMALLEST, 1e-310])
def test_the_compensation_stays_finite_with_the_smallest_values(engine, tiny):
    from octoprint_kincomp.core.compensator import Options
    from octoprint_kincomp.engines.select import make_compensator

    p = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": tiny},
            "scale_ppm": {"x": -tiny},
            "backlash": {
                "x": MAX_BACKLASH_UM,
                "y": [{"at_mm": 0.0, "um": tiny}, {"at_mm": tiny, "um": 50.0}],
                "fraction": tiny,
                "smoothing_mm": tiny,
            },
        }
    )
    comp = make_compensator(p, Options(chord_tol_mm=0.01))
    lines = [
        "G28",
        "G90",
        "G1 X10 Y10 Z1 F3000",
        "G1 X50 Y10",
        "G1 X20 Y40",
        "G2 X30 Y50 I5 J5",
        "G1 X10 Y10",
        "G1 X60 Y5 E1",
    ]
    out = []
    for line in lines:
        got = comp.process(line)
        out.extend([got] if isinstance(got, str) else got)
    text = "\n".join(out).lower()
    assert "inf" not in text and "nan" not in text, text
    assert all(math.isfinite(v) for v in _numbers(text))
