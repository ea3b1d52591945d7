"""The background file worker (BackgroundCompensator) on its own: jobs run one after the
other, report their progress in steps, keep failures, and wait while a print runs."""

import threading

from octoprint_kincomp.plugin.jobs import BackgroundCompensator
from tests.support.mocked_plugin import wait_for


def test_a_job_runs_and_reports_progress_in_steps():
    seen = []

    def run(job, progress):
        for i in range(1, 101):
            progress(i / 100)
        job.result = job.path + ".out"

    worker = BackgroundCompensator(run, lambda job: seen.append((job.state, job.progress)))
    job = worker.submit("a.gcode")
    wait_for(lambda: job.state == "done")
    wait_for(lambda: seen and seen[-1][0] == "done")
    assert job.to_dict() == {"path": "a.gcode", "progress": 1.0, "state": "done",
                             "result": "a.gcode.out", "error": None, "report": None}
    assert [s for s, _ in seen[:2]] == ["queued", "running"]
    steps = [p for s, p in seen if s == "running"][1:]
    assert 10 <= len(steps) <= 21 and steps == sorted(steps)  # every ~5 %, not every call


def test_a_failure_is_kept_and_the_next_job_still_runs():
    def run(job, progress):
        if job.path == "bad.gcode":
            raise ValueError("line 3: no such thing")
        job.result = "ok"

    worker = BackgroundCompensator(run, lambda job: None)
    bad, good = worker.submit("bad.gcode"), worker.submit("good.gcode")
    wait_for(lambda: good.state == "done")
    assert bad.state == "failed" and bad.error == "line 3: no such thing"
    assert set(worker.jobs) == {"bad.gcode", "good.gcode"}


def test_jobs_wait_while_paused_and_are_not_queued_twice():
    started = threading.Event()

    def run(job, progress):
        started.set()

    worker = BackgroundCompensator(run, lambda job: None)
    worker.set_paused(True)
    job = worker.submit("a.gcode")
    assert worker.submit("a.gcode") is job  # still queued: the same job
    assert not started.wait(0.2) and job.state == "queued"
    worker.set_paused(False)
    wait_for(lambda: job.state == "done")
    assert worker.submit("a.gcode") is not job  # done: a new one
