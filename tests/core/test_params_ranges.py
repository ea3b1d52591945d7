"""Issue 26: every number a params document accepts is finite and within its documented
range, and so is every quantity derived from it (the firmware equivalents and exports):
``backlash.fraction: 1e-310`` was accepted and made every later ``/status`` a 500
(OverflowError in core/firmware.py)."""

import math
import re

import pytest

from octoprint_kincomp.core.firmware import equivalents, export_json, format_export
from octoprint_kincomp.core.params import (
    MAX_BACKLASH_UM,
    MAX_SCALE_PPM,
    MAX_SMOOTHING_MM,
    MAX_SQUARENESS_UM_PER_M,
    MIN_BACKLASH_FRACTION,
    MIN_MAGNITUDE,
    Params,
    ParamsError,
)


@pytest.mark.parametrize("doc, field", [
    ({"backlash": {"x": 45.0, "fraction": 1e-310, "smoothing_mm": 2.0}}, "backlash.fraction"),
    ({"backlash": {"fraction": 1e-4}}, "backlash.fraction"),
    ({"backlash": {"x": 1e-310}}, "backlash.x"),
    ({"scale_ppm": {"y": -1e-310}}, "scale_ppm.y"),
    ({"squareness_um_per_m": {"xy": 1e308}}, "squareness_um_per_m.xy"),
    ({"backlash": {"x": [{"at_mm": 1e-320, "um": 1.0}, {"at_mm": 5.0, "um": 2.0}]}},
     "backlash.x[0].at_mm"),
    ({"scale_ppm": {"x": True}}, "scale_ppm.x"),
    ({"scale_ppm": {"x": "1"}}, "scale_ppm.x"),
])
def test_values_outside_their_range_are_refused_naming_the_field(doc, field):
    with pytest.raises(ParamsError) as exc:
        Params.from_dict(doc)
    assert exc.value.field == field


def _numbers(text):
    return [float(m) for m in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]\d+)?", text)]


EXTREMES = [0.0, MIN_MAGNITUDE, 1e-9, 1.0]


@pytest.mark.parametrize("tiny", EXTREMES)
@pytest.mark.parametrize("fraction", [0.0, MIN_BACKLASH_FRACTION, 1.0])
@pytest.mark.parametrize("smoothing", [0.0, MIN_MAGNITUDE, MAX_SMOOTHING_MM])
def test_every_derived_quantity_stays_finite_at_the_ends_of_the_ranges(tiny, fraction,
                                                                        smoothing):
    for backlash in (tiny, MAX_BACKLASH_UM):
        for other in (tiny, -MAX_SCALE_PPM, MAX_SQUARENESS_UM_PER_M):
            p = Params.from_dict({
                "squareness_um_per_m": {"xy": other, "xz": tiny, "yz": -tiny},
                "scale_ppm": {"x": -MAX_SCALE_PPM if other < 0 else tiny, "y": tiny},
                "backlash": {"x": backlash, "y": tiny, "fraction": fraction,
                             "smoothing_mm": smoothing}})
            eq = equivalents(p)
            text = "\n".join(eq["marlin"] + eq["klipper"] + eq["reprapfirmware"])
            text += format_export(p) + str(export_json(p))
            assert "inf" not in text.lower() and "nan" not in text.lower(), text
            assert all(math.isfinite(v) for v in _numbers(text))
            assert len(p.hash()) == 12
