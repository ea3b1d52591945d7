"""The sensor floor imports core/ and ballbar/ (and numpy, pyserial, the standard library),
never OctoPrint, flask or the plugin/ floor."""

import ast
import glob
import os
import sys

import pytest

from tests.support import ROOT

ALLOWED_ABSOLUTE = {"numpy", "serial", "__future__"}
ALLOWED_RELATIVE = {"core", "ballbar"}


def test_sensor_imports_only_lower_floors():
    stdlib = getattr(sys, "stdlib_module_names", None)
    if stdlib is None:
        pytest.skip("needs Python 3.10+ to know the standard library's modules")
    files = glob.glob(os.path.join(ROOT, "octoprint_kincomp", "sensor", "*.py"))
    assert len(files) >= 10
    for path in files:
        tree = ast.parse(open(path, encoding="utf-8").read())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level == 1:
                    continue  # the sensor floor itself
                if node.level == 2:
                    top = (node.module or "").split(".")[0]
                    assert top in ALLOWED_RELATIVE, (path, node.module)
                    continue
                names = [(node.module or "").split(".")[0]]
            else:
                continue
            for name in names:
                assert name in ALLOWED_ABSOLUTE or name in stdlib, (path, name)
