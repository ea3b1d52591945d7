"""Issue 26 end to end, on real OctoPrint servers (virtual printer):

* concurrent partial saves (two on KinComp's ``/settings``, one on OctoPrint's
  ``/api/settings``) never erase the calibration: in ``/status`` and in config.yaml after
  every trial (the in-process test runs hundreds: tests/plugin/test_concurrent_saves.py);
* a server killed (SIGKILL) in the middle of a stream of saves loses at most the save in
  flight: after the restart the calibration is whole and the stored value is one sent;
* the standing probe: endpoints x bad values (types, NaN/Infinity, 1e308/1e-310, negative,
  huge, unicode, nesting): never a 5xx, and a refused request stores nothing;
* a wrong type in config.yaml (``sensor.units: [mm]``, ``params: garbage``) at start-up:
  the settings problem names the field, compensation is off, no endpoint fails, and the API
  repairs it;
* ``GET /runs/<id>/trace`` under a relative basedir (as ``./run.sh`` starts OctoPrint).
"""

import copy
import math
import os
import random
import signal
import threading
import time

import pytest
import yaml

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth
from octoprint_kincomp.tools.devserver import DevServer
from tests.support.serverutil import status

pytestmark = pytest.mark.slow

BASE = "/plugin/kincomp"
CALIBRATION = {
    "squareness_um_per_m": {"xy": 420.0, "xz": -130.0, "yz": 75.0},
    "scale_ppm": {"x": 310.0, "y": -120.0, "z": 0.0},
    "backlash": {"x": 45.0, "y": 30.0, "z": 0.0},
}
WANT = Params.from_dict(CALIBRATION).hash()


_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # (libyaml's: the same documents)
_read = {}  # config.yaml's path -> (its bytes, KinComp's part of it) as last read


def _kincomp_yaml(srv):
    """KinComp's part of the server's config.yaml (read again only when the file changed:
    the bad-value probe asks after each of some 2,000 requests)."""
    path = os.path.join(srv.basedir, "config.yaml")
    with open(path, "rb") as f:
        raw = f.read()
    if path not in _read or _read[path][0] != raw:
        doc = yaml.load(raw, Loader=_LOADER) or {}
        kc = dict((doc.get("plugins") or {}).get("kincomp") or {})
        kc.pop("_config_version", None)
        _read[path] = (raw, kc)
    return dict(_read[path][1])


def _apply(srv, params, enabled):
    code, body = srv.request(
        "POST", f"{BASE}/apply", {"params": params, "enabled": enabled, "apply_now": True}
    )
    assert code == 200, body


def _reset(srv):
    _apply(srv, Params().to_dict(), False)
    code, body = srv.request(
        "POST",
        f"{BASE}/settings",
        {"decimals": 3, "chord_tol_mm": 0.01, "limits_policy": "warn", "apply_now": True},
    )
    assert code == 200, body


# -- 1. concurrent saves -------------------------------------------------------------------

TRIALS = 25


def test_concurrent_saves_keep_the_calibration(server):
    _apply(server, CALIBRATION, True)
    failures = []
    try:
        for trial in range(TRIALS):
            barrier = threading.Barrier(3)
            codes = []

            def call(method, path, body):
                barrier.wait()
                codes.append(server.request(method, path, body)[0])

            policy = ("warn", "clamp")[trial % 2]
            threads = [
                threading.Thread(
                    target=call, args=("POST", f"{BASE}/settings", {"decimals": 3 + trial % 4})
                ),
                threading.Thread(
                    target=call,
                    args=("POST", f"{BASE}/settings", {"chord_tol_mm": 0.001 * (1 + trial)}),
                ),
                threading.Thread(
                    target=call,
                    args=(
                        "POST",
                        "/api/settings",
                        {"plugins": {"kincomp": {"limits_policy": policy}}},
                    ),
                ),
            ]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            st = status(server)
            s = st["settings"]
            disk = _kincomp_yaml(server)
            ok = (
                sorted(codes) == [200, 200, 200]
                and st["params_hash"] == WANT
                and st["compensation"]["enabled"]
                and disk.get("params", {}).get("squareness_um_per_m", {}).get("xy") == 420.0
                and s["decimals"] == 3 + trial % 4
                and math.isclose(s["chord_tol_mm"], 0.001 * (1 + trial))
                and s["limits_policy"] == policy
            )
            if not ok:
                failures.append(
                    (
                        trial,
                        codes,
                        st["params_hash"],
                        s["decimals"],
                        s["chord_tol_mm"],
                        s["limits_policy"],
                    )
                )
        print(
            f"\nreal server: {TRIALS - len(failures)}/{TRIALS} concurrent-save trials "
            "kept the calibration and every save's key"
        )
        assert not failures, failures[:5]
    finally:
        _reset(server)


# -- 2. a kill during saves ------------------------------------------------------------------


def _kill(srv):
    os.killpg(srv.proc.pid, signal.SIGKILL)
    srv.proc.wait(timeout=30)
    srv.proc = None


