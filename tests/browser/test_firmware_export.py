"""The settings page's firmware export (copy buttons) and the version and README link on
the settings page and the Calibration tab, in a real headless Chromium (issue 14)."""

import os

import pytest

from octoprint_kincomp import __plugin_url__, __version__
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.firmware.export import export
from tests.support.browser import SHOTS, ZERO, open_settings, open_tab
from tests.support.serverutil import settings

pytestmark = pytest.mark.slow

PARAMS = {
    "squareness_um_per_m": {"xy": -3638.6, "xz": 0.0, "yz": 0.0},
    "scale_ppm": {"x": -451.7, "y": 287.0, "z": 0.0},
    "backlash": {"x": 20.0, "y": 8.0, "z": 0.0},
}


def test_settings_show_the_export_per_firmware_and_copy_it(page, server):
    # (a partial update: the stored parameters, PARAMS over what earlier tests on the shared
    # server left, e.g. a campaign's servo lags, are what the page exports)
    stored = settings(server, enabled=False, params=PARAMS)["params"]
    page.context.grant_permissions(["clipboard-read", "clipboard-write"], origin=server.url)
    open_settings(page)
    want = export(Params.from_dict(stored))
    # the version that runs and the README link
    page.wait_for_function("document.querySelector('#kincomp_version').textContent !== ''")
    assert page.inner_text("#kincomp_version") == __version__
    assert page.get_attribute("#kincomp_about a", "href") == __plugin_url__
    # one tab per firmware; each shows its sections as the server made them
    for fw in ("klipper", "marlin", "reprapfirmware"):
        page.click(f"#kincomp_fw_tab_{fw}")
        for section in want[fw].sections:
            sel = f"#kincomp_fw_{fw}_{section.key} pre"
            page.wait_for_selector(sel, state="visible")
            assert page.inner_text(sel) == section.text
            # no parameter hash in the web UI (issue 35)
            assert Params.from_dict(stored).hash() not in page.inner_text(sel)
        assert len(want[fw].notes) == page.locator(f"#kincomp_fw_{fw} .kincomp-fw-notes li").count()
    # the copy button puts exactly the block on the clipboard
    page.click("#kincomp_fw_tab_reprapfirmware")
    page.click("#kincomp_fw_reprapfirmware_config_g .kincomp-copy")
    page.wait_for_selector("#kincomp_fw_reprapfirmware_config_g >> text=Copied")
    clip = page.evaluate("navigator.clipboard.readText()")
    assert clip == want["reprapfirmware"].sections[0].text
    assert "M556 S100 X0.36386" in clip  # RepRapFirmware's sign: opposite of KinComp's
    page.click("#kincomp_fw_tab_klipper")
    page.locator("#kincomp_firmware_export").scroll_into_view_if_needed()
    page.screenshot(path=os.path.join(SHOTS, "settings-firmware-export.png"))

    # without the Clipboard API (OctoPrint over plain http on the LAN): the copy command
    # on a selected text area inside the settings dialog
    page.add_init_script(
        "window.kincompClipboard = navigator.clipboard;"
        "Object.defineProperty(Navigator.prototype, 'clipboard',"
        " {get: function () { return undefined; }});"
    )
    page.reload()
    page.wait_for_selector("#navbar_show_settings", state="visible")
    open_settings(page)
    page.click("#kincomp_fw_tab_marlin")
    page.click("#kincomp_fw_marlin_terminal .kincomp-copy")
    page.wait_for_selector("#kincomp_fw_marlin_terminal >> text=Copied")
    assert page.evaluate("window.kincompClipboard.readText()") == want["marlin"].sections[0].text
    settings(server, enabled=False, params=ZERO)


def test_calibration_tab_shows_version_and_readme(page, server):
    open_tab(page)
    page.wait_for_function("document.querySelector('#kincomp_tab_version').textContent !== ''")
    assert page.inner_text("#kincomp_tab_version") == __version__
    assert page.get_attribute("#kincomp_tab_about a", "href") == __plugin_url__
