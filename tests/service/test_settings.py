"""The plugin settings without OctoPrint: validation naming the field, partial params updates,
migration of old versions, limits and feeds from a printer profile (issue 3)."""

import pytest

from octoprint_kincomp.core.kinematics import changes_nothing
from octoprint_kincomp.service.settings.schema import (
    SettingsError,
    defaults,
    engine_config,
    limits_from_profile,
    max_feeds_from_profile,
    migrate,
    validate_settings,
)


def test_settings_validation():
    s = validate_settings({"enabled": True, "params": {"squareness_um_per_m": {"xy": 12}}})
    assert s["enabled"] is True and s["params"]["squareness_um_per_m"]["xy"] == 12
    for bad, field in (
        ({"enabled": "yes"}, "enabled"),
        ({"mode": "sometimes"}, "mode"),
        ({"chord_tol_mm": 5}, "chord_tol_mm"),
        ({"decimals": 2}, "decimals"),
        ({"bogus": 1}, "bogus"),
        ({"params": {"squareness_um_per_m": {"xy": 1e9}}}, "params.squareness_um_per_m.xy"),
        ({"params": {"backlash": {"x": -3}}}, "params.backlash.x"),
        ({"home_mm": [0, 0]}, "home_mm"),
    ):
        with pytest.raises(SettingsError) as exc:
            validate_settings(bad)
        assert exc.value.field == field


def test_partial_params_update_keeps_the_other_terms():
    """{"params": {"scale_ppm": {"x": 100}}} changes X scale only (it used to reset the
    squareness and backlash it did not mention to zero); null resets a term; applying a
    complete proposal (replace_params) replaces the document."""
    base = validate_settings(
        {
            "params": {
                "squareness_um_per_m": {"xy": -3000.0},
                "backlash": {"x": 30.0, "y": [{"at_mm": 0, "um": 5}, {"at_mm": 200, "um": 9}]},
                "servo_lag_ms": {"x": 0.5},
            }
        }
    )
    s = validate_settings({"params": {"scale_ppm": {"x": 100}}}, base)
    p = s["params"]
    assert p["scale_ppm"]["x"] == 100.0 and p["squareness_um_per_m"]["xy"] == -3000.0
    assert p["backlash"]["x"] == 30.0 and p["backlash"]["y"][1] == {"at_mm": 200.0, "um": 9.0}
    assert p["servo_lag_ms"]["x"] == 0.5
    # a table replaced by a number, a whole term removed with null
    s = validate_settings({"params": {"backlash": {"y": 4}, "servo_lag_ms": None}}, base)
    assert s["params"]["backlash"]["y"] == 4.0 and "servo_lag_ms" not in s["params"]
    assert s["params"]["backlash"]["x"] == 30.0
    full = validate_settings({"params": {"scale_ppm": {"x": 100}}}, base, replace_params=True)
    assert full["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert "servo_lag_ms" not in full["params"]
    # a merged document is still validated as a whole
    with pytest.raises(SettingsError) as exc:
        validate_settings({"params": {"scale_ppm": {"q": 1}}}, base)
    assert exc.value.field.startswith("params.scale_ppm")


def test_settings_migration_from_flat_keys():
    old = {"enabled": True, "skew_xy": 250.0, "scale_x": -100.0}
    new = validate_settings(migrate(old, None))
    assert new["params"]["squareness_um_per_m"]["xy"] == 250.0
    assert new["params"]["scale_ppm"]["x"] == -100.0


def test_profile_limits_and_feeds():
    prof = {
        "volume": {"width": 220, "depth": 210, "height": 250, "origin": "lowerleft"},
        "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 200}},
    }
    assert limits_from_profile(prof) == (0, 220, 0, 210, 0, 250)
    prof["volume"]["origin"] = "center"
    assert limits_from_profile(prof) == (-110, 110, -105, 105, 0, 250)
    prof["volume"]["custom_box"] = {
        "x_min": -5,
        "x_max": 225,
        "y_min": -3,
        "y_max": 215,
        "z_min": 0,
        "z_max": 250,
    }
    assert limits_from_profile(prof) == (-5, 225, -3, 215, 0, 250)
    assert max_feeds_from_profile(prof) == {"x": 6000.0, "y": 6000.0, "z": 200.0}
    params, options = engine_config(defaults(), (0, 1, 0, 1, 0, 1))
    assert changes_nothing(params) and options.limits == (0, 1, 0, 1, 0, 1)