def test_a_kill_during_saves_loses_at_most_the_save_in_flight(tmp_path):
    srv = DevServer(str(tmp_path / "op"), kincomp={"enabled": True, "params": CALIBRATION})
    srv.start()
    rng = random.Random(26)
    try:
        for kill in range(3):
            sent, stop = [], threading.Event()

            def saver():
                i = 0
                while not stop.is_set():
                    value = round(0.001 * (1 + (i + 50 * kill) % 200), 3)
                    try:
                        code, _ = srv.request("POST", f"{BASE}/settings", {"chord_tol_mm": value})
                    except OSError:
                        return  # the server is gone
                    sent.append((code, value))
                    i += 1

            t = threading.Thread(target=saver)
            t.start()
            time.sleep(1.0 + rng.random() * 2.0)
            _kill(srv)
            stop.set()
            t.join(timeout=70)
            srv.start()
            st = status(srv)
            assert st["params_hash"] == WANT, st["settings"]["params"]
            assert st["settings_problem"] is None and st["compensation"]["enabled"]
            assert _kincomp_yaml(srv)["params"]["squareness_um_per_m"]["xy"] == 420.0
            answered = [v for c, v in sent if c == 200]
            assert answered, sent
            # the last answered save, or the one in flight when the server died
            in_flight = round(0.001 * (1 + (len(sent) + 50 * kill) % 200), 3)
            assert st["settings"]["chord_tol_mm"] in (answered[-1], in_flight), (
                st["settings"]["chord_tol_mm"],
                answered[-3:],
                in_flight,
            )
            print(
                f"\nkill {kill + 1}: {len(answered)} saves answered before the kill; "
                f"calibration whole after the restart"
            )
    finally:
        srv.stop()


# -- 3. the standing probe: endpoints x bad values ---------------------------------------------


def _nested(depth):
    v = 1
    for _ in range(depth):
        v = [v]
    return v


BAD = [
    None,
    True,
    False,
    "",
    "x",
    "1",
    "\u0661\u0662\u0663",
    "\ud800",
    "\u202egcode",
    "a" * 5000,
    [],
    [1],
    ["mm"],
    {},
    {"a": 1},
    _nested(40),
    -1,
    0,
    -1e308,
    1e308,
    1e-310,
    2**70,
    float("nan"),
    float("inf"),
    float("-inf"),
]


def _settings_fields():
    """(dotted field, body maker) for every settings field, nested ones inside their
    objects, as a partial save sends them."""
    from octoprint_kincomp.service.settings.schema import defaults

    out = []

    def walk(doc, path):
        for key, value in doc.items():
            here = path + [key]
            out.append(here)
            if isinstance(value, dict):
                walk(value, here)

    walk(defaults(), [])
    return out


def _quoted(value):
    """``value`` as a URL part (None where it cannot be one: a lone surrogate)."""
    from urllib.parse import quote

    try:
        return quote(str(value), safe="")
    except UnicodeEncodeError:
        return None


def _body(path, value):
    body = value
    for key in reversed(path):
        body = {key: body}
    return body


