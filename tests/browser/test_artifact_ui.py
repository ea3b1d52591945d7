"""The printed artifact of the Calibration tab in a real headless Chromium against the real
server (issues 27, 35): write the full artifact, see its numbered drawing, type SIMULATED
caliper readings (with a 1 mm typo) into the measuring form, analyse, see the values with
their uncertainties and the typo named by its id, apply; the quick artifact in demo mode, in
English at 1400x900 and in German at 1920x1080 (each also at the other size): its STL, its
simulated readings, the result's verdict and Apply with the parameters it sets in view from
the top of the result, no ballbar plot for it in the tab. Screenshots go to
test-artifacts/screenshots/ (artifact-measure.png, artifact-result.png,
artifact-quick-result.png, artifact-quick-result-de.png)."""

import os

import numpy as np
import pytest

from octoprint_kincomp.calibration.artifact.program import read_measurements
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.artifact import simulate_readings
from tests.support.browser import SHOTS, ZERO, no_popups, open_tab, popups, step
from tests.support.serverutil import settings, status

pytestmark = pytest.mark.slow

TRUTH = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": 900.0, "xz": -600.0, "yz": 300.0},
        "scale_ppm": {"x": 250.0, "y": -150.0, "z": 0.0},
    }
)


def _open_artifact(page):
    open_tab(page)
    step(page, "artifact")
    # (the last result is shown when there is one: to the program)
    page.click("#kincomp_artifact_step_program")
    page.wait_for_selector("#kincomp_artifact_program", state="visible")


def test_measuring_form_result_and_apply(page, server):
    settings(server, enabled=False, params=ZERO)
    _open_artifact(page)
    page.check("#kincomp_artifact_mode_full")
    page.fill("#kincomp_artifact_nozzle", "0.4")
    no_popups(page)
    page.click("#kincomp_artifact_write")
    page.wait_for_selector("#kincomp_artifact_table tbody tr")
    # where it went is said above the sheet, not in a pop-up (issue 35)
    note = page.inner_text("#kincomp_artifact_sheet_note")
    assert "added to the files as kincomp/artifact_" in note, note
    assert not popups(page), popups(page)
    rows = page.locator("#kincomp_artifact_table tbody tr")
    assert rows.count() == 36
    # the drawing numbers every measurement (outside/inside of a pair of walls)
    labels = page.locator("#kincomp_artifact_drawing svg text").all_text_contents()
    assert "1/2" in labels and "35/36" in labels
    path = page.inner_text("#kincomp_artifact_measure code").strip()
    assert path.startswith("kincomp/artifact_")
    with open(os.path.join(server.basedir, "uploads", path), encoding="utf-8") as f:
        meas = read_measurements(f.read())
    readings = simulate_readings(
        meas, TRUTH, shrinkage=0.004, line_width_mm=0.45, rng=np.random.default_rng(27)
    )
    readings["B3-in"][2] += 1.0  # typed 1 mm off
    # a reading that is no number is refused, naming the field, before anything is sent
    page.fill("#kincomp_artifact_r_X1-out_1", "abc")
    page.click("#kincomp_artifact_analyse")
    # (issue 35: beside the Analyse button, the row marked and its field focused, not at the
    # top of a form 36 rows long)
    page.wait_for_selector("#kincomp_artifact_form_error >> text=X1-out")
    assert not page.is_visible("#kincomp_artifact_error")
    assert "X1-out" in page.locator("#kincomp_artifact_table tbody tr.error").inner_text()
    assert page.evaluate("document.activeElement.id") == "kincomp_artifact_r_X1-out_1"
    gap = page.evaluate("""() => document.querySelector('#kincomp_artifact_analyse')
        .getBoundingClientRect().top - document.querySelector('#kincomp_artifact_form_error')
        .getBoundingClientRect().bottom""")
    assert 0 <= gap < 50, gap
    for m in meas:
        for k, v in enumerate(readings[m.id], 1):
            page.fill(f"#kincomp_artifact_r_{m.id}_{k}", f"{v:.2f}")
    no_popups(page)
    page.screenshot(path=os.path.join(SHOTS, "artifact-measure.png"), full_page=True)
    page.click("#kincomp_artifact_analyse")
    page.wait_for_selector("#kincomp_artifact_result", state="visible")
    page.wait_for_selector("#kincomp_artifact_values tbody tr")
    table = page.inner_text("#kincomp_artifact_values")
    first = page.locator("#kincomp_artifact_values tbody tr").first.inner_text()
    assert "Squareness XY" in first and "±" in first
    value = float(first.split("\t")[1])
    assert abs(value - 900.0) < 100.0, table
    findings = page.inner_text("#kincomp_artifact_findings")
    assert "B3-in" in findings and "left out" in findings
    # the verdict says why (the typo left out), and no "Checked" label beside it
    verdict = page.inner_text("#kincomp_artifact_verdict")
    assert verdict.startswith("Apply with care") and "B3-in" in verdict, verdict
    assert "Checked" not in page.inner_text("#kincomp_artifact_result")
    no_popups(page)
    page.screenshot(path=os.path.join(SHOTS, "artifact-result.png"), full_page=True)
    # the row of the typo is marked in the form
    page.click("#kincomp_artifact_step_measure")
    marked = page.locator("#kincomp_artifact_table tbody tr.error").all_inner_texts()
    assert len(marked) == 1 and "B3-in" in marked[0]
    page.click("#kincomp_artifact_step_result")
    no_popups(page)
    page.click("#kincomp_artifact_apply")
    page.wait_for_selector("#kincomp_artifact_result >> text=Applied on")
    # what Apply did is said beside "Applied on", not in a pop-up (issue 35)
    page.wait_for_selector("#kincomp_artifact_applied >> text=compensation is on")
    assert not popups(page), popups(page)
    st = status(server)
    assert st["settings"]["enabled"] is True
    assert abs(st["settings"]["params"]["squareness_um_per_m"]["xy"] - value) < 0.5
    settings(server, enabled=False, params=ZERO)
    # the history has the run; opened (after a reload), it comes back with its drawing and
    # readings
    page.reload()
    page.wait_for_selector("#tab_plugin_kincomp_link", state="attached")
    open_tab(page)
    step(page, "history")
    page.wait_for_selector("#kincomp_history tbody tr")
    first_row = page.locator("#kincomp_history tbody tr").first
    assert path.rsplit("/", 1)[-1] in first_row.inner_text()
    # its own figures, not dashes: squareness per plane, the mismatches, no circularity
    shown = first_row.locator(".kincomp-history-squareness").inner_text()
    assert f"XY {value:.1f}" in shown and "XZ " in shown and "scale mismatch X-Y " in shown
    assert first_row.locator(".kincomp-history-circularity").inner_text() == "no circle (artifact)"
    # a value a line: the history stays inside the tab, as wide as with ballbar runs only
    page.set_viewport_size({"width": 1400, "height": 900})
    fits = page.evaluate("""() => {
        const t = document.querySelector('#kincomp_history');
        const box = t.closest('.tab-pane').getBoundingClientRect();
        return t.getBoundingClientRect().right <= box.right + 1; }""")
    assert fits
    first_row.locator("button").click()
    page.wait_for_selector("#kincomp_artifact_result", state="visible")
    page.wait_for_selector("#kincomp_artifact_result >> text=Applied on")
    page.click("#kincomp_artifact_step_measure")
    assert page.input_value("#kincomp_artifact_r_A1-out_1") == f"{readings['A1-out'][0]:g}"
    assert "35/36" in page.locator("#kincomp_artifact_drawing svg text").all_text_contents()


