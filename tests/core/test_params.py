import json

import pytest

from octoprint_kincomp.core.kinematics import changes_nothing
from octoprint_kincomp.core.params import Params, ParamsError


def test_defaults_are_zero_and_round_trip():
    p = Params()
    assert changes_nothing(p)
    d = p.to_dict()
    assert d["version"] == 1 and d["kinematics"] == "parallel"
    assert Params.from_dict(d) == p
    assert Params.from_json(p.to_json()).hash() == p.hash()


def test_partial_document_fills_defaults():
    p = Params.from_dict({"squareness_um_per_m": {"xy": 120.5}})
    assert p.squareness_um_per_m == {"xy": 120.5, "xz": 0.0, "yz": 0.0}
    assert p.scale_ppm == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert not changes_nothing(p)


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"squareness_um_per_m": {"xy": float("nan")}}, "squareness_um_per_m.xy"),
        ({"squareness_um_per_m": {"xy": 60000}}, "squareness_um_per_m.xy"),
        ({"scale_ppm": {"z": float("inf")}}, "scale_ppm.z"),
        ({"scale_ppm": {"q": 1}}, "scale_ppm.q"),
        ({"backlash": {"x": -1}}, "backlash.x"),
        ({"backlash": {"y": [{"at_mm": 0, "um": -2}]}}, "backlash.y[0].um"),
        ({"backlash": {"y": [{"at_mm": 0}]}}, "backlash.y[0]"),
        ({"backlash": {"fraction": 1.5}}, "backlash.fraction"),
        ({"backlash": {"smoothing_mm": -1}}, "backlash.smoothing_mm"),
        ({"bogus": 1}, "bogus"),
        ({"kinematics": "delta"}, "kinematics"),
        ({"version": 7}, "version"),
        ({"squareness_um_per_m": {"xy": "12"}}, "squareness_um_per_m.xy"),
        ({"squareness_um_per_m": {"xy": True}}, "squareness_um_per_m.xy"),
        ({"axis_errors": {"x": {"rz_urad": [0, 1000]}}}, "axis_errors.x.rz_urad"),
        ({"axis_errors": {"x": {"wobble": 1}}}, "axis_errors.x.wobble"),
        ({"nozzle_offset_mm": {"x": 1e6}}, "nozzle_offset_mm.x"),
    ],
)
def test_invalid_values_name_the_field(doc, field):
    with pytest.raises(ParamsError) as exc:
        Params.from_dict(doc)
    assert exc.value.field == field
    assert str(exc.value).startswith(field)


def test_bad_json_is_a_clear_error():
    with pytest.raises(ParamsError, match="not valid JSON"):
        Params.from_json("{nope")
    with pytest.raises(ParamsError, match="must be an object"):
        Params.from_json("[1, 2]")


def test_backlash_points_interpolate_and_hold_outside():
    p = Params.from_dict(
        {"backlash": {"x": [{"at_mm": 210, "um": 4.4}, {"at_mm": 10, "um": 37.4}]}}
    )
    bx = p.backlash["x"]
    assert bx.points == ((10.0, 37.4), (210.0, 4.4))  # sorted
    assert bx.um_at(10) == pytest.approx(37.4)
    assert bx.um_at(110) == pytest.approx((37.4 + 4.4) / 2)
    assert bx.um_at(-50) == pytest.approx(37.4)
    assert bx.um_at(500) == pytest.approx(4.4)
    assert not bx.is_constant
    again = Params.from_json(p.to_json())
    assert again.backlash["x"].points == bx.points


def test_duplicate_backlash_positions_rejected():
    with pytest.raises(ParamsError, match="same position"):
        Params.from_dict({"backlash": {"x": [{"at_mm": 1, "um": 2}, {"at_mm": 1, "um": 3}]}})


def test_hash_ignores_meta_but_not_values():
    a = Params.from_dict({"scale_ppm": {"x": 10}})
    b = Params.from_dict({"scale_ppm": {"x": 10}, "meta": {"source": "run 7"}})
    c = Params.from_dict({"scale_ppm": {"x": 11}})
    assert a.hash() == b.hash()
    assert a.hash() != c.hash()
    assert len(a.hash()) == 12


def test_fraction_zero_disables_backlash():
    p = Params.from_dict({"backlash": {"x": 40, "fraction": 0}})
    assert not p.has_backlash
    assert changes_nothing(p)


def test_meta_must_be_json():
    with pytest.raises(ParamsError, match="meta"):
        Params.from_dict({"meta": {"x": float("nan")}})
    assert json.loads(Params.from_dict({"meta": {"note": "ok"}}).to_json())["meta"] == {
        "note": "ok"
    }


def test_backlash_tables_are_bounded_by_the_kernels_limit():
    """Issue 17: every move walks the table; 2,500 points were accepted."""
    from octoprint_kincomp.core.params import MAX_BACKLASH_POINTS
    from octoprint_kincomp.engines.kernel import MAX_POINTS

    assert MAX_BACKLASH_POINTS == MAX_POINTS == 64
    table = [{"at_mm": float(i), "um": 10.0} for i in range(65)]
    with pytest.raises(ParamsError) as e:
        Params.from_dict({"backlash": {"y": table}})
    assert e.value.field == "backlash.y" and "64" in str(e.value)
    assert len(Params.from_dict({"backlash": {"y": table[:64]}}).backlash["y"].points) == 64
