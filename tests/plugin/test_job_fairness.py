"""Issue 26, case 4: read-only users cannot block admins' jobs. A per-user quota, places
kept for admins (whose jobs also run first), one job per file whatever the path's spelling
(``x/../big.gcode``, ``/big.gcode``), and a cancel for a job (its owner or an admin)."""

import json
import os
import threading
from unittest import mock

import pytest

from octoprint_kincomp.service.files.jobs import CANCELLED, JobQueue, QueueFull
from octoprint_kincomp.service.files.worker import WorkerProcess
from tests.support.blueprint import PREFIX, blueprint_client
from tests.support.mocked_plugin import wait_for


def _blocked(gate):
    return lambda job, progress: gate.wait(10)


def test_read_only_users_have_a_quota_and_leave_places_for_admins():
    gate = threading.Event()
    q = JobQueue(lambda job: None, limit=8, per_user=2, reserved=3)
    try:
        q.submit("dryrun", "a0", _blocked(gate), owner="ro1", admin=False)
        q.submit("dryrun", "a1", _blocked(gate), owner="ro1", admin=False)
        with pytest.raises(QueueFull) as exc:
            q.submit("dryrun", "a2", _blocked(gate), owner="ro1", admin=False)
        assert exc.value.mine
        for i, user in enumerate(["ro2", "ro2", "ro3"]):
            q.submit("dryrun", f"b{i}", _blocked(gate), owner=user, admin=False)
        # five read-only jobs: the other three places are the admins'
        with pytest.raises(QueueFull) as exc:
            q.submit("dryrun", "c", _blocked(gate), owner="ro4", admin=False)
        assert not exc.value.mine
        admin_jobs = [
            q.submit("compensate", f"d{i}", _blocked(gate), owner="admin", admin=True)
            for i in range(3)
        ]
        with pytest.raises(QueueFull):
            q.submit("compensate", "e", _blocked(gate), owner="admin", admin=True)
        # the same file is the same job, whoever asks
        assert q.submit("dryrun", "a0", _blocked(gate), owner="ro9", admin=False).owner == "ro1"
    finally:
        gate.set()
    wait_for(lambda: all(j.state == "done" for j in admin_jobs))


def test_admins_jobs_run_first():
    order, first = [], threading.Event()
    q = JobQueue(lambda job: None)

    def run(job, progress):
        first.wait(10)
        order.append(job.path)

    job = q.submit("dryrun", "ro-0", run, owner="ro", admin=False)  # runs at once, waits
    wait_for(lambda: job.state == "running")
    q.submit("dryrun", "ro-1", run, owner="ro", admin=False)
    q.submit("dryrun", "ro2-0", run, owner="ro2", admin=False)
    last = q.submit("compensate", "admin-0", run, owner="admin", admin=True)
    first.set()
    wait_for(lambda: len(order) == 4)
    assert order[:2] == ["ro-0", "admin-0"] and last.state == "done"


def test_a_queued_job_is_cancelled_at_once_a_running_one_at_its_next_step():
    gate, steps = threading.Event(), []

    def slow(job, progress):
        for i in range(1000):
            steps.append(i)
            progress(i / 1000)
            gate.wait(0.01)

    q = JobQueue(lambda job: None)
    running = q.submit("dryrun", "a", slow)
    queued = q.submit("dryrun", "b", lambda j, p: None)
    wait_for(lambda: running.state == "running" and steps)
    assert q.cancel(queued) and queued.state == "failed" and queued.error == CANCELLED
    assert q.cancel(running)
    assert not q.cancel(running)  # issue 37 row 10: a second cancel does nothing (409)
    wait_for(lambda: running.state == "failed")
    assert running.error == CANCELLED and len(steps) < 1000
    assert not q.cancel(running)  # finished: nothing to cancel
    assert q.submit("dryrun", "b", lambda j, p: None) is not queued  # a new one


