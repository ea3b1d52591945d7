"""Issue 17, case 4 and 5: every endpoint answers bad input with 400 naming the field, never
500; non-finite numbers never reach storage; a damaged stored run can still be read; links
out of the uploads folder are not followed; backlash tables are bounded. Through the real
blueprint (tests/support/blueprint.py), with a property test over every POST route."""

import json
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from octoprint_kincomp.calibration.ballbar.program import spec_from_program
from tests.support.blueprint import PREFIX, blueprint_client


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path))
    with open(os.path.join(ns.uploads, "ok.gcode"), "w") as f:
        f.write("G28\nG1 X10 Y10 Z1 F3000\nG1 X50 Y20\n")
    yield ns
    ns.stop()


def post(api, path, body=None, raw=None):
    data = raw if raw is not None else json.dumps(body)
    resp = api.client.post(PREFIX + path, data=data, content_type="application/json")
    return resp.status_code, resp.get_json(silent=True) or {}


def deep(n):
    return "[" * n + "]" * n


def test_dryrun_of_a_path_octoprint_cannot_sanitize_is_400_naming_it(api):
    resp = api.client.get(PREFIX + "/dryrun?path=./ok.gcode")
    assert resp.status_code == 400 and "path" in resp.get_json()["error"]
    resp = api.client.get(PREFIX + "/dryrun?path=ok.gcode")
    assert resp.status_code == 200, resp.get_json()
    assert resp.get_json()["report"]["moves"] == 2


@pytest.mark.parametrize("path", ["./", ".", "\\"])
def test_arming_for_a_path_octoprint_cannot_sanitize_is_404_naming_it(api, path):
    # ("./" made OctoPrint's sanitize_path raise IndexError: a 500, found by the property test)
    resp = api.client.post(
        PREFIX + "/sensor/arm", data=json.dumps({"path": path}), content_type="application/json"
    )
    assert resp.status_code == 404 and path in resp.get_json()["error"], resp.get_data()[:300]


@pytest.mark.parametrize("route", ["/settings", "/program", "/analyze", "/apply", "/compensate"])
def test_json_nested_5000_deep_is_400(api, route):
    for body in (deep(5000), '{"a": ' + deep(5000) + "}", '{"params": ' + deep(40) + "}"):
        code, resp = post(api, route, raw=body)
        assert code == 400, (route, code, resp)


@pytest.mark.parametrize(
    "body, field",
    [
        ({"plane": "../../x"}, "plane"),
        ({"plane": 5}, "plane"),
        ({"centre": "abc"}, "centre"),
        ({"centre": [1, 2]}, "centre"),
        ({"radius": "big"}, "radius"),
        ({"feed": None}, "feed"),
    ],
)
def test_program_names_the_bad_field(api, body, field):
    code, resp = post(api, "/program", body)
    assert code == 400 and field in resp["error"], resp


GOOD_ARTIFACT = {"plane": "XY", "ac": 141.5, "bd": 141.3, "ad": 100.0}


@pytest.mark.parametrize(
    "change, field",
    [
        ({"plane": "QQ"}, "plane"),
        ({"lengths": "abc"}, "lengths"),
        ({"lengths": {"x": "abc"}}, "lengths.x"),
        ({"lengths": {"q": [[100, 100.1]]}}, "lengths"),
        ({"lengths": {"x": [[100]]}}, "lengths.x"),
        ({"ac": "1"}, "ac"),
        ({"ac": 1e308}, "finite"),
        ({"lengths": {"x": [[100, 1e308]]}}, "finite"),
    ],
)
def test_artifact_measurements_are_checked_and_nothing_absurd_is_stored(api, change, field):
    code, resp = post(api, "/artifact/analyze", {"square": dict(GOOD_ARTIFACT, **change)})
    assert code == 400 and field in resp["error"], resp
    assert api.plugin.runs.list() == []
    code, run = post(
        api,
        "/artifact/analyze",
        {"square": dict(GOOD_ARTIFACT, lengths={"x": [[100, 100.05], [50, 50.02]]})},
    )
    assert code == 200 and run["diagnostics"]["scale_ppm"]["x"] > 0


def test_non_finite_numbers_are_refused_naming_the_field(api):
    code, resp = post(api, "/settings", raw='{"chord_tol_mm": NaN}')
    assert code == 400 and "chord_tol_mm" in resp["error"]
    code, resp = post(api, "/settings", raw='{"params": {"scale_ppm": {"x": 1e400}}}')
    assert code == 400 and "params.scale_ppm.x" in resp["error"]
    code, resp = post(
        api, "/analyze", raw='{"summary": {"plane": "XY", "squareness_um_per_m": Infinity}}'
    )
    assert code == 400 and "summary.squareness_um_per_m" in resp["error"]
    assert api.plugin.runs.list() == []


