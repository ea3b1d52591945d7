"""Shared fixtures.

``engine``: the test runs once per engine (``"compiled"``: the C kernel, ``"python"``: the
pure-Python paths), with every compensator made inside on that engine
(``engines.select.use``). The compiled run fails if the kernel is not built: the test
set-up builds it, so the compiled variants cannot silently test Python twice.
``server``: one real OctoPrint (virtual printer, KinComp installed) for the end-to-end and
browser tests of a session, on a free loopback port, stopped at the end. Set
KINCOMP_E2E_KEEP=<dir> to keep its logs."""

import os
import shutil

import pytest

from octoprint_kincomp.engines.select import ENGINES, use


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Each phase's report on its test item (``item.rep_call``...): a fixture's teardown can
    see whether the test failed (the browser page then leaves its picture)."""
    outcome = yield
    rep = outcome.get_result()
    setattr(item, "rep_" + rep.when, rep)


@pytest.fixture(params=ENGINES)
def engine(request):
    with use(request.param):
        yield request.param


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    from octoprint_kincomp.tools.devserver import USER_FLAGS, DevServer

    base = str(tmp_path_factory.mktemp("octoprint"))
    srv = DevServer(base, kincomp={"enabled": False}, throttle=0.0, users=tuple(USER_FLAGS))
    srv.start()
    try:
        srv.connect()
        yield srv
    finally:
        srv.stop()
        keep = os.environ.get("KINCOMP_E2E_KEEP")
        if keep:
            shutil.copytree(os.path.join(base, "logs"), keep, dirs_exist_ok=True)


@pytest.fixture(scope="session")
def klippy(tmp_path_factory):
    """Real Klipper's ``klippy`` directory for ``tests/support/klipper.py``'s ``run``: a copy
    of ``../shared/klipper`` (read-only in CI) with its C helper built, once per session
    (about 10 s of one core). KINCOMP_KLIPPY_CACHE=<dir> keeps the copy there between
    sessions. The test is skipped when Klipper cannot run here (no Klipper, no gcc)."""
    from tests.support import klipper

    why = klipper.available()
    if why:
        pytest.skip(why)
    cache = os.environ.get("KINCOMP_KLIPPY_CACHE") or str(tmp_path_factory.mktemp("klippy"))
    return klipper.prepare(cache)
