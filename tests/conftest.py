"""Shared fixtures (how to write a fast real-server or browser test: docs/tests.md).

``engine``: the test runs once per engine (``"compiled"``: the C kernel, ``"python"``: the
pure-Python paths), with every compensator made inside on that engine
(``engines.select.use``). The compiled run fails if the kernel is not built: the test
set-up builds it, so the compiled variants cannot silently test Python twice.
``server``: one real OctoPrint (virtual printer, KinComp installed) for the end-to-end and
browser tests of a session (of each worker process under ``-n``), on a free loopback port,
stopped at the end. Set KINCOMP_E2E_KEEP=<dir> to keep its logs.
``new_server``: a factory for a test that needs an OctoPrint of its own (its own stored
settings, plugins or restarts): ``new_server(kincomp=..., connect=True)``, stopped at the
test's end. Every test server's users (admin, viewer, settings-only, read-only) are made
once per session and copied into its basedir (``devserver.users_template``).
``browser``: one headless Chromium per session; ``page``: a new browser context per test
(viewport and locale from ``browser_context_args``, which a module or test may override)
on ``server``, logged in as the admin from the state stored after the session's first
login; ``@pytest.mark.fresh_login``: through the login form instead.

Under pytest-xdist (``./test.sh`` runs ``-n 3 --dist loadgroup``): the slowest modules are
handed out first, modules with module-scoped fixtures stay on one worker, and a test marked
``alone`` (it measures rates or times) runs while no other test runs."""

import os
import shutil
import sys
import tempfile

import pytest

from octoprint_kincomp.engines.select import ENGINES, use
from tests.support.machine import SESSION_DIR_ENV

# the modules that take longest, slowest first (measured with --durations=0): handed out
# first under -n, so that the end of the run is many short tests spread over both workers
SLOWEST_FIRST = [
    "tests/e2e/test_soak.py",
    "tests/e2e/test_reliability.py",
    "tests/browser/test_campaign_ui.py",
    "tests/e2e/test_reliability_round3.py",
    "tests/e2e/test_server.py",
    "tests/e2e/test_campaign.py",
    "tests/plugin/test_campaign_api.py",
    "tests/browser/test_first_hour.py",
    "tests/browser/test_result_decision.py",
    "tests/sensor/test_capture.py",
    "tests/browser/test_ui.py",
    "tests/browser/test_findings_ui.py",
    "tests/e2e/test_compat.py",
    "tests/core/test_arc_fit.py",
    "tests/core/test_properties.py",
    "tests/corpus/test_corpus.py",
    "tests/firmware/test_klipper_travel.py",
    "tests/engines/test_fastpaths.py",
]
# modules whose tests share module-scoped fixtures: one worker runs all of them (the
# fixture is made once); every other test may go to either worker
ONE_WORKER = [
    "tests/e2e/test_compat.py",
    "tests/sensor/test_capture.py",
    "tests/browser/test_result_decision.py",  # (its analysed campaign: made once)
    "tests/engines/test_fastpaths.py",  # (the reference path's output: computed once per case)
    "tests/simulator/test_closed_loop.py",
    "tests/release/test_extras.py",
    "tests/calibration/test_campaign.py",
    "tests/calibration/test_artifact_fit.py",
    "tests/calibration/test_analysis.py",
]
# the test servers' analyses come in the answer however loaded the machine is (20 s in use:
# a CI machine running two workers starves the nice-19 analysis worker; the 202 path has its
# own tests: tests/js/jobs.test.js, the reliability tests' polling)
os.environ.setdefault("KINCOMP_ANALYSIS_WAIT_S", "600")


def pytest_configure(config):
    """The session's folder (shared by the workers under -n: made by the main process):
    the users made once for every test server, the lock of the ``alone`` tests."""
    from octoprint_kincomp.tools.devserver import GCODE_ANALYSIS_ENV, USERS_TEMPLATE_ENV

    if not os.environ.get(SESSION_DIR_ENV):
        os.environ[SESSION_DIR_ENV] = tempfile.mkdtemp(prefix="kincomp-tests-")
        config._kincomp_session_dir = os.environ[SESSION_DIR_ENV]
    os.environ.setdefault(USERS_TEMPLATE_ENV, os.path.join(os.environ[SESSION_DIR_ENV], "users"))
    os.environ.setdefault(GCODE_ANALYSIS_ENV, "never")  # (no test reads OctoPrint's)