def test_cancelling_a_job_in_the_worker_process_ends_it_and_the_next_runs(tmp_path):
    src = tmp_path / "big.gcode"
    src.write_text(
        "G28\n" + "".join(f"G1 X{i % 200}.{i % 7} Y{i % 190}.{i % 3}\n" for i in range(400_000))
    )
    worker = WorkerProcess()
    q = JobQueue(lambda job: None, worker=worker)
    args = {
        "src": str(src),
        "dst": str(tmp_path / "out.gcode"),
        "params": {"scale_ppm": {"x": 100.0}},
        "options": {"chord_tol_mm": 0.01},
    }

    def run(job, progress):
        job.report = worker.call(job.id, "compensate", args, progress)

    try:
        job = q.submit("compensate", "big.gcode", run)
        wait_for(lambda: job.progress > 0.0, timeout=60)
        pid = worker.pid
        assert q.cancel(job)
        wait_for(lambda: job.state == "failed", timeout=30)
        assert job.error == CANCELLED and worker.pid != pid
        assert not (tmp_path / "out.gcode").exists()
        assert not [n for n in os.listdir(tmp_path) if n.startswith(".kincomp-")]
        small = tmp_path / "small.gcode"
        small.write_text("G28\nG1 X10 Y10\n")
        args2 = dict(args, src=str(small), dst=None, dry_run=True)
        nxt = q.submit(
            "dryrun",
            "small.gcode",
            lambda j, p: setattr(j, "report", worker.call(j.id, "compensate", args2, p)),
        )
        wait_for(lambda: nxt.state in ("done", "failed"), timeout=60)
        assert nxt.state == "done", nxt.error
    finally:
        worker.stop()


class _GatedWorker:
    """Jobs that wait for ``gate`` (then report a dry run of nothing)."""

    pid = None

    def __init__(self):
        self.gate = threading.Event()

    def call(self, job_id, kind, args, progress):
        while not self.gate.wait(0.01):
            progress(0.5)
        return {"report": {"moves": 0}}

    def stop(self):
        pass

    def stop_if_idle(self, idle_s):
        pass


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path), stored={"enabled": True})
    for i in range(4):
        with open(os.path.join(ns.uploads, f"big{i}.gcode"), "w") as f:
            f.write("G28\nG1 X10 Y10\n")
    os.makedirs(os.path.join(ns.uploads, "x"), exist_ok=True)
    ns.worker = ns.plugin.jobs.worker = _GatedWorker()
    yield ns
    ns.worker.gate.set()
    ns.stop()


def _as(user, admin):
    return mock.patch("octoprint_kincomp.plugin.http.current_user", return_value=(user, admin))


def test_one_job_per_file_whatever_the_spelling(api):
    ids = set()
    with _as("ro", False):
        for spelling in ("big0.gcode", "x/../big0.gcode", "/big0.gcode", "x//../big0.gcode"):
            resp = api.client.get(PREFIX + "/dryrun?path=" + spelling)
            assert resp.status_code == 202, (spelling, resp.get_json())
            ids.add(resp.get_json()["job"]["id"])
            assert resp.get_json()["job"]["path"] == "big0.gcode"
    assert len(ids) == 1


def test_a_read_only_user_cannot_block_an_admin_and_jobs_can_be_cancelled(api):
    with _as("ro", False):
        codes = [
            api.client.get(PREFIX + f"/dryrun?path=big{i}.gcode").status_code for i in range(3)
        ]
    assert codes == [202, 202, 429]
    jobs = [j for j in api.plugin.jobs.jobs.values() if j.active]
    with _as("admin", True):
        resp = api.client.post(
            PREFIX + "/compensate",
            data=json.dumps({"path": "big3.gcode"}),
            content_type="application/json",
        )
        assert resp.status_code == 202, resp.get_json()
    ro_job = jobs[1]
    with _as("other", False):  # someone else's job: no
        resp = api.client.post(PREFIX + f"/jobs/{ro_job.id}/cancel")
        assert resp.status_code == 403
    with _as("ro", False):  # the owner: yes
        resp = api.client.post(PREFIX + f"/jobs/{ro_job.id}/cancel")
        assert resp.status_code == 200 and resp.get_json()["job"]["error"] == CANCELLED
        assert api.client.post(PREFIX + f"/jobs/{ro_job.id}/cancel").status_code == 409
        assert api.client.get(PREFIX + "/dryrun?path=big2.gcode").status_code == 202
    with _as("admin", True):  # an admin: anyone's
        resp = api.client.post(PREFIX + f"/jobs/{jobs[0].id}/cancel")
        assert resp.status_code == 200
        wait_for(lambda: jobs[0].state == "failed")
        assert jobs[0].error == CANCELLED
        assert api.client.post(PREFIX + "/jobs/nope/cancel").status_code == 404
