"""The browser tests' Chromium and pages (the ``browser`` and ``page`` fixtures of
tests/conftest.py are built from these), and the steps every browser test takes: log in,
open KinComp's tab, a step of it, its settings.

One Chromium per test session (``launched``); each test gets its own browser context (its
cookies, viewport and locale: ``browser_page``), logged in from the state stored after the
first login on that server (``stored_login``: the login form is filled once per server and
user, not once per test). Debian's chromium, driven by Playwright (no browser download)."""

from __future__ import annotations

import contextlib
import os
import shutil
from typing import Dict, Optional

import pytest

from tests.support import ARTIFACTS

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SHOTS = os.path.join(ARTIFACTS, "screenshots")
# the pictures in docs/ and the browser tests' screenshots they are copies of (refreshed by
# scripts/docs_screenshots.py after a browser run; tests/release/test_docs.py keeps the two
# lists together)
DOCS_SHOTS = {
    "wizard.png": "wizard.png",
    "result.png": "result.png",
    "campaign-result.png": "campaign-result.png",
    "campaign.png": "campaign.png",
    "live-view.png": "live-view.png",
    "settings.png": "settings.png",
    "plot-before-after.png": "plot-before-after.png",
    "firmware-export.png": "settings-firmware-export.png",
    "artifact-quick-result.png": "artifact-quick-result.png",
}
ZERO = {
    "squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}
LAUNCH_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
# a test's browser context unless it asks for another (the ``browser_context_args`` fixture)
CONTEXT = {"viewport": {"width": 1400, "height": 1100}, "locale": "en-US"}
# CSS animations stopped in every test page: OctoPrint's striped progress bar animates all
# through a print (Bootstrap's progress-bar-stripes), which kept a software-rendering headless
# Chromium busy at a quarter of a core per printing page (the demo campaign test: the page's
# renderer 88 s of CPU with it, 62 s without); no KinComp style animates, transitions (which
# Bootstrap's dialogs wait for) are left alone
NO_ANIMATIONS = """
document.addEventListener("DOMContentLoaded", function () {
    var style = document.createElement("style");
    style.textContent = "*, *::before, *::after { animation: none !important; }";
    document.head.appendChild(style);
});
"""
LOGGED_IN = "#navbar_show_settings"  # shown once the page has a logged-in user
LOGIN_TIMEOUT_MS = 120_000


@contextlib.contextmanager
def launched():
    """Debian's headless chromium under Playwright, closed at the end."""
    if not os.path.exists(CHROMIUM):
        pytest.fail("Debian's chromium is missing: run ./scripts/bootstrap.sh (it installs it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            yield b
        finally:
            b.close()


# (server address, OctoPrint's pid, user) -> Playwright storage state after a login
_STORED: Dict[tuple, dict] = {}


def login(pg, server, user: str = "admin") -> None:
    """``user`` logs in on ``server``'s page through OctoPrint's login form."""
    pg.goto(server.url + "/")
    pg.fill("#login-user", user)
    pg.fill("#login-password", server.logins[user]["password"])
    pg.click("#login-button")
    pg.wait_for_selector(LOGGED_IN, state="visible", timeout=LOGIN_TIMEOUT_MS)


def stored_login(browser, server, user: str = "admin") -> dict:
    """The storage state (cookies) of ``user`` logged in on ``server``: made by one login
    through the form per server process and user, then reused by every context."""
    key = (server.url, getattr(server.proc, "pid", None), user)
    if key not in _STORED:
        context = browser.new_context(**CONTEXT)
        try:
            pg = context.new_page()
            pg.set_default_timeout(60_000)
            login(pg, server, user)
            _STORED[key] = context.storage_state()
        finally:
            context.close()
    return _STORED[key]


def open_logged_in(pg, server, user: str = "admin") -> None:
    """Opens ``server``'s page logged in: from the stored state, or (the state no longer
    valid, e.g. after a restart) through the form."""
    pg.goto(server.url + "/")
    pg.wait_for_selector(f"{LOGGED_IN}:visible, #login-user:visible", timeout=LOGIN_TIMEOUT_MS)
    if not pg.is_visible(LOGGED_IN):
        login(pg, server, user)


@contextlib.contextmanager
def browser_page(
    browser,
    server,
    request=None,
    user: Optional[str] = "admin",
    fresh_login: bool = False,
    **context_args,
):
    """A page in a new browser context on ``server`` (``context_args``: Playwright's
    ``new_context`` arguments, default :data:`CONTEXT`), logged in as ``user`` (None: not
    logged in; ``fresh_login``: through the form, not from the stored state). At the end: a
    failed test (``request``) leaves its picture, the context is closed, and no KinComp
    error may have reached the page's console."""
    os.makedirs(SHOTS, exist_ok=True)
    args = dict(CONTEXT, **context_args)
    if user is not None and not fresh_login:
        args["storage_state"] = stored_login(browser, server, user)
    context = browser.new_context(**args)
    context.add_init_script(NO_ANIMATIONS)
    errors = []
    try:
        pg = context.new_page()
        pg.set_default_timeout(60_000)
        pg.on("pageerror", lambda e: errors.append(f"{e} {getattr(e, 'stack', '')}"))
        # OctoPrint catches view model callback exceptions and logs them to the console
        pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        if user is not None:
            if fresh_login:
                login(pg, server, user)
            else:
                open_logged_in(pg, server, user)
            pg.wait_for_selector("#tab_plugin_kincomp_link", state="attached")
        name = request.node.name if request is not None else "page"
        try:
            yield pg
        except BaseException:  # (used inside a test: the test failed here)
            failure_picture(pg, name)
            raise
        rep = getattr(request.node, "rep_call", None) if request is not None else None
        if rep is not None and rep.failed:  # (as a fixture: the test failed)
            failure_picture(pg, name)
    finally:
        context.close()
    kincomp_errors = [e for e in errors if "kincomp" in e.lower()]
    assert not kincomp_errors, kincomp_errors


def popups(page) -> list:
    """The texts of OctoPrint's notification pop-ups open on the page."""
    return page.evaluate("[...document.querySelectorAll('.ui-pnotify')].map(n => n.innerText)")


def no_popups(page) -> None:
    """Close OctoPrint's notification pop-ups so that they do not cover a screenshot."""
    page.evaluate("document.querySelectorAll('.ui-pnotify').forEach(e => e.remove())")


def failure_picture(pg, name: str) -> None:
    """What the page showed when a test failed: a screenshot in SHOTS and, in the test's
    output, its address (with the tab shown), whether the Calibration tab is visible, any
    dialog open and the offline overlay (a failed click on a hidden element says little
    more than that it was hidden)."""
    try:
        pg.screenshot(path=os.path.join(SHOTS, f"failed-{name}.png"), full_page=True)
        shown = pg.evaluate("""() => ({
            url: location.href,
            kincompTabVisible: !!(document.querySelector('#kincomp_tab') || {}).offsetParent,
            modals: [...document.querySelectorAll('.modal.in')].map(m => m.id),
            offline: !!(document.querySelector('#offline_overlay') || {}).offsetParent})""")
        print(f"page at the failure of {name}: {shown}")
    except Exception as exc:
        print(f"no picture of the page at the failure of {name}: {exc}")


def open_tab(page) -> None:
    """The Calibration tab; on a narrow layout OctoPrint moves tabs into an overflow menu. It
    opens on the step the page was last on (a new browser context: step 1)."""
    if not page.is_visible("#tab_plugin_kincomp_link a"):
        page.click("#tabs .tabdrop .dropdown-toggle")
    page.locator('a[href="#tab_plugin_kincomp"]:visible').first.click()
    page.wait_for_selector("#kincomp_steps", state="visible")


def reload(page) -> None:
    """Reload the page as a user would (F5) and be back on the Calibration tab: the tab, and
    its step, as the page left them (OctoPrint opens its first tab when it does not keep
    the address's tab)."""
    page.reload()
    page.wait_for_selector("#kincomp_steps", state="attached")
    if not page.is_visible("#kincomp_steps"):
        open_tab(page)


def step(page, name: str) -> None:
    """Go to a step of the Calibration tab (``name``: program, measure, result, campaign,
    history). OctoPrint folds pills that no longer fit on one row into a menu (its tabdrop,
    at any window resize; in the 1400 px test window the steps take two rows): a folded step
    is clicked in that menu."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    link = f"#kincomp_step_{name}"
    menu = "#kincomp_tab .kincomp-steps .tabdrop .dropdown-toggle"
    for _ in range(3):
        if not page.is_visible(link) and page.is_visible(menu):
            page.click(menu)
        try:
            page.click(link, timeout=5_000)
            return
        except PlaywrightTimeout:  # folded (or unfolded) meanwhile: look again
            continue
    page.click(link)  # (this one reports what is wrong)


def open_settings(page) -> None:
    page.click("#navbar_show_settings")
    page.click("#settings_plugin_kincomp_link a")
    page.wait_for_selector("#kincomp_sq_xy", state="visible")
    # the form is filled from the server
    page.wait_for_function("document.querySelector('#kincomp_sq_xy').value !== ''")