def pytest_unconfigure(config):
    made = getattr(config, "_kincomp_session_dir", None)
    if made:
        shutil.rmtree(made, ignore_errors=True)
        del os.environ[SESSION_DIR_ENV]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session, config, items):
    """The order and grouping for pytest-xdist's loadgroup scheduling (it hands out work in
    collection order): the slowest modules first, ``alone`` tests last (one group: their
    worker waits for the other's current test, which is then a short one)."""
    rank = {m: i for i, m in enumerate(SLOWEST_FIRST)}

    def module(item):
        return item.nodeid.split("::", 1)[0]

    def key(indexed):
        i, item = indexed
        alone = item.get_closest_marker("alone") is not None
        return (alone, rank.get(module(item), len(rank)), i)

    items[:] = [item for _, item in sorted(enumerate(items), key=key)]
    for item in items:
        if item.get_closest_marker("alone") is not None:
            item.add_marker(pytest.mark.xdist_group("alone"))
        elif module(item) in ONE_WORKER:
            item.add_marker(pytest.mark.xdist_group(module(item)))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    from tests.support.machine import hold

    with hold(item.get_closest_marker("alone") is not None):
        yield


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
    from tests.support.serverutil import printer_eeprom_path, printer_limits

    base = str(tmp_path_factory.mktemp("octoprint"))
    srv = DevServer(base, kincomp={"enabled": False}, throttle=0.0, users=tuple(USER_FLAGS))
    srv.start()
    try:
        srv.connect()
        srv.printer_limits_at_start = printer_limits(srv)
        with open(printer_eeprom_path(srv), "rb") as f:
            srv.printer_eeprom_at_start = f.read()
        yield srv
    finally:
        srv.stop()
        keep = os.environ.get("KINCOMP_E2E_KEEP")
        if keep:
            shutil.copytree(os.path.join(base, "logs"), keep, dirs_exist_ok=True)


@pytest.fixture(autouse=True)
def _no_blueprint_client_left_on():
    """A test that made a blueprint client (tests/support/blueprint.py) stopped it, and
    granted permissions (tests/support/permissions.py) gave them back: permission checks
    that pass must not outlive the test."""
    yield
    blueprint = sys.modules.get("tests.support.blueprint")
    left = list(blueprint.OPEN) if blueprint else []
    for ns in left:
        ns.stop()
    assert not left, "the test left a blueprint client's patches on (call its stop())"
    permissions = sys.modules.get("tests.support.permissions")
    assert not (permissions and permissions._HELD), "the test left the permissions granted"


@pytest.fixture(autouse=True)
def _shared_printer_settings_put_back(request):
    """A test on the session's server that sent settings to its printer (a printed slicer
    file's M201/M203/M204/M205, which a real Marlin keeps after the print too) leaves them
    put back for the next test: the printer's motion limits are part of every analysis. A
    print a test left running or paused (it failed mid-print) is cancelled."""
    if "server" not in request.fixturenames:
        yield
        return
    from tests.support.serverutil import (
        put_back_printer_settings,
        serial_log_size,
        settings_sent_since,
    )

    srv = request.getfixturevalue("server")
    start = serial_log_size(srv)
    yield
    left = srv.state()
    if left in ("Printing", "Paused", "Pausing", "Resuming"):
        # (a test that failed mid-print: the next test would wait for a printer that waits)
        print(f"the test left the shared printer {left!r}: cancelled for the next test")
        srv.request("POST", "/api/job", {"command": "cancel"})
        srv.wait_state("Operational", 120)
    if settings_sent_since(srv, start):
        put_back_printer_settings(srv, srv.printer_eeprom_at_start, srv.printer_limits_at_start)


@pytest.fixture
def new_server(tmp_path):
    """``new_server(name="op", start=True, connect=False, **DevServer arguments)``: an
    OctoPrint of the test's own in ``tmp_path/name`` (its users copied, not made), started
    (and connected to the virtual printer) unless told otherwise; all stopped at the end."""
    from octoprint_kincomp.tools.devserver import DevServer

    made = []

    def make(name="op", start=True, connect=False, **kwargs):
        srv = DevServer(str(tmp_path / name), **kwargs)
        made.append(srv)
        if start:
            srv.start()
        if connect:
            srv.connect()
        return srv

    try:
        yield make
    finally:
        for srv in made:
            srv.stop()


@pytest.fixture(scope="session")
def browser():
    """One headless Chromium for the session (Debian's, under Playwright)."""
    from tests.support.browser import launched

    with launched() as b:
        yield b


@pytest.fixture
def browser_context_args():
    """The ``page``'s browser context (Playwright's new_context arguments): override it in a
    module or test for another viewport or locale."""
    from tests.support.browser import CONTEXT

    return dict(CONTEXT)


@pytest.fixture
def page(browser, server, browser_context_args, request):
    """A page on ``server`` in a new context, logged in as the admin (stored login; with
    ``@pytest.mark.fresh_login`` through the form). A failed test leaves
    ``failed-<test>.png``; a KinComp error in the page's console fails the test."""
    from tests.support.browser import browser_page

    fresh = request.node.get_closest_marker("fresh_login") is not None
    with browser_page(browser, server, request, fresh_login=fresh, **browser_context_args) as pg:
        yield pg


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
