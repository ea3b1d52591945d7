"""Permission checks that pass, for tests that call KinComp's routes on a mocked plugin.

One patch of ``plugin.http.require`` for the whole process, on while any caller holds it
(counted, under a lock): callers that overlap, from threads or out of order, cannot leave
the mock in place for good, as nested ``mock.patch`` of one target exited out of order do
(a later test's permission check then passed: ``test_request_helpers``)."""

import contextlib
import threading
from unittest import mock

_LOCK = threading.Lock()
_HELD = []  # one entry per holder
_PATCH = []  # the patch, while it is on


def grant() -> None:
    with _LOCK:
        if not _HELD:
            _PATCH.append(mock.patch("octoprint_kincomp.plugin.http.require"))
            _PATCH[0].start()
        _HELD.append(None)


def release() -> None:
    with _LOCK:
        _HELD.pop()
        if not _HELD:
            _PATCH.pop().stop()


@contextlib.contextmanager
def granted():
    """Every permission check passes inside (the checks are tested on their own)."""
    grant()
    try:
        yield
    finally:
        release()
