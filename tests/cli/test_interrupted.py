"""Issue 17, cases 3 and 5 on the command line: editing in place leaves no temporary file
when interrupted (SIGTERM, SIGINT) and cleans those of killed runs (only its own pattern, only
of processes that no longer run); in place through a symbolic link edits the link's target;
an unwritable folder is reported with the user's file, not the temporary one."""

import json
import os
import signal
import subprocess
import sys
import time
from unittest import mock

import pytest

from octoprint_kincomp.cli import main
from octoprint_kincomp.core.params import Params

SKEW = {"squareness_um_per_m": {"xy": 500.0, "xz": 0.0, "yz": 0.0}}
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _files(tmp_path, moves=10):
    src = tmp_path / "part.gcode"
    with open(src, "w") as f:
        f.write("G28\n")
        for i in range(moves):
            f.write(
                f"G1 X{10 + i % 150} Y{10 + (i * 7) % 150} Z{0.2 + (i % 50) * 0.2:.1f} "
                f"E{i * 0.01:.2f} F3000 ; move {i}\n"
            )
    params = tmp_path / "p.json"
    params.write_text(json.dumps(SKEW))
    return str(src), str(params)


def temps(folder):
    return sorted(n for n in os.listdir(folder) if n.startswith(".kincomp-"))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_an_interrupted_in_place_edit_leaves_no_temp_file(tmp_path, sig):
    src, params = _files(tmp_path, moves=1_000_000)
    with open(src, "rb") as f:
        original = f.read()
    env = dict(os.environ, PYTHONPATH=ROOT)
    # SIGINT as a terminal gives it: a suite started in the background (nohup, &) passes on an
    # ignored SIGINT, and Python then installs no KeyboardInterrupt handler (exit 0 here once)
    proc = subprocess.Popen(
        [sys.executable, "-m", "octoprint_kincomp", "compensate", src, "--params", params],
        env=env,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.time() + 120
    while not temps(tmp_path) or os.path.getsize(tmp_path / temps(tmp_path)[0]) == 0:
        assert proc.poll() is None and time.time() < deadline, "never started writing"
        time.sleep(0.001)
    # held while the signal is sent: the compiled engine writes the 50 MB file in a third of
    # a second, which once ran out before the signal on a loaded machine (exit 0)
    proc.send_signal(signal.SIGSTOP)
    assert proc.poll() is None, "finished before it could be interrupted"
    proc.send_signal(sig)
    proc.send_signal(signal.SIGCONT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    assert b"interrupted" in err
    assert temps(tmp_path) == []
    with open(src, "rb") as f:
        assert f.read() == original  # untouched


def test_stale_temp_files_of_dead_runs_are_removed_and_only_those(tmp_path):
    src, params = _files(tmp_path)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()
    stale = tmp_path / f".kincomp-{dead}-abcd1234.gcode"
    stale.write_text("half a file")
    alive = tmp_path / f".kincomp-{os.getppid()}-abcd1234.gcode"  # a running writer's
    alive.write_text("being written")
    other = tmp_path / ".kincomp-notes.txt"  # not ours
    other.write_text("keep")
    assert main(["compensate", src, "--params", params]) == 0
    assert sorted(temps(tmp_path)) == sorted([alive.name, other.name])


def test_in_place_through_a_link_edits_its_target(tmp_path):
    src, params = _files(tmp_path)
    link = tmp_path / "link.gcode"
    os.symlink(src, link)
    assert main(["compensate", str(link), "--params", params]) == 0
    assert os.path.islink(link) and os.readlink(link) == src
    with open(src) as f:
        assert Params.from_dict(SKEW).hash() in f.readline()  # the target is compensated


def test_an_unwritable_folder_names_the_users_file(tmp_path, capsys):
    src, params = _files(tmp_path)
    denied = PermissionError(13, "Permission denied", str(tmp_path / ".kincomp-1-abcdefgh.gcode"))
    with mock.patch("tempfile.mkstemp", side_effect=denied):  # (root may write anywhere)
        assert main(["compensate", src, "--params", params]) == 1
    err = capsys.readouterr().err
    assert f"{src}: Permission denied" in err and ".kincomp-" not in err
