"""The machine lock of the test run under -n (tests/conftest.py holds it around every test):
a test holds it shared, an ``alone`` test (it measures rates or times) exclusively, so that
nothing else runs while it measures. ``measured()``: an ``alone`` test whose measurement is
over lets the other worker go on while it finishes (waits for what it started to end, cleans
up)."""

from __future__ import annotations

import contextlib
import fcntl
import os

SESSION_DIR_ENV = "KINCOMP_TEST_SESSION_DIR"
_held = {}  # "run": the open run lock of this process's current test, "exclusive": bool


@contextlib.contextmanager
def hold(exclusive: bool):
    """Held around one test: shared, or ``exclusive`` (it waits for the other worker's
    current test; the other's next test waits at the gate meanwhile)."""
    folder = os.environ.get(SESSION_DIR_ENV)
    if not os.environ.get("PYTEST_XDIST_WORKER") or not folder:
        yield
        return
    mode = fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH
    with open(os.path.join(folder, "gate.lock"), "a") as gate:
        with open(os.path.join(folder, "run.lock"), "a") as run:
            fcntl.flock(gate, mode)
            fcntl.flock(run, mode)
            if not exclusive:
                fcntl.flock(gate, fcntl.LOCK_UN)
            _held.update(run=run, gate=gate, exclusive=exclusive)
            try:
                yield
            finally:
                _held.clear()
                fcntl.flock(run, fcntl.LOCK_UN)
                fcntl.flock(gate, fcntl.LOCK_UN)


def measured() -> None:
    """The current ``alone`` test has measured: from here on it shares the machine (the other
    worker's tests run beside what is left of it). Nothing to do outside -n or when shared."""
    if not _held.get("exclusive"):
        return
    fcntl.flock(_held["run"], fcntl.LOCK_SH)  # (from exclusive: the others may share now)
    fcntl.flock(_held["gate"], fcntl.LOCK_UN)
    _held["exclusive"] = False
