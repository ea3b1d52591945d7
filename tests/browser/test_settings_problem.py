"""Issue 17 in the browser: invalid stored settings (squareness_um_per_m.xy: "garbage" in
config.yaml) show a banner on KinComp's settings page with the field marked; the other
stored values are in the form, and saving a fixed value clears the problem and keeps them."""

import os

import pytest

from tests.support.browser import SHOTS, browser_page, no_popups, open_settings
from tests.support.serverutil import status

pytestmark = pytest.mark.slow

GARBAGE = {
    "enabled": True,
    "params": {
        "squareness_um_per_m": {"xy": "garbage", "xz": 120.0, "yz": -80.0},
        "scale_ppm": {"x": 350.0, "y": -200.0, "z": 15.0},
    },
}


def test_the_settings_page_shows_and_fixes_invalid_stored_settings(browser, new_server, request):
    srv = new_server(kincomp=GARBAGE)  # (its own: the garbage is in config.yaml at start-up)
    with browser_page(browser, srv, request) as page:
        open_settings(page)
        page.wait_for_selector("#kincomp_settings_problem >> text=params.squareness_um_per_m.xy")
        assert page.is_visible("#settings_plugin_kincomp .control-group.error #kincomp_sq_xy")
        assert page.input_value("#kincomp_sq_xz") == "120"  # the rest of the calibration
        assert page.input_value("#kincomp_sc_x") == "350"
        no_popups(page)
        page.evaluate("document.querySelector('#settings_plugin_kincomp').scrollIntoView()")
        page.screenshot(path=os.path.join(SHOTS, "settings-stored-invalid.png"))
        page.fill("#kincomp_sq_xy", "250")
        page.click("#kincomp_save")
        page.wait_for_selector("text=Saved.")
        page.wait_for_selector("#kincomp_settings_problem", state="hidden")
        st = status(srv)
        assert st["settings_problem"] is None and st["compensation"]["enabled"] is True
        p = st["settings"]["params"]
        assert p["squareness_um_per_m"] == {"xy": 250.0, "xz": 120.0, "yz": -80.0}
        assert p["scale_ppm"] == {"x": 350.0, "y": -200.0, "z": 15.0}
