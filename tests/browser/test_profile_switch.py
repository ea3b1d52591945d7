"""Issue 28 in the browser: the settings page opened while printer A's profile was in force
and saved after a switch to printer B is refused (nothing stored: A's values never reach
B's set); the page says so and offers Reload, which shows B's settings; saved then, they go
to B."""

import os

import pytest

from tests.e2e.test_printer_profiles import SECOND, _connect
from tests.support import browser as ui
from tests.support.browser import browser_page
from tests.support.serverutil import status

pytestmark = pytest.mark.slow

CALIBRATED = {
    "enabled": True,
    "home_mm": [0, 0, 0],
    "params": {"squareness_um_per_m": {"xy": 1000.0, "xz": 0.0, "yz": 0.0}},
}


@pytest.fixture
def two_printers(browser, new_server, request):
    """A server whose default printer profile (A) is calibrated and connected, a second
    profile (B) made, and a logged-in page on it: (server, page)."""
    srv = new_server(kincomp=CALIBRATED)
    _connect(srv, "_default")
    code, body = srv.request(
        "POST", "/api/printerprofiles", {"profile": dict(SECOND), "basedOn": "_default"}
    )
    assert code == 200, body
    with browser_page(browser, srv, request) as page:
        yield srv, page


def test_a_stale_settings_page_is_refused_and_offers_reload(two_printers):
    srv, page = two_printers
    os.makedirs(ui.SHOTS, exist_ok=True)
    ui.open_settings(page)
    page.wait_for_selector("#kincomp_settings_profile >> text=Default")
    assert page.input_value("#kincomp_sq_xy") == "1000"

    _connect(srv, SECOND["id"])  # printer B: the page still shows A's settings
    page.fill("#kincomp_sc_x", "250")
    page.click("#kincomp_save")
    page.wait_for_selector("#kincomp_settings_reload", state="visible")
    assert "Not saved" in page.inner_text("#kincomp_settings_error")
    assert SECOND["name"] in page.inner_text("#kincomp_settings_error")
    st = status(srv)
    assert st["profile"]["id"] == SECOND["id"] and st["profile"]["calibrated"] is False
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0  # A's not in B
    assert st["settings"]["params"]["scale_ppm"]["x"] == 0.0
    ui.no_popups(page)
    page.evaluate("document.querySelector('#settings_plugin_kincomp').scrollIntoView()")
    page.screenshot(path=os.path.join(ui.SHOTS, "settings-stale-profile.png"))

    page.click("#kincomp_settings_reload")
    page.wait_for_selector(f"#kincomp_settings_profile >> text={SECOND['name']}")
    page.wait_for_selector("#kincomp_settings_error", state="hidden")
    assert page.input_value("#kincomp_sq_xy") == "0"
    page.fill("#kincomp_sc_x", "250")
    page.click("#kincomp_save")
    page.wait_for_selector("text=Saved.")
    st = status(srv)
    assert st["settings"]["params"]["scale_ppm"]["x"] == 250.0
    assert st["settings"]["params"]["squareness_um_per_m"]["xy"] == 0.0
    assert st["profile"]["calibrated"] is True
