"""The job queue (JobQueue) on its own: jobs run one after the other, report their progress
in steps, keep failures, wait while a print runs (compensations only), one job of a kind per
file, a limit (QueueFull), and the job list over a restart (an interrupted job is failed).
The worker process (WorkerProcess): real work in a child at nice 19, and a killed child
fails the job instead of hanging it (issue 17)."""

import json
import os
import threading

import pytest

from octoprint_kincomp.core.params import Params
from octoprint_kincomp.service.files.jobs import INTERRUPTED, JobQueue, QueueFull
from octoprint_kincomp.service.files.worker import WorkerDied, WorkerProcess
from tests.support.mocked_plugin import wait_for


def test_a_job_runs_and_reports_progress_in_steps():
    seen = []

    def run(job, progress):
        for i in range(1, 101):
            progress(i / 100)
        job.result = job.path + ".out"

    queue = JobQueue(lambda job: seen.append((job.state, job.progress)))
    job = queue.submit("compensate", "a.gcode", run)
    wait_for(lambda: job.state == "done")
    wait_for(lambda: seen and seen[-1][0] == "done")
    d = job.to_dict()
    assert (d["kind"], d["path"], d["progress"], d["state"], d["result"], d["error"]) == (
        "compensate",
        "a.gcode",
        1.0,
        "done",
        "a.gcode.out",
        None,
    )
    assert [s for s, _ in seen[:2]] == ["queued", "running"]
    steps = [p for s, p in seen if s == "running"][1:]
    assert 10 <= len(steps) <= 21 and steps == sorted(steps)  # every ~5 %, not every call


def test_a_failure_is_kept_and_the_next_job_still_runs():
    def run(job, progress):
        if job.path == "bad.gcode":
            raise ValueError("line 3: no such thing")
        job.result = "ok"

    queue = JobQueue(lambda job: None)
    bad = queue.submit("compensate", "bad.gcode", run)
    good = queue.submit("compensate", "good.gcode", run)
    wait_for(lambda: good.state == "done")
    assert bad.state == "failed" and bad.error == "line 3: no such thing"
    assert isinstance(bad.exception, ValueError)
    assert {j.path for j in queue.jobs.values()} == {"bad.gcode", "good.gcode"}


def test_compensations_wait_while_printing_dry_runs_do_not_and_none_runs_twice():
    started = threading.Event()

    def run(job, progress):
        started.set()

    queue = JobQueue(lambda job: None)
    queue.set_paused(True)
    job = queue.submit("compensate", "a.gcode", run, held_while_printing=True)
    assert queue.submit("compensate", "a.gcode", run) is job  # still queued: the same job
    assert not started.wait(0.2) and job.state == "queued"
    dry = queue.submit("dryrun", "a.gcode", run)  # another kind: its own job, not held
    assert dry is not job
    wait_for(lambda: dry.state == "done")
    assert job.state == "queued"
    queue.set_paused(False)
    wait_for(lambda: job.state == "done")
    assert queue.submit("compensate", "a.gcode", run) is not job  # done: a new one


def test_the_queue_has_a_limit():
    gate = threading.Event()
    queue = JobQueue(lambda job: None, limit=3)
    jobs = [queue.submit("dryrun", f"{i}.gcode", lambda j, p: gate.wait(10)) for i in range(3)]
    with pytest.raises(QueueFull):
        queue.submit("dryrun", "3.gcode", lambda j, p: None)
    assert queue.submit("dryrun", "1.gcode", lambda j, p: None) is jobs[1]  # same file: 202
    gate.set()
    wait_for(lambda: all(j.state == "done" for j in jobs))
    queue.submit("dryrun", "3.gcode", lambda j, p: None)  # room again


def test_the_job_list_survives_a_restart_and_interrupted_jobs_are_failed(tmp_path):
    history = str(tmp_path / "jobs.json")
    gate = threading.Event()
    queue = JobQueue(lambda job: None, history=history)
    done = queue.submit("compensate", "done.gcode", lambda j, p: None)
    wait_for(lambda: done.state == "done")
    running = queue.submit("compensate", "big.gcode", lambda j, p: gate.wait(10))
    waiting = queue.submit("compensate", "next.gcode", lambda j, p: None)
    wait_for(lambda: running.state == "running")
    # the server is killed here; a new one reads the list
    again = JobQueue(lambda job: None, history=history)
    got = {j.path: j for j in again.jobs.values()}
    assert got["done.gcode"].state == "done"
    for path in ("big.gcode", "next.gcode"):
        assert got[path].state == "failed" and got[path].error == INTERRUPTED
    with open(history) as f:
        assert {d["id"] for d in json.load(f)} == {done.id, running.id, waiting.id}
    gate.set()


def test_the_worker_process_runs_a_dry_run_at_low_priority(tmp_path):
    src = tmp_path / "a.gcode"
    src.write_text("G28\nG1 X10 Y10 Z1 F3000\nG1 X50 Y20\n")
    worker = WorkerProcess()
    try:
        steps = []
        params = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}}).to_dict()
        result = worker.call(
            "j1",
            "compensate",
            {
                "src": str(src),
                "dst": None,
                "params": params,
                "options": {"home_mm": (0, 0, 0)},
                "dry_run": True,
            },
            steps.append,
        )
        assert result["report"]["moves_compensated"] == 2 and result["precompensated"] is None
        with open(f"/proc/{worker.pid}/stat") as f:
            assert int(f.read().rsplit(")", 1)[1].split()[16]) == 19  # nice
        # an error in the child comes back as the exception it is
        with pytest.raises(FileNotFoundError):
            worker.call(
                "j2",
                "compensate",
                {"src": str(tmp_path / "none.gcode"), "dst": None, "params": params, "options": {}},
                steps.append,
            )
    finally:
        worker.stop()
    assert worker.pid is None


def test_a_killed_worker_fails_the_job_and_leaves_no_temp_file(tmp_path):
    src = tmp_path / "big.gcode"
    with open(src, "w") as f:
        for i in range(400000):
            f.write(f"G1 X{i % 200} Y{(i * 7) % 200} Z{1 + i % 3} F3000\n")
    out = tmp_path / "out" / "job.gcode"
    out.parent.mkdir()
    worker = WorkerProcess()
    params = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}}).to_dict()

    def progress(frac):
        if frac > 0.05 and worker.pid:
            os.kill(worker.pid, 9)  # SIGKILL: nothing in the child can clean up

    with pytest.raises(WorkerDied):
        worker.call(
            "j",
            "compensate",
            {"src": str(src), "dst": str(out), "params": params, "options": {}},
            progress,
        )
    from octoprint_kincomp.core.atomic import clean_stale

    left = os.listdir(out.parent)
    assert all(n.startswith(".kincomp-") for n in left)  # only its temp file, if any
    clean_stale(str(out.parent))  # what the plugin does at start-up
    assert os.listdir(out.parent) == []
