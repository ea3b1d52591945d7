"""Issue 17, case 3 in the plugin: at start-up the data folder loses the temporary files of
processes that no longer run and the outputs of jobs that never finished, and those jobs
are listed as failed; a job that fails on its way leaves nothing behind."""

import json
import os
import subprocess
import sys

from tests.support.blueprint import PREFIX, blueprint_client
from tests.support.mocked_plugin import wait_for


def _dead_pid():
    return subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()


def test_start_up_cleans_the_data_folder_and_reports_interrupted_jobs(tmp_path):
    data = tmp_path / "data"
    (data / "jobs").mkdir(parents=True)
    (data / "runs").mkdir()
    dead = _dead_pid()
    left = [
        data / f".kincomp-{dead}-abcd1234.gcode",
        data / "jobs" / "0123456789ab.gcode",
        data / "runs" / f".kincomp-{dead}-zz99zz99.tmp",
    ]
    for path in left:
        path.write_text("49 MB of a half-written file")
    keep = data / "notes.txt"
    keep.write_text("not ours")
    (data / "jobs.json").write_text(
        json.dumps(
            [
                {
                    "id": "0123456789ab",
                    "kind": "compensate",
                    "path": "big.gcode",
                    "state": "running",
                    "progress": 0.4,
                }
            ]
        )
    )
    ns = blueprint_client(str(tmp_path))
    try:
        assert not any(p.exists() for p in left) and keep.exists()
        jobs = ns.client.get(PREFIX + "/status").get_json()["jobs"]
        assert [(j["path"], j["state"]) for j in jobs] == [("big.gcode", "failed")]
        assert "interrupted" in jobs[0]["error"]
        job = ns.client.get(PREFIX + "/jobs/0123456789ab").get_json()["job"]
        assert job["state"] == "failed"
    finally:
        ns.stop()


def test_a_failing_compensation_job_leaves_no_file(tmp_path):
    ns = blueprint_client(str(tmp_path))
    try:
        with open(os.path.join(ns.uploads, "ok.gcode"), "w") as f:
            f.write("G28\nG1 X10 Y10 Z1 F3000\n" * 1000)
        ns.client.post(
            PREFIX + "/settings",
            json={"enabled": True, "params": {"squareness_um_per_m": {"xy": 500.0}}},
        )
        ns.plugin.jobs.set_paused(False)
        ns.plugin._file_manager.add_file.side_effect = OSError(28, "No space left on device")
        resp = ns.client.post(PREFIX + "/compensate", json={"path": "ok.gcode"})
        assert resp.status_code == 202
        job_id = resp.get_json()["job"]["id"]
        job = ns.plugin.jobs.get(job_id)
        wait_for(lambda: job.state == "failed", timeout=30)
        assert "No space left" in job.error
        data = ns.plugin.get_plugin_data_folder()
        leftovers = [
            os.path.join(d, n)
            for d, _, names in os.walk(data)
            for n in names
            if n.endswith(".gcode")
        ]
        assert leftovers == []
    finally:
        ns.stop()
