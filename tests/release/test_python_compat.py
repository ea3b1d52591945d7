"""The package claims Python >= 3.8 (``__plugin_pythoncompat__``, pyproject's
requires-python) but this machine runs 3.11 only: every module must at least parse with the
Python 3.8 grammar, and use no 3.9+ built-ins or syntax that the grammar check cannot see
(annotations are safe: every module postpones them with ``from __future__ import
annotations`` where it uses newer ones)."""

import ast
import glob
import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MODULES = sorted(glob.glob(os.path.join(ROOT, "octoprint_kincomp", "**", "*.py"), recursive=True))
# 3.9+ APIs that 3.8 lacks (str/bytes methods, functools, math, zoneinfo, ...)
NEWER = re.compile(
    r"\.removeprefix\(|\.removesuffix\(|functools\.cache\b|\bfrom functools "
    r"import .*\bcache\b|math\.lcm\(|\bzoneinfo\b|\bgraphlib\b|\btomllib\b|"
    r"\bstrict=True\)|\bkw_only=|\bslots=True"
)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: os.path.relpath(p, ROOT))
def test_module_parses_as_python_38(path):
    with open(path, encoding="utf-8") as f:
        source = f.read()
    tree = ast.parse(source, filename=path, feature_version=(3, 8))
    assert not NEWER.search(source), NEWER.search(source).group(0)
    # PEP 604/585 annotations (X | None, list[int]) only with postponed evaluation
    postponed = any(
        isinstance(n, ast.ImportFrom)
        and n.module == "__future__"
        and any(a.name == "annotations" for a in n.names)
        for n in tree.body
    )
    if not postponed:
        for node in ast.walk(tree):
            ann = getattr(node, "annotation", None) or getattr(node, "returns", None)
            if ann is not None:
                text = ast.get_source_segment(source, ann) or ""
                assert "|" not in text and not re.search(r"\b(list|dict|tuple|set)\[", text), (
                    path,
                    node.lineno,
                    text,
                )
