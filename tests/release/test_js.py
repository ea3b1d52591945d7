"""The web UI's logic, unit-tested in node's own test runner (tests/js/*.test.js) with the
libraries OctoPrint ships: run here so that ./test.sh runs them (node is Debian's nodejs,
installed by scripts/bootstrap.sh)."""

import glob
import os
import shutil
import subprocess

import octoprint

from tests.support import ROOT

JS_TESTS = os.path.join(ROOT, "tests", "js")


def test_the_ui_logic_passes_its_unit_tests():
    node = shutil.which("node") or shutil.which("nodejs")
    assert node, "node is not installed (scripts/bootstrap.sh installs Debian's nodejs)"
    files = sorted(glob.glob(os.path.join(JS_TESTS, "*.test.js")))
    assert files
    lib = os.path.join(os.path.dirname(octoprint.__file__), "static", "js", "lib")
    run = subprocess.run(
        [node, "--test", *files],
        capture_output=True,
        text=True,
        env=dict(os.environ, KINCOMP_OCTOPRINT_LIB=lib),
        timeout=300,
    )
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "# fail 0" in run.stdout