def _in_view_from_the_result(page, size):
    """At the window ``size`` (width, height), with the top of the artifact's result at the
    top of the window: the verdict, the values, the parameters Apply sets and the Apply button
    are all inside the window."""
    page.set_viewport_size({"width": size[0], "height": size[1]})
    page.evaluate("document.querySelector('#kincomp_artifact_result').scrollIntoView()")
    shown = page.evaluate("""() => ['#kincomp_artifact_verdict', '#kincomp_artifact_values',
        '#kincomp_artifact_sets', '#kincomp_artifact_apply'].map(s => {
            const r = document.querySelector(s).getBoundingClientRect();
            return [s, r.height > 0 && r.top >= 0 && r.bottom <= window.innerHeight];
        })""")
    assert all(ok for _, ok in shown), (size, shown)


def _quick_simulated_result(page):
    """The quick artifact written, its STL downloaded, demo mode's readings filled in and
    analysed: the result step shown."""
    assert page.is_checked("#kincomp_artifact_mode_quick")  # the default
    page.click("#kincomp_artifact_write")
    page.wait_for_selector("#kincomp_artifact_table tbody tr")
    assert page.locator("#kincomp_artifact_table tbody tr").count() == 12
    assert page.locator("#kincomp_artifact_table tbody tr").first.locator("input").count() == 1
    stl = page.request.get(page.eval_on_selector("#kincomp_artifact_stl", "a => a.href"))
    assert stl.status == 200 and len(stl.body()) > 84
    page.click("#kincomp_artifact_simulate")
    page.wait_for_function("document.querySelector('#kincomp_artifact_r_A1-out_1').value !== ''")
    assert page.is_visible("#kincomp_artifact_simulated_label")
    page.click("#kincomp_artifact_analyse")
    page.wait_for_selector("#kincomp_artifact_verdict", state="visible")