def test_a_stored_run_with_infinity_can_still_be_read(api):
    run_id = api.plugin.runs.new_id()
    path = os.path.join(api.plugin.runs.folder, run_id + ".json")
    with open(path, "w") as f:  # as an older version stored it
        f.write(
            '{"id": "%s", "diagnostics": {"scale_ppm": {"x": Infinity}}, '
            '"proposed": {}, "applied": null}' % run_id
        )
    resp = api.client.get(f"{PREFIX}/runs/{run_id}")
    assert resp.status_code == 200
    assert resp.get_json()["diagnostics"]["scale_ppm"]["x"] is None
    assert api.client.get(f"{PREFIX}/runs").status_code == 200
    with pytest.raises(ValueError):
        api.plugin.runs.save({"id": api.plugin.runs.new_id(), "x": float("inf")})
    assert len(os.listdir(api.plugin.runs.folder)) == 1  # nothing new stored


def test_more_than_64_backlash_points_are_refused_naming_the_axis(api):
    table = [{"at_mm": i, "um": 10.0} for i in range(65)]
    code, resp = post(api, "/settings", {"params": {"backlash": {"x": table}}})
    assert code == 400 and "params.backlash.x" in resp["error"] and "64" in resp["error"]
    code, _ = post(api, "/settings", {"params": {"backlash": {"x": table[:64]}}})
    assert code == 200


def test_a_link_out_of_the_uploads_is_not_followed(api, tmp_path):
    secret = tmp_path / "outside.gcode"
    secret.write_text("G1 X1 Y1\n")
    os.symlink(str(secret), os.path.join(api.uploads, "link.gcode"))
    os.symlink(os.path.join(api.uploads, "ok.gcode"), os.path.join(api.uploads, "in.gcode"))
    post(api, "/settings", {"enabled": True, "params": {"squareness_um_per_m": {"xy": 500}}})
    resp = api.client.get(PREFIX + "/dryrun?path=link.gcode")
    assert resp.status_code == 403 and "link" in resp.get_json()["error"]
    code, _ = post(api, "/compensate", {"path": "link.gcode"})
    assert code == 403
    api.plugin.files.file_added({"path": "link.gcode", "storage": "local"})
    assert not api.plugin.jobs.jobs  # nothing queued: no copy of the target lands here
    assert api.client.get(PREFIX + "/dryrun?path=in.gcode").status_code == 200  # inside


# ~~ random bodies against every POST route -----------------------------------------------
FIELDS = [
    "path",
    "plane",
    "centre",
    "radius",
    "feed",
    "print",
    "mount_pause",
    "summary",
    "artifact",
    "ac",
    "bd",
    "ad",
    "lengths",
    "x",
    "run",
    "params",
    "enabled",
    "apply_now",
    "squareness_um_per_m",
    "scale_ppm",
    "backlash",
    "mode",
    "demo",
    "home_mm",
    "decimals",
    "chord_tol_mm",
    "limits_policy",
    "xy",
    "um",
    "at_mm",
]
scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(10**20), 10**20)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12)
    | st.sampled_from(["XY", "QQ", "../../x", "ok.gcode", "./ok.gcode"])
)
keys = st.sampled_from(FIELDS) | st.text(max_size=6)
bodies = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=5),
    max_leaves=16,
)


def post_routes(app):
    return sorted(
        {
            r.rule
            for r in app.url_map.iter_rules()
            if r.rule.startswith(PREFIX) and "POST" in r.methods and "<" not in r.rule
        }
    )


def test_the_property_test_reaches_every_post_route(api):
    routes = post_routes(api.app)
    assert {
        "/plugin/kincomp/settings",
        "/plugin/kincomp/program",
        "/plugin/kincomp/analyze",
        "/plugin/kincomp/apply",
        "/plugin/kincomp/compensate",
        "/plugin/kincomp/trace",
    } <= set(routes)


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(body=st.dictionaries(keys, bodies, max_size=6) | bodies)
def test_random_json_bodies_never_give_a_500(api, body):
    raw = json.dumps(body)  # (NaN and Infinity as JSON's non-standard tokens)
    for route in post_routes(api.app):
        resp = api.client.post(route, data=raw, content_type="application/json")
        assert resp.status_code < 500, (route, raw, resp.get_data()[:300])
    resp = api.client.get(PREFIX + "/dryrun", query_string={"path": str(body)[:200]})
    assert resp.status_code < 500


