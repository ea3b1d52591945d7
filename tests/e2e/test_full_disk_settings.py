"""Issue 37 row 8 on a real OctoPrint server: the settings dialog's save on a full disk.

OctoPrint's ``POST /api/settings`` hands KinComp its part (``on_settings_save``) and then
writes config.yaml. On a full disk the write failed (500) while the compensator already used
the new parameters and config.yaml kept the old ones; the next unrelated save stored them.
Here the server's basedir is a small tmpfs filled to the last byte: the failed save must
leave the compensator, KinComp's settings and config.yaml as they were, and the next save
after space is freed must not bring the refused value back. (The in-process version:
tests/plugin/test_concurrent_saves.py.)

A tmpfs needs root (the test set-up's containers run as root); elsewhere the test is
skipped and says why.
"""

import errno
import os
import subprocess

import pytest
import yaml

from tests.support.serverutil import status

pytestmark = pytest.mark.slow

CALIBRATION = {
    "squareness_um_per_m": {"xy": 294.8, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 120.0, "y": -80.0, "z": 0.0},
    "backlash": {"x": 40.0, "y": 30.0, "z": 0.0},
}
REFUSED_XY = 1234.0


@pytest.fixture
def small_disk(tmp_path):
    """A 24 MB tmpfs at ``tmp_path/disk``, unmounted at the end."""
    if not (hasattr(os, "geteuid") and os.geteuid() == 0):
        pytest.skip("a full disk needs a tmpfs, which needs root")
    where = tmp_path / "disk"
    where.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=24m", "tmpfs", str(where)], capture_output=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)])


def _fill(folder):
    """Writes ``folder/filler`` until the disk is full; returns its path."""
    path = os.path.join(folder, "filler")
    block = b"\0" * (1 << 16)
    with open(path, "wb", buffering=0) as f:
        for size in (1 << 16, 4096, 512, 1):
            try:
                while True:
                    f.write(block[:size])
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
    return path


def _stored_xy(base):
    with open(os.path.join(base, "config.yaml")) as f:
        config = yaml.safe_load(f) or {}
    return config["plugins"]["kincomp"]["params"]["squareness_um_per_m"]["xy"]


def _dialog_save(srv, kincomp):
    return srv.request("POST", "/api/settings", {"plugins": {"kincomp": kincomp}})


def test_a_dialog_save_on_a_full_disk_leaves_nothing_in_force(new_server, small_disk):
    srv = new_server(name="disk/op", kincomp={"enabled": True, "params": CALIBRATION})
    before = status(srv)
    assert before["settings"]["params"]["squareness_um_per_m"]["xy"] == 294.8
    filler = _fill(srv.basedir)
    try:
        code, _ = _dialog_save(srv, {"params": {"squareness_um_per_m": {"xy": REFUSED_XY}}})
        assert code >= 500, f"the save on a full disk answered {code}"
        after = status(srv)
        assert after["compensation"]["params_hash"] == before["compensation"]["params_hash"]
        assert after["settings"]["params"]["squareness_um_per_m"]["xy"] == 294.8
        assert _stored_xy(srv.basedir) == 294.8
    finally:
        os.remove(filler)
    # the next unrelated save, with room again: the refused value does not come back
    code, _ = _dialog_save(srv, {"decimals": 4})
    assert code == 200, code
    assert _stored_xy(srv.basedir) == 294.8
    final = status(srv)
    assert final["settings"]["decimals"] == 4
    assert final["compensation"]["params_hash"] == before["compensation"]["params_hash"]
