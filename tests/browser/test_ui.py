"""The web UI in a real headless Chromium (Debian's chromium, driven by Playwright) against
a real OctoPrint with the virtual printer. Screenshots go to test-artifacts/screenshots/."""

import os
import shutil
import time
import urllib.parse

import pytest

from tests.support.serverutil import settings, status

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SHOTS = os.path.join(os.path.dirname(__file__), "..", "..", "test-artifacts", "screenshots")
ZERO = {
    "squareness_um_per_m": {"xy": 0.0, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": 0.0, "y": 0.0, "z": 0.0},
    "backlash": {"x": 0.0, "y": 0.0, "z": 0.0},
}


@pytest.fixture(scope="module")
def browser():
    if not os.path.exists(CHROMIUM):
        pytest.fail("Debian's chromium is missing: run ./scripts/bootstrap.sh (it installs it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(
            executable_path=CHROMIUM,
            args=[
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
            ],
        )
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser, server, request):
    os.makedirs(SHOTS, exist_ok=True)
    context = browser.new_context(viewport={"width": 1400, "height": 1100}, locale="en-US")
    pg = context.new_page()
    pg.set_default_timeout(60_000)
    errors = []
    pg.on("pageerror", lambda e: errors.append(f"{e} {getattr(e, 'stack', '')}"))
    # OctoPrint catches view model callback exceptions and logs them to the console
    pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    login(pg, server)
    pg.wait_for_selector("#tab_plugin_kincomp_link", state="attached")
    yield pg
    rep = getattr(request.node, "rep_call", None)
    if rep is not None and rep.failed:
        _failure_picture(pg, request.node.name)
    context.close()
    kincomp_errors = [e for e in errors if "kincomp" in e.lower()]
    assert not kincomp_errors, kincomp_errors


def login(pg, server):
    """The admin logs in on ``server``'s page."""
    pg.goto(server.url + "/")
    pg.fill("#login-user", "admin")
    pg.fill("#login-password", server.logins["admin"]["password"])
    pg.click("#login-button")
    pg.wait_for_selector("#navbar_show_settings", state="visible", timeout=120_000)


def _no_popups(page):
    """Close OctoPrint's notification pop-ups so that they do not cover a screenshot."""
    page.evaluate("document.querySelectorAll('.ui-pnotify').forEach(e => e.remove())")


def _failure_picture(pg, name: str) -> None:
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


def _open_tab(page):
    """The Calibration tab; on a narrow layout OctoPrint moves tabs into an overflow menu."""
    if not page.is_visible("#tab_plugin_kincomp_link a"):
        page.click("#tabs .tabdrop .dropdown-toggle")
    page.locator('a[href="#tab_plugin_kincomp"]:visible').first.click()
    page.wait_for_selector("#kincomp_plane", state="visible")


def _step(page, name: str) -> None:
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


def _open_settings(page):
    page.click("#navbar_show_settings")
    page.click("#settings_plugin_kincomp_link a")
    page.wait_for_selector("#kincomp_sq_xy", state="visible")
    # the form is filled from the server
    page.wait_for_function("document.querySelector('#kincomp_sq_xy').value !== ''")


def test_settings_change_save_and_refuse_invalid(page, server):
    settings(server, enabled=False, params=ZERO)
    _open_settings(page)
    page.fill("#kincomp_sq_xy", "-1234.5")
    page.fill("#kincomp_sc_x", "250")
    page.check("#kincomp_bl_x_varies")
    page.fill("#kincomp_bl_x_at0", "10")
    page.fill("#kincomp_bl_x_um0", "30")
    page.fill("#kincomp_bl_x_at1", "190")
    page.fill("#kincomp_bl_x_um1", "12")
    page.check("#kincomp_enabled")
    page.click("#kincomp_save")
    page.wait_for_selector("text=Saved.")
    st = status(server)
    p = st["settings"]["params"]
    assert st["settings"]["enabled"] is True
    assert p["squareness_um_per_m"]["xy"] == -1234.5 and p["scale_ppm"]["x"] == 250.0
    assert p["backlash"]["x"] == [{"at_mm": 10.0, "um": 30.0}, {"at_mm": 190.0, "um": 12.0}]
    # the firmware equivalents follow the saved parameters
    page.wait_for_function(
        "document.querySelector('#kincomp_fw_marlin').textContent.indexOf('M852 I-0.001234') >= 0"
    )
    page.locator("#settings_plugin_kincomp h3").first.scroll_into_view_if_needed()
    page.evaluate("document.querySelector('#settings_plugin_kincomp').scrollIntoView()")
    page.screenshot(path=os.path.join(SHOTS, "settings.png"))
    # the server runs the compiled kernel, and the settings say so
    assert st["engine"] == "compiled"
    assert page.locator("#kincomp_engine span:visible").inner_text() == "compiled fast path"
    page.locator("#kincomp_fw_marlin").scroll_into_view_if_needed()
    page.screenshot(path=os.path.join(SHOTS, "settings-firmware.png"))

    # not a number: marked inline, nothing sent
    page.fill("#kincomp_sq_xz", "abc")
    page.click("#kincomp_save")
    page.wait_for_selector("#settings_plugin_kincomp .control-group.error >> text=Enter a number")
    # out of range: the server's 400 message shows next to the field; stored value kept
    page.fill("#kincomp_sq_xz", "0")
    page.fill("#kincomp_sc_y", "900000")
    page.click("#kincomp_save")
    page.wait_for_selector("#settings_plugin_kincomp .alert-error >> text=params.scale_ppm.y")
    assert page.is_visible("#settings_plugin_kincomp .control-group.error #kincomp_sc_y")
    page.screenshot(path=os.path.join(SHOTS, "settings-invalid.png"))
    assert status(server)["settings"]["params"] == p
    settings(server, enabled=False, params=ZERO)


