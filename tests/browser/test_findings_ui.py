"""Issue 23 in the browser: a result that is not trusted shows its findings (worst first, with
the advice) above the result, and its Apply needs the explicit "Apply anyway" step; the
settings page shows the printer's motion limits and takes pasted Klipper limits.

The error finding is written into the stored run (the analysis checks that give such
findings are issue 23's other half); what is tested here is the UI and the API around it."""

import json
import os

import pytest

from tests.support.browser import SHOTS, browser_page, no_popups, open_settings, open_tab, step
from tests.support.serverutil import status

pytestmark = pytest.mark.slow

ERROR = {
    "code": "motion.feed_capped",
    "severity": "error",
    "message": {
        "text": "the run took 19.1 s longer than planned",
        "template": "the run took %(s)s s longer than planned",
        "params": {"s": "19.1"},
    },
    "advice": {"text": "lower the feed to what the Z axis reaches"},
    "evidence": {"sync_mismatch_ms": 19074.0},
}
WARNING = {
    "code": "model.residual",
    "severity": "warning",
    "message": {"text": "the fit leaves 3 um periodic at 2 mm"},
    "advice": {"text": "fit the cyclic term"},
    "evidence": {},
}


def _untrusted_run(srv):
    code, run = srv.request(
        "POST",
        "/plugin/kincomp/analyze",
        {"summary": {"plane": "XY", "squareness_um_per_m": 400.0}},
    )
    assert code == 200, run
    path = os.path.join(srv.basedir, "data", "kincomp", "runs", run["id"] + ".json")
    with open(path, encoding="utf-8") as f:
        stored = json.load(f)
    stored["findings"] = (
        [run["findings"][0], WARNING, ERROR] if run["findings"] else [WARNING, ERROR]
    )  # stored in any order: the page shows the worst first
    stored["trusted"] = False
    stored.pop("verdict", None)  # (decided again from the findings when read)
    with open(path, "w", encoding="utf-8") as f:
        json.dump(stored, f)
    return run


def test_an_untrusted_result_shows_its_findings_and_needs_apply_anyway(
    browser, new_server, request
):
    srv = new_server()  # (its own: a fresh run store and parameters)
    run = _untrusted_run(srv)
    before = status(srv)["params_hash"]
    with browser_page(browser, srv, request) as page:
        open_tab(page)
        step(page, "history")
        page.wait_for_selector(f"#kincomp_history >> text={run['filename']}")
        row = page.locator("#kincomp_history tbody tr", has_text=run["filename"]).first
        assert row.locator(".kincomp-untrusted-label").is_visible()
        row.locator("button").click()
        page.wait_for_selector("#kincomp_result", state="visible")
        # the verdict says it first; the findings are in the details (issue 35)
        assert page.inner_text("#kincomp_verdict").startswith("Do not apply")
        page.click("#kincomp_details_toggle")
        items = page.locator("#kincomp_findings li.kincomp-finding")
        items.first.wait_for()
        severities = [items.nth(i).get_attribute("data-severity") for i in range(items.count())]
        rank = {"error": 0, "warning": 1, "info": 2}
        assert severities == sorted(severities, key=rank.get) and "warning" in severities
        # the error is the verdict's reason, with what to do (the list holds the rest)
        shown = page.inner_text("#kincomp_result")
        assert "19.1 s longer than planned" in shown
        assert "lower the feed to what the Z axis reaches" in shown
        assert page.is_visible("#kincomp_findings .kincomp-untrusted")
        # Apply asks first; cancelling applies nothing
        page.click("#kincomp_apply")
        page.wait_for_selector("#kincomp_apply_confirm .kincomp-apply-confirm", state="visible")
        no_popups(page)
        page.screenshot(path=os.path.join(SHOTS, "untrusted-result.png"), full_page=True)
        page.click("#kincomp_apply_confirm .kincomp-apply-cancel")
        page.wait_for_selector("#kincomp_apply_confirm .kincomp-apply-confirm", state="hidden")
        assert status(srv)["params_hash"] == before
        page.click("#kincomp_apply")
        page.click("#kincomp_apply_confirm .kincomp-apply-anyway")
        page.wait_for_selector("#kincomp_result >> text=Applied on")
        st = status(srv)
        assert st["params_hash"] != before
        assert st["settings"]["params"]["squareness_um_per_m"]["xy"] != 0.0


def test_the_settings_page_takes_pasted_klipper_limits(browser, new_server, request):
    srv = new_server()  # (its own: no printer connected, no limits stated yet)
    with browser_page(browser, srv, request) as page:
        open_settings(page)
        page.wait_for_selector("#kincomp_limits_table", state="visible")
        page.fill("#kincomp_limits_text", "nothing useful")
        page.click("#kincomp_save")  # the page's one Save
        page.wait_for_selector("#kincomp_limits_error >> text=no motion limits found")
        page.fill(
            "#kincomp_limits_text",
            "[printer]\nmax_velocity: 300\nmax_accel: 3000\nmax_z_velocity: 2\nmax_z_accel: 100",
        )
        page.click("#kincomp_save")  # the page's one Save
        page.wait_for_selector("#kincomp_limits_z >> text=Klipper max_z_velocity")
        assert "120" in page.inner_text("#kincomp_limits_z")  # 2 mm/s
        assert "Entered by hand" in page.inner_text("#kincomp_limits_source")
        ml = status(srv)["motion_limits"]
        assert ml["stated"]["source"] == "pasted"
        assert ml["effective"]["max_feed_mm_min"]["z"] == 120.0
        page.evaluate("document.querySelector('#kincomp_motion_limits').scrollIntoView()")
        no_popups(page)
        page.screenshot(path=os.path.join(SHOTS, "settings-motion-limits.png"))