def test_quick_artifact_in_demo_mode(page, server):
    """Issue 35's done-when, English at 1400x900 (and 1920x1080): a newcomer's quick artifact
    in demo mode, the whole loop without a printer."""
    settings(server, enabled=False, params=ZERO, demo={"enabled": True, "live": False})
    try:
        page.set_viewport_size({"width": 1400, "height": 900})
        _open_artifact(page)
        _quick_simulated_result(page)
        verdict = page.inner_text("#kincomp_artifact_verdict")
        assert verdict.startswith("SIMULATED") and "Apply:" in verdict, verdict
        sets = page.inner_text("#kincomp_artifact_sets")
        assert "Squareness XY" in sets and "Scale Z" in sets
        # what Apply sets: the demo printer's hidden XY squareness, within the quick sigma
        row = page.locator("#kincomp_artifact_sets tbody tr").first.inner_text().split("\t")
        assert row[:2] == ["Squareness XY", "0.0"] and abs(float(row[2]) + 3638.6) < 400, row
        _in_view_from_the_result(page, (1400, 900))
        no_popups(page)
        page.screenshot(path=os.path.join(SHOTS, "artifact-quick-result.png"))
        _in_view_from_the_result(page, (1920, 1080))
        page.click("#kincomp_artifact_apply")
        page.wait_for_selector("#kincomp_artifact_result >> text=Applied on")
        st = status(server)
        assert st["settings"]["enabled"] is True
        assert abs(st["settings"]["params"]["squareness_um_per_m"]["xy"] - float(row[2])) < 0.1
        # opened from the history, the tab draws no ballbar plot for it
        step(page, "history")
        # (its own row, once the history has it: the first row may still be an older run's)
        run = server.request("GET", "/plugin/kincomp/runs")[1]["runs"][0]
        assert run["source"] == "artifact", run
        mine = page.locator(f"#kincomp_history tbody tr:has(input[value='{run['id']}'])")
        mine.first.locator("button").click()
        page.wait_for_selector("#kincomp_artifact_result", state="visible")
        hidden = page.evaluate(
            "getComputedStyle(document.querySelector('#kincomp_tab .kincomp-plot-box')).display"
        )
        assert hidden == "none"
    finally:
        settings(server, enabled=False, params=ZERO, demo={"enabled": False, "live": True})


def test_quick_artifact_in_german(page, server):
    """The same in German at 1920x1080 (and 1400x900): one term per thing (Prüfteil), the
    verdict and Apply in view."""
    settings(server, enabled=False, params=ZERO, demo={"enabled": True, "live": False})
    try:
        page.set_viewport_size({"width": 1920, "height": 1080})
        page.goto(server.url + "/?l10n=de")
        page.wait_for_selector("#tab_plugin_kincomp_link", state="attached")
        _open_artifact(page)
        assert "Gedrucktes Prüfteil" in page.inner_text("#kincomp_step_artifact")
        assert "Prüfteil drucken" in page.inner_text("#kincomp_artifact_print")
        assert "Schnell: 12 Messwerte" in page.inner_text("#kincomp_artifact_program")
        page.click("#kincomp_artifact_write")
        page.wait_for_selector("#kincomp_artifact_table tbody tr")
        head = page.inner_text("#kincomp_artifact_table thead")
        assert "Nennmaß" in head and "Messwerte (mm)" in head
        assert "außen" in page.locator("#kincomp_artifact_table tbody tr").first.inner_text()
        # how to measure each span, in German too (the header's hints were English)
        form = page.inner_text("#kincomp_artifact_table tbody")
        assert "backen" in form, form[:300]
        for english in ("jaws", "walls", "tower", " deg "):
            assert english not in form, english
        page.click("#kincomp_artifact_analyse")
        page.wait_for_selector(
            "#kincomp_artifact_form_error >> text=Tragen Sie zuerst die Messwerte ein"
        )
        page.click("#kincomp_artifact_step_program")
        _quick_simulated_result(page)
        verdict = page.inner_text("#kincomp_artifact_verdict")
        assert verdict.startswith("SIMULIERT") and "Übernehmen:" in verdict, verdict
        assert "Rechtwinkligkeit XY" in page.inner_text("#kincomp_artifact_sets")
        text = page.inner_text("#kincomp_artifact")
        for english in ("printed artifact", "Kugelstab", "Prüfkörper", "Checked"):
            assert english not in text, english
        _in_view_from_the_result(page, (1920, 1080))
        no_popups(page)
        page.screenshot(path=os.path.join(SHOTS, "artifact-quick-result-de.png"))
        _in_view_from_the_result(page, (1400, 900))
    finally:
        settings(server, enabled=False, params=ZERO, demo={"enabled": False, "live": True})
