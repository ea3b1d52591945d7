"""Compatibility (issue 14): KinComp loads and its end-to-end smoke test passes on the oldest
supported OctoPrint release line (1.10.x, the latest patch on PyPI, in its own environment
made by scripts/compat-venv.sh) and on the newest one (this environment's OctoPrint).

Each runs a real ``octoprint serve`` with the virtual printer: the plugin is loaded (log,
``/plugin/kincomp/status``), its settings page and tab render into the web UI, and commands
sent through ``/api/printer/command`` leave in serial.log compensated exactly once (equal to
an offline compensation of the same commands)."""

import os
import shutil
import subprocess
import sys

import pytest

from octoprint_kincomp import __version__
from octoprint_kincomp.tools.devserver import ADMIN, DevServer
from tests.support.serverutil import (
    BrowserSession,
    marker,
    offline,
    sent,
    settings,
    status,
)

pytestmark = pytest.mark.slow

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OLDEST = "1.10"  # the oldest OctoPrint release line KinComp supports (pyproject: >=1.10.0)
PARAMS = {
    "squareness_um_per_m": {"xy": 800.0, "xz": -300.0, "yz": 200.0},
    "scale_ppm": {"x": 500.0, "y": -400.0, "z": 0.0},
    "backlash": {"x": 30.0, "y": 25.0},
}
COMMANDS = [
    "G90",
    "G21",
    "M82",
    "G28",
    "G1 Z5 F600",
    "G1 X50 Y60 F3000",
    "G0 X120 Y30",
    "G2 X140 Y30 I10 J0 F1200",
    "G91",
    "G1 X-5 Y5",
    "G90",
    "M18",
]


def _oldest_python() -> str:
    """The compatibility environment's python, made (or checked, quickly) by the script
    the test set-up runs (scripts/bootstrap.sh)."""
    venv = os.environ.get("KINCOMP_COMPAT_VENV") or os.path.join(ROOT, ".venv-op110")
    env = dict(os.environ, KINCOMP_COMPAT_VENV=venv)
    run = subprocess.run(
        [os.path.join(ROOT, "scripts", "compat-venv.sh")],
        env=env,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert run.returncode == 0, f"scripts/compat-venv.sh failed:\n{run.stderr[-3000:]}"
    return os.path.join(venv, "bin", "python")


def _octoprint_version(python: str) -> str:
    return subprocess.run(
        [python, "-c", "import octoprint; print(octoprint.__version__)"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()


@pytest.fixture(scope="module")
def started(tmp_path_factory):
    """The module's servers, one per release line, each started on its first use and
    stopped at the module's end (however the tests of the two lines are ordered)."""
    servers = {}

    def get(line):
        if line not in servers:
            servers[line] = _start(line, tmp_path_factory)
        return servers[line]

    try:
        yield get
    finally:
        for srv, version in servers.values():
            srv.stop()
            keep = os.environ.get("KINCOMP_E2E_KEEP")
            if keep:
                shutil.copytree(
                    os.path.join(srv.basedir, "logs"),
                    os.path.join(keep, f"compat-{version}"),
                    dirs_exist_ok=True,
                )


def _start(line, tmp_path_factory):
    python = _oldest_python() if line == "oldest" else sys.executable
    version = _octoprint_version(python)
    if line == "oldest":
        assert version.startswith(OLDEST + "."), version
    base = str(tmp_path_factory.mktemp(f"octoprint-{line}"))
    srv = DevServer(base, kincomp={"enabled": False}, python=python)
    srv.start()
    try:
        srv.connect()
    except BaseException:
        srv.stop()
        raise
    return srv, version


@pytest.fixture(params=["oldest", "newest"])
def compat_server(request, started):
    return started(request.param)


def test_plugin_loads_and_renders(compat_server):
    srv, version = compat_server
    code, info = srv.request("GET", "/api/version")
    assert code == 200 and info["server"] == version
    st = status(srv)
    assert st["version"] == __version__
    assert set(st["equivalents"]["export"]) == {"klipper", "marlin", "reprapfirmware"}
    log = srv.octoprint_log()
    assert f"KinComp ({__version__})" in log  # the plugin list at start-up
    assert f"KinComp {__version__} ready" in log
    problems = [
        l
        for l in log.splitlines()
        if "kincomp" in l.lower() and (" - ERROR - " in l or "Traceback" in l)
    ]
    assert not problems, problems
    # the settings page and the Calibration tab are in the page OctoPrint renders
    web = BrowserSession(srv).login(ADMIN, srv.logins[ADMIN]["password"])
    code, html = web.open("GET", "/")
    assert code == 200
    assert 'id="kincomp_settings"' in html and 'id="kincomp_tab"' in html


def test_commands_go_out_compensated_once(compat_server):
    srv, _ = compat_server
    # (commands queued at once: the home is given, see test_server.py)
    settings(srv, enabled=True, mode="on_the_fly", params=PARAMS, home_mm=[0.0, 0.0, 0.0])
    start = marker(srv)
    code, _ = srv.request("POST", "/api/printer/command", {"commands": COMMANDS})
    assert code == 204
    end = marker(srv)
    got = sent(srv, after=start, until=end)
    assert got == offline(srv, COMMANDS)
    assert "G1 X50 Y60 F3000" not in got  # compensated...
    assert len(got) > len(COMMANDS)  # ...and the arc linearised
    assert all(c in got for c in ("G90", "G91", "M82", "M18", "G28"))
    settings(srv, enabled=False, home_mm=None)
