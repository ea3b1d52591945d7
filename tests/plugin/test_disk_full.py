"""Issue 26, case 6: a full disk on every writing endpoint answers 507 with a message and
leaves nothing half-written (no temporary file, no run or campaign without its data, no
trace without its run). ENOSPC is simulated in the one place every KinComp file is written
(``core.atomic``): the write fails after some bytes, as a full disk makes it."""

import contextlib
import errno
import json
import os

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.core import atomic
from octoprint_kincomp.simulator.printer import simulate_program, volume_truth
from tests.support.blueprint import PREFIX, blueprint_client


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path), stored={"enabled": False})
    ns.data = os.path.join(str(tmp_path), "data")
    yield ns
    ns.stop()


def _files(folder):
    return sorted(
        os.path.relpath(os.path.join(d, n), folder)
        for d, _, names in os.walk(folder)
        for n in names
    )


@pytest.fixture
def disk_full(monkeypatch):
    real = atomic.replacing

    @contextlib.contextmanager
    def full(target, suffix=".tmp"):
        with real(target, suffix) as f:

            class Full:
                def write(self, data):
                    f.write(data[:10])
                    raise OSError(errno.ENOSPC, "No space left on device")

                def __getattr__(self, name):
                    return getattr(f, name)

            yield Full()

    def on():
        monkeypatch.setattr(atomic, "replacing", full)

    return on


def _trace(spec=None, params_hash=None):
    text = generate(TestSpec(**(spec or {})), params_hash=params_hash)
    spec, prog_hash = spec_from_program(text)
    return simulate_program(text, volume_truth(noise_um=0.5), spec, prog_hash).to_text()


def _post(api, path, body=None, raw=None, content_type="application/json"):
    data = raw if raw is not None else json.dumps(body)
    return api.client.post(PREFIX + path, data=data, content_type=content_type)


def test_every_writing_endpoint_answers_507_and_keeps_nothing(api, disk_full):
    # before the disk fills: a campaign to add a test's trace to
    resp = _post(api, "/campaign/plan", {"radius_xy": 50})
    assert resp.status_code == 200, resp.get_json()
    doc = resp.get_json()
    cid = doc["id"]
    step_trace = _trace(doc["steps"][0]["spec"], doc["params_hash"]).encode()
    before = _files(api.data)
    runs_before = api.client.get(PREFIX + "/runs").get_json()["runs"]
    disk_full()
    trace = _trace().encode()
    calls = [
        ("/analyze", {"summary": {"plane": "XY", "squareness_um_per_m": 40.0}}, None),
        (
            "/artifact/analyze",
            {"square": {"plane": "XY", "ac": 141.5, "bd": 141.3, "ad": 100.0}},
            None,
        ),
        ("/campaign/plan", {"radius_xy": 50}, None),
        ("/trace", None, trace),
        (f"/campaigns/{cid}/steps/1/trace", None, step_trace),
    ]
    for path, body, raw in calls:
        resp = _post(api, path, body, raw, "application/json" if raw is None else "text/csv")
        assert resp.status_code == 507, (path, resp.status_code, resp.get_data()[:300])
        assert "disk is full" in resp.get_json()["error"]
        assert _files(api.data) == before, path  # nothing half-written, no temp file
    assert api.client.get(PREFIX + "/runs").get_json()["runs"] == runs_before
    assert not any(".kincomp-" in f for f in _files(api.data))


def test_a_new_runs_trace_is_not_kept_without_it(tmp_path, monkeypatch):
    from octoprint_kincomp.service.calibration import run_store as runs_module
    from octoprint_kincomp.service.calibration.run_store import RunStore

    store = RunStore(str(tmp_path))
    real, calls = runs_module.write_atomic, []

    def second_fails(path, data):
        calls.append(path)
        if len(calls) == 2:  # the run's JSON, after its trace
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(runs_module, "write_atomic", second_fails)
    run = {"id": store.new_id(), "diagnostics": {}}
    with pytest.raises(OSError):
        store.save(run, b"t,r\n0,0\n")
    assert os.listdir(store.folder) == []
    assert os.path.isabs(store.folder)