def test_a_test_measured_with_compensation_off_is_analysed_against_no_parameters(api):
    """Stored parameters do not act while compensation is off: a test printed then measures
    the whole error, so the analysis must not add it to the stored parameters (it did once:
    the proposal was stored + measured, twice the error)."""
    stored = {"squareness_um_per_m": {"xy": 300.0}}
    summary = {"summary": {"plane": "XY", "squareness_um_per_m": 40.0}}
    assert post(api, "/settings", {"enabled": False, "params": stored})[0] == 200
    code, off = post(api, "/analyze", summary)
    assert code == 200, off
    assert off["params_before"]["squareness_um_per_m"]["xy"] == 0.0
    whole = off["proposed"]["squareness_um_per_m"]["xy"]
    assert abs(whole) == pytest.approx(40.0, abs=1e-6)
    code, prog = post(api, "/program", {"plane": "XY", "centre": [100, 100, 5], "radius": 30})
    assert code == 200, prog
    written = api.plugin._file_manager.add_file.call_args[0][2].stream().read().decode()
    assert spec_from_program(written)[0].params_hash == off["params_before_hash"]  # none
    # on: the same reading is a residual on top of the parameters in force
    assert post(api, "/settings", {"enabled": True})[0] == 200
    code, on = post(api, "/analyze", summary)
    assert code == 200 and on["params_before"]["squareness_um_per_m"]["xy"] == 300.0
    assert on["proposed"]["squareness_um_per_m"]["xy"] == pytest.approx(300.0 + whole, abs=1e-6)


# ~~ issue 37 rows 3 and 7: numbers beyond the float range, stored or pasted ----------------
HUGE = "1" + "0" * 400  # a JSON integer beyond the float range


@pytest.mark.parametrize(
    "route, body",
    [
        ("/program", '{"plane": "XY", "radius": %s}'),
        ("/artifact/program", '{"size_mm": %s}'),
        ("/artifact/analyze", '{"plane": "XY", "ac": %s, "bd": 141.3, "ad": 100}'),
        ("/campaign/plan", '{"radius": %s}'),
        ("/settings", '{"chord_tol_mm": %s}'),
        ("/analyze", '{"summary": {"plane": "XY", "squareness_um_per_m": %s}}'),
    ],
)
def test_an_integer_beyond_the_float_range_is_400(api, route, body):
    code, resp = post(api, route, raw=body % HUGE)
    assert code == 400 and "finite" in resp["error"], (code, resp)


LIMITS = [
    "[printer]\nmax_velocity: 1e307\nmax_accel: 3000",
    "[printer]\nmax_velocity: 300\nmax_z_velocity: 1e307\nmax_accel: 3000",
    "SET_VELOCITY_LIMIT VELOCITY=1e308",
    "[printer]\nmax_velocity: 300\nmax_accel: 1e308",
    "M201 X1e300 Y3000 Z100",
]


@pytest.mark.parametrize("text", LIMITS)
def test_pasted_motion_limits_beyond_any_printers_are_refused(api, text):
    body = {"motion_limits": {"text": text, "source": "pasted"}}
    code, resp = post(api, "/settings", body)
    assert code == 400 and "motion_limits.text" in resp["error"], resp
    assert api.plugin.store.current()["motion_limits"]["text"] == ""
    resp = api.client.get(PREFIX + "/status")
    assert resp.status_code == 200


@pytest.mark.parametrize("text", LIMITS)
def test_a_stored_limit_beyond_range_is_reported_and_repairable(tmp_path, text):
    """Stored by an earlier version (or by hand): /status was a 500 on every call (Infinity
    in the JSON), /program and /campaign/plan too. Now the problem is reported, naming the
    field, every page works, and a save of a good text repairs it."""
    stored = {"motion_limits": {"text": text, "source": "pasted", "firmware": ""}}
    ns = blueprint_client(str(tmp_path), stored=stored)
    try:
        resp = ns.client.get(PREFIX + "/status")
        assert resp.status_code == 200, resp.get_data()[:300]
        body = json.loads(resp.get_data())  # strict JSON: no Infinity
        assert body["settings_problem_field"] == "motion_limits.text"
        for route, req in (("/program", {"plane": "XY"}), ("/campaign/plan", {})):
            code = ns.client.post(PREFIX + route, json=req).status_code
            assert code < 500, route
        good = {"text": "[printer]\nmax_velocity: 300\nmax_accel: 3000", "source": "pasted"}
        resp = ns.client.post(PREFIX + "/settings", json={"motion_limits": good})
        assert resp.status_code == 200, resp.get_json()
        assert ns.client.get(PREFIX + "/status").get_json()["settings_problem"] is None
    finally:
        ns.stop()


def test_arming_never_follows_a_link_out_of_the_uploads(api, tmp_path):
    """Issue 37 row 9: /sensor/arm read /etc/passwd through a link where the other routes
    answer 403; a stored file holding only a program's plane line was a 500."""
    secret = tmp_path / "outside.gcode"
    secret.write_text("; ballbar plane: XY\n")
    os.symlink(str(secret), os.path.join(api.uploads, "link.gcode"))
    code, resp = post(api, "/sensor/arm", {"path": "link.gcode"})
    assert code == 403 and "link" in resp["error"], (code, resp)
    with open(os.path.join(api.uploads, "cut.gcode"), "w") as f:
        f.write("; ballbar plane: XY\n")
    code, resp = post(api, "/sensor/arm", {"path": "cut.gcode"})
    assert code == 400 and "centre" in resp["error"], (code, resp)