def test_the_bad_value_probe_gives_no_5xx_and_stores_nothing_refused(server):
    _apply(server, CALIBRATION, False)
    before_doc = _kincomp_yaml(server)
    before_status = status(server)["settings"]
    requests = []
    for path in _settings_fields():
        for value in BAD:
            requests.append(("POST", f"{BASE}/settings", _body(path, value), "admin"))
            if len(path) == 1:  # OctoPrint's endpoint: the same checks (the top level)
                requests.append(
                    ("POST", "/api/settings", {"plugins": {"kincomp": _body(path, value)}}, "admin")
                )
    for value in BAD:
        q = _quoted(value)
        requests += [
            ("POST", f"{BASE}/apply", {"params": value}, "admin"),
            ("POST", f"{BASE}/apply", {"run": value}, "admin"),
            ("POST", f"{BASE}/apply", {"params": {"backlash": {"fraction": value}}}, "admin"),
            ("POST", f"{BASE}/apply", {"params": {"scale_ppm": {"x": value}}}, "admin"),
            ("POST", f"{BASE}/analyze", {"summary": value}, "admin"),
            (
                "POST",
                f"{BASE}/artifact/analyze",
                {"square": {"plane": "XY", "ac": value, "bd": 1, "ad": 1}},
                "admin",
            ),
            ("POST", f"{BASE}/campaign/plan", {"radius_xy": value, "preview": True}, "admin"),
            ("POST", f"{BASE}/compensate", {"path": value}, "admin"),
            ("POST", f"{BASE}/program", {"plane": value}, "admin"),
            ("POST", f"{BASE}/program", {"radius_mm": value}, "admin"),
            ("POST", f"{BASE}/sensor/arm", {"path": value}, "admin"),
            ("POST", f"{BASE}/sensor/open", {"port": value}, "admin"),
            ("POST", f"{BASE}/settings", {"sensor": {"units": value}}, "viewer"),
        ]
        if q is not None:
            requests += [
                ("POST", f"{BASE}/jobs/{q or 'x'}/cancel", None, "viewer"),
                ("GET", f"{BASE}/dryrun?path={q}", None, "viewer"),
                ("GET", f"{BASE}/compare?before={q}&after={q}", None, "viewer"),
                ("GET", f"{BASE}/runs/{q or 'x'}/trace", None, "viewer"),
            ]
    fives, refused_but_stored, counts = [], [], {}
    for method, path, body, user in requests:
        code, resp = server.request(method, path, body, key=user)
        counts[code // 100] = counts.get(code // 100, 0) + 1
        if code >= 500:
            fives.append((code, method, path, repr(body)[:120], str(resp)[:200]))
        elif code >= 400 and ("settings" in path or "apply" in path):
            now = _kincomp_yaml(server)
            if now != before_doc:
                refused_but_stored.append((method, path, repr(body)[:120]))
                before_doc = now
        elif code < 300 and ("settings" in path or "apply" in path):
            before_doc = _kincomp_yaml(server)  # accepted (a valid value): the new baseline
    print(f"\nbad-value probe: {len(requests)} requests, answers by class {counts}")
    assert not fives, fives[:10]
    assert not refused_but_stored, refused_but_stored[:10]
    after = status(server)
    assert after["settings_problem"] is None
    assert set(after["settings"]) == set(before_status)
    # every setting the probe changed with a valid value back as it was (the shared server's
    # next tests: its motion limits, stored as a 2,000-letter firmware name and no text, left
    # a later test program without its planner)
    code, body = server.request("POST", f"{BASE}/settings", before_status)
    assert code == 200, body
    assert status(server)["settings"] == before_status
    _reset(server)


# -- 4. wrong types in config.yaml at start-up --------------------------------------------------

GETS = [
    "/status",
    "/runs",
    "/files",
    "/sensor/status",
    "/campaigns",
    "/dryrun?path=a.gcode",
    "/compare?before=a&after=b",
]


@pytest.mark.parametrize(
    "stored, field",
    [
        ({"enabled": True, "params": CALIBRATION, "sensor": {"units": ["mm"]}}, "sensor.units"),
        ({"enabled": True, "params": "garbage"}, "params"),
    ],
)
def test_a_wrong_type_in_config_yaml_at_start_up(tmp_path, stored, field):
    srv = DevServer(str(tmp_path / "op"), kincomp=copy.deepcopy(stored))
    srv.start()
    try:
        for path in GETS:
            code, body = srv.request("GET", BASE + path)
            assert code < 500, (path, body)
        code, body = srv.request("GET", "/api/settings")
        assert code == 200
        st = status(srv)
        assert st["settings_problem_field"] == field, st["settings_problem"]
        assert st["compensation"]["enabled"] is False
        assert "invalid" in srv.octoprint_log()
        disk = _kincomp_yaml(srv)  # kept until the user fixes it (OctoPrint drops defaults)
        if field == "params":
            assert disk["params"] == "garbage"
        else:
            assert disk["sensor"]["units"] == ["mm"]
            assert Params.from_dict(disk["params"]).hash() == WANT
        code, body = srv.request("POST", f"{BASE}/settings", {"decimals": 4})
        assert code == 400 and field in body["error"]
        fix = {"sensor": {"units": "mm"}} if field == "sensor.units" else {"params": CALIBRATION}
        code, body = srv.request("POST", f"{BASE}/settings", fix)
        assert code == 200, body
        st = status(srv)
        assert st["settings_problem"] is None and st["compensation"]["enabled"] is True
        assert st["params_hash"] == WANT
    finally:
        srv.stop()


# -- 5. a run's trace under a relative basedir -------------------------------------------------


def test_a_runs_trace_downloads_under_a_relative_basedir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    srv = DevServer("op")  # relative, as ./run.sh passes it
    srv.start()
    try:
        text = generate(TestSpec())
        spec, prog_hash = spec_from_program(text)
        trace = simulate_program(text, volume_truth(noise_um=0.5), spec, prog_hash).to_text()
        code, run = srv.request(
            "POST", f"{BASE}/trace", raw=trace.encode(), content_type="text/csv"
        )
        deadline = time.time() + 120
        while code == 202 and time.time() < deadline:
            time.sleep(1.0)
            code, job = srv.request("GET", f"{BASE}/jobs/{run['job']['id']}")
            if job["job"]["state"] == "done":
                code, run = srv.request("GET", f"{BASE}/runs/{job['job']['result']}")
            elif job["job"]["state"] == "failed":
                raise AssertionError(job)
            else:
                code = 202
        assert code == 200, run
        code, body = srv.request("GET", f"{BASE}/runs/{run['id']}/trace")
        assert code == 200, body
        assert (
            body.replace("\r\n", "\n") == trace.replace("\r\n", "\n")
            or str(body)[:200] == trace[:200]
        )
    finally:
        srv.stop()