def test_calibration_wizard_demo_loop(page, server):
    # the fallback path: the trace simulated after the print (live: test_live_view.py)
    settings(server, enabled=False, params=ZERO, demo={"enabled": True, "live": False})
    try:
        _open_tab(page)
        page.fill("#kincomp_cx", "100")
        page.fill("#kincomp_cy", "100")
        page.fill("#kincomp_cz", "5")
        page.fill("#kincomp_radius", "120")
        # too big for the 200 x 200 mm bed: drawn red, printing impossible
        page.wait_for_selector("#kincomp_bed circle.kincomp-bed-outside")
        page.fill("#kincomp_radius", "60")
        page.wait_for_selector("#kincomp_bed circle.kincomp-bed-circle:not(.kincomp-bed-outside)")
        assert page.is_disabled("#kincomp_print_program")
        for box in page.query_selector_all("input.kincomp-check"):
            box.check()
        page.screenshot(path=os.path.join(SHOTS, "wizard.png"), full_page=True)
        page.wait_for_selector("#kincomp_print_program:enabled")
        page.click("#kincomp_print_program")
        # printed through OctoPrint; the demo's virtual ballbar then has a simulated trace
        page.wait_for_selector("#kincomp_step_measure", state="visible")
        deadline = time.time() + 600
        while server.request("GET", "/plugin/kincomp/demo/trace")[0] != 200:
            assert time.time() < deadline, "no simulated trace"
            time.sleep(1)
        server.wait_print_done()
        _step(page, "measure")
        page.click("#kincomp_use_simulated")
        page.wait_for_selector("#kincomp_plot canvas", timeout=120_000)
        page.wait_for_selector("#kincomp_result_table >> text=Squareness")
        runs = server.request("GET", "/plugin/kincomp/runs")[1]["runs"]
        run = server.request("GET", f"/plugin/kincomp/runs/{runs[0]['id']}")[1]
        assert run["simulated"]
        shown = page.inner_text("#kincomp_result_table")
        assert f"{run['diagnostics']['squareness_um_per_m']:.2f}" in shown
        assert page.is_visible("text=SIMULATED data.")
        _no_popups(page)
        page.locator("#kincomp_result").screenshot(path=os.path.join(SHOTS, "plot.png"))
        page.click("#kincomp_apply")
        page.wait_for_selector("#kincomp_state_on", state="visible")
        st = status(server)
        assert st["settings"]["enabled"] is True
        assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == pytest.approx(
            run["proposed"]["squareness_um_per_m"]["xy"]
        )
        # re-test with compensation on: the result is compared with the run before it
        first_trace = server.request("GET", "/plugin/kincomp/demo/trace")[1]
        page.click("#kincomp_retest")
        page.wait_for_selector("#kincomp_print_program:enabled")
        page.click("#kincomp_print_program")
        deadline = time.time() + 600
        while True:
            code, trace = server.request("GET", "/plugin/kincomp/demo/trace")
            if code == 200 and trace != first_trace:
                break
            assert time.time() < deadline, "no simulated re-test trace"
            time.sleep(1)
        server.wait_print_done()
        _step(page, "measure")
        page.click("#kincomp_use_simulated")
        page.wait_for_selector(
            "#kincomp_result_table >> text=Reduction", state="visible", timeout=120_000
        )
        row = page.locator("#kincomp_result_table tr", has_text="Squareness").inner_text()
        reduction = float(row.split()[-2])
        assert reduction > 90, row
        page.wait_for_selector("#kincomp_plot .legend >> text=CCW (before)")
        _no_popups(page)
        page.locator("#kincomp_result").screenshot(
            path=os.path.join(SHOTS, "plot-before-after.png")
        )
        page.wait_for_selector("#kincomp_plot .legend >> text=fitted centre")
        # history lists both runs, with the parameters used and the measurement file
        _step(page, "history")
        page.wait_for_selector(f"#kincomp_history >> text={run['filename']}")
        assert page.locator("#kincomp_history tbody tr").count() >= 2
        assert page.is_visible(f"#kincomp_history >> text={run['params_before_hash']}")
        href = page.locator("#kincomp_history a.kincomp-trace-link").first.get_attribute("href")
        path = urllib.parse.urlparse(urllib.parse.urljoin(page.url, href)).path
        code, text = server.request("GET", path)
        assert code == 200 and "direction,time_s,reading_mm" in text
    finally:
        settings(server, demo={"enabled": False, "live": True}, params=ZERO, enabled=False)


