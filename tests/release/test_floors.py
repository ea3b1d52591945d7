"""The package's floors (docs/architecture.md): a module imports only its own floor and the
floors below it, and nothing below ``plugin/`` imports OctoPrint or Flask."""

import ast
import glob
import os

from tests.support import ROOT

PKG = "octoprint_kincomp"
# lowest first; the package root (OctoPrint's metadata and entry point) and __main__ stand
# above them all
FLOORS = [
    "core",
    "engines",
    "firmware",
    "calibration",
    "simulator",
    "sensor",
    "service",
    "plugin",
    "tools",
    "cli",
]
SERVER_LIBRARIES = {"octoprint", "flask", "flask_babel", "flask_login", "werkzeug"}


def _imports(path, module):
    """(absolute module names imported by the file at ``path``, whose own name is ``module``)."""
    tree = ast.parse(open(path, encoding="utf-8").read())
    package = module.rsplit(".", 1)[0] if not path.endswith("__init__.py") else module
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = parts[: len(parts) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
                yield name
                if not node.module:  # from . import a, b: the submodules
                    for alias in node.names:
                        yield name + "." + alias.name
            else:
                yield node.module


def _modules():
    for path in glob.glob(os.path.join(ROOT, PKG, "**", "*.py"), recursive=True):
        rel = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
        if rel.endswith(".__init__"):
            rel = rel[: -len(".__init__")]
        yield path, rel


def _floor(module):
    parts = module.split(".")
    if len(parts) < 2 or parts[0] != PKG:
        return None
    return parts[1] if parts[1] in FLOORS else None


def test_every_module_sits_on_a_floor():
    stray = [m for _, m in _modules() if m not in (PKG, PKG + ".__main__") and _floor(m) is None]
    assert stray == []


def test_imports_go_only_down():
    wrong = []
    for path, module in _modules():
        own = _floor(module)
        if own is None:
            continue
        for name in _imports(path, module):
            other = _floor(name or "")
            if name in (PKG,) or (other is None and (name or "").startswith(PKG + ".")):
                wrong.append((module, name, "the package root"))
            elif other is not None and FLOORS.index(other) > FLOORS.index(own):
                wrong.append((module, name, f"{own} imports {other}"))
    assert wrong == []


def test_nothing_below_the_plugin_imports_octoprint_or_flask():
    below = FLOORS[: FLOORS.index("plugin")]
    wrong = []
    for path, module in _modules():
        if _floor(module) not in below:
            continue
        for name in _imports(path, module):
            if (name or "").split(".")[0] in SERVER_LIBRARIES:
                wrong.append((module, name))
    assert wrong == []


def test_the_architecture_page_names_every_room():
    """Each package folder of the tree is named on docs/architecture.md (as ``room/``)."""
    text = open(os.path.join(ROOT, "docs", "architecture.md"), encoding="utf-8").read()
    base = os.path.join(ROOT, PKG)
    rooms = sorted(
        os.path.relpath(os.path.dirname(p), base).replace(os.sep, "/")
        for p in glob.glob(os.path.join(base, "**", "__init__.py"), recursive=True)
        if os.path.dirname(p) != base
    )
    assert len(rooms) >= 20
    missing = [r for r in rooms if f"`{r}/`" not in text and f"`{r.split('/')[-1]}/`" not in text]
    assert missing == []
