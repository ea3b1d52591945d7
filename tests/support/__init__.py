"""What the tests share: helpers (a simulated printer, distances), random G-code programs,
the mocked plugin, the real-server utilities, the paths of the sample files and of what a run
leaves (screenshots, figures), and the check that a result applies cleanly."""

import os

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))
ARTIFACTS = os.path.join(ROOT, "test-artifacts")  # what a run leaves to look at (git ignores it)


def assert_applies_cleanly(result) -> None:
    """A result document that says "apply" with nothing to warn about (info findings only)."""
    warned = [f["code"] for f in result["findings"] if f["severity"] != "info"]
    assert not warned, result["findings"]
    assert result["verdict"]["decision"] == "apply", result["verdict"]