def test_steps_folded_into_octoprints_menu_are_still_reached(page, server):
    # the cause of a flaky CI failure: at a window resize OctoPrint's tabdrop folds the step
    # pills that wrap to a second row into its menu (here Campaign and History); they are
    # reached there
    _open_tab(page)
    page.evaluate("() => $(window).trigger('resize')")
    page.wait_for_selector("#kincomp_step_history", state="hidden")
    _step(page, "history")
    page.wait_for_selector("#kincomp_history", state="visible")
    _step(page, "program")
    page.wait_for_selector("#kincomp_plane", state="visible")


def test_files_compensated_with_older_parameters_are_flagged(page, server):
    skew = dict(ZERO, squareness_um_per_m={"xy": 700.0, "xz": 0.0, "yz": 0.0})
    settings(server, enabled=True, mode="on_upload", params=skew)
    try:
        code, _ = server.upload(
            "/api/files/local", "flagged.gcode", b"G28\nG1 X10 Y50 F3000\nG1 X20 Y60\n"
        )
        assert code == 201
        settings(server, params=dict(ZERO, squareness_um_per_m={"xy": 650.0, "xz": 0.0, "yz": 0.0}))
        page.reload()
        page.wait_for_selector("#navbar_show_settings", state="visible", timeout=120_000)
        _open_tab(page)
        page.wait_for_selector("#kincomp_outdated >> text=flagged.gcode", state="visible")
    finally:
        settings(server, enabled=False, mode="on_the_fly", params=ZERO)
        server.request("DELETE", "/api/files/local/flagged.gcode")


def test_german_browser_gets_the_german_ui(browser, server):
    """Jinja (server side) and gettext in the view models (browser side) both translate."""
    context = browser.new_context(
        viewport={"width": 1400, "height": 1100},
        locale="de-DE",
        extra_http_headers={"Accept-Language": "de-DE,de;q=0.9"},
    )
    try:
        pg = context.new_page()
        pg.set_default_timeout(60_000)
        pg.goto(server.url + "/")
        pg.fill("#login-user", "admin")
        pg.fill("#login-password", server.logins["admin"]["password"])
        pg.click("#login-button")
        pg.wait_for_selector("#navbar_show_settings", state="visible", timeout=120_000)
        _open_tab(pg)
        assert "Kalibrierung" in pg.inner_text("#tab_plugin_kincomp_link")
        assert pg.is_visible("text=Testprogramm drucken")  # template, rendered by Jinja
        pg.fill("#kincomp_radius", "60")
        pg.wait_for_selector("#tab_plugin_kincomp >> text=der Kreis passt")  # JS gettext
        pg.screenshot(path=os.path.join(SHOTS, "wizard-de.png"))
        # the server's validation message in the user's language, inline in the settings
        settings(server, enabled=False, params=ZERO)
        _open_settings(pg)
        pg.fill("#kincomp_sc_y", "900000")
        pg.click("#kincomp_save")
        pg.wait_for_selector(
            "#settings_plugin_kincomp .alert-error >> text=liegt außerhalb des zulässigen Bereichs"
        )
        assert status(server)["settings"]["params"]["scale_ppm"]["y"] == 0.0
    finally:
        context.close()
