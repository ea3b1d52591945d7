"""The printed artifact of the Calibration tab in a real headless Chromium against the real
server (issue 27): write the artifact, see its numbered drawing, type SIMULATED caliper
readings (with a 1 mm typo) into the measuring form, analyse, see the values with their
uncertainties and the typo named by its id, apply; the form in German. Screenshots go to
test-artifacts/screenshots/ (artifact-measure.png, artifact-result.png)."""

import os

import numpy as np
import pytest

from octoprint_kincomp.calibration.artifact.program import read_measurements
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.simulator.artifact import simulate_readings
from tests.support.browser import SHOTS, ZERO, no_popups, open_tab, step
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
    page.click("#kincomp_artifact_toggle")
    page.wait_for_selector("#kincomp_artifact_program", state="visible")


def test_measuring_form_result_and_apply(page, server):
    settings(server, enabled=False, params=ZERO)
    _open_artifact(page)
    page.fill("#kincomp_artifact_nozzle", "0.4")
    page.click("#kincomp_artifact_write")
    page.wait_for_selector("#kincomp_artifact_table tbody tr")
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
    page.wait_for_selector("#kincomp_artifact_error >> text=X1-out")
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
    assert page.is_visible("#kincomp_artifact_trusted")
    no_popups(page)
    page.screenshot(path=os.path.join(SHOTS, "artifact-result.png"), full_page=True)
    # the row of the typo is marked in the form
    page.click("#kincomp_artifact_step_measure")
    marked = page.locator("#kincomp_artifact_table tbody tr.error").all_inner_texts()
    assert len(marked) == 1 and "B3-in" in marked[0]
    page.click("#kincomp_artifact_step_result")
    page.click("#kincomp_artifact_apply")
    page.wait_for_selector("#kincomp_artifact_result >> text=Applied on")
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


def test_measuring_form_in_german(page, server):
    page.goto(server.url + "/?l10n=de")
    page.wait_for_selector("#tab_plugin_kincomp_link", state="attached")
    _open_artifact(page)
    assert "Gedrucktes Prüfteil" in page.inner_text("#kincomp_artifact_toggle")
    assert "Prüfteil drucken" in page.inner_text("#kincomp_artifact_print")
    page.click("#kincomp_artifact_write")
    page.wait_for_selector("#kincomp_artifact_table tbody tr")
    head = page.inner_text("#kincomp_artifact_table thead")
    assert "Nennmaß" in head and "Messwerte (mm)" in head
    first = page.locator("#kincomp_artifact_table tbody tr").first.inner_text()
    assert "außen" in first
    page.click("#kincomp_artifact_analyse")
    page.wait_for_selector("#kincomp_artifact_error >> text=Tragen Sie zuerst die Messwerte ein")
