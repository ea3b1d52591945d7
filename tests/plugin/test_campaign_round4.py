"""Issue 37 rows 2, 4 and 5 on the plugin with mocked OctoPrint objects, its jobs run in the
calling process: a measurement stays with the printer profile it was made on whatever is
switched during its analysis (and /apply on another profile is refused unless forced); a
campaign deleted during an analysis stays deleted and nothing is stored; two tests measured
at once both land; the same test twice at once is refused, leaving no orphaned run."""

import contextlib
import threading
from unittest import mock

import pytest

from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate, spec_from_program
from octoprint_kincomp.simulator.demo import demo_truth
from octoprint_kincomp.simulator.printer import simulate_program
from tests.plugin.test_campaign_api import OTHER, PROFILE, call, offline_trace, plan, upload
from tests.support.mocked_plugin import api_app, mocked_plugin

# where the analysis is looked up (today's entry point; before issue 37: each caller's own)
ANALYSE = (
    "octoprint_kincomp.service.calibration.measurement.analyse",
    "octoprint_kincomp.service.calibration.campaign_measure.analyse",
    "octoprint_kincomp.calibration.ballbar.analysis.analyse",
)


@pytest.fixture
def plugin(tmp_path):
    from octoprint_kincomp.service.files.worker import InProcessWorker

    p = mocked_plugin(str(tmp_path), profile=PROFILE)
    p._printer.is_printing.return_value = False
    p.jobs.worker = InProcessWorker()
    yield p
    p.sensor._release()


@pytest.fixture
def app():
    return api_app()


@contextlib.contextmanager
def held_analysis():
    """Every analysis waits for ``go`` once it has begun (``started``)."""
    import importlib

    from octoprint_kincomp.calibration.ballbar import analysis

    started, go = threading.Event(), threading.Event()
    real = analysis.analyse

    def held(*args, **kwargs):
        started.set()
        assert go.wait(30)
        return real(*args, **kwargs)

    with contextlib.ExitStack() as stack:
        for target in ANALYSE:
            module, name = target.rsplit(".", 1)
            try:
                if hasattr(importlib.import_module(module), name):
                    stack.enter_context(mock.patch(target, held))
            except ImportError:
                pass
        yield started, go


def in_thread(fn):
    out = {}
    t = threading.Thread(target=lambda: out.update(r=fn()))
    t.start()
    return t, out


def switch_profile(plugin, profile):
    pm = plugin._printer_profile_manager
    pm.get_current.return_value = pm.get_current_or_default.return_value = profile
    plugin.store.follow_profile()


def _trace():
    spec = TestSpec(plane="XY", centre=(100.0, 100.0, 10.0), radius_mm=50.0)
    text = generate(spec)
    spec, prog_hash = spec_from_program(text)
    return simulate_program(text, demo_truth(), spec, prog_hash).to_text()


def test_a_measurement_stays_with_the_profile_it_was_made_on(app, plugin, tmp_path):
    trace = tmp_path / "t.csv"
    trace.write_text(_trace())
    data = {"file.path": str(trace), "file.name": "t.csv"}
    with held_analysis() as (started, go):
        t, out = in_thread(lambda: call(app, plugin.calibration.trace, data=data))
        assert started.wait(30)
        switch_profile(plugin, OTHER)  # during the analysis
        go.set()
        t.join(60)
    code, run = out["r"]
    assert code == 200, run
    assert run["profile"] == "_default"
    code, body = call(app, plugin.calibration.apply, json={"run": run["id"]})
    assert code == 409 and "_default" in body["error"], body
    code, body = call(
        app, plugin.calibration.apply, json={"run": run["id"], "expected_profile": "_default"}
    )
    assert code == 409, body  # a page loaded for the run's printer: refused, force or not
    # (an upload KinComp did not print: what the data cannot check is confirmed, issue 34)
    need = run["needs_confirmation"]
    confirm = {k: need["stated"][k] for k in need["confirm"]}
    code, body = call(
        app, plugin.calibration.apply, json={"run": run["id"], "force": True, "confirm": confirm}
    )
    assert code == 200, body  # forced: applied with a warning (test_printer_profiles.py)
    assert [f["code"] for f in body["findings"]] == ["applied.other_profile"]


def test_a_campaign_deleted_during_an_analysis_stays_deleted(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    text = offline_trace(doc, 1)
    with held_analysis() as (started, go):
        t, out = in_thread(lambda: upload(app, plugin, tmp_path, cid, 1, text))
        assert started.wait(30)
        code, _ = call(app, plugin.campaign.delete, cid)
        assert code == 200
        go.set()
        t.join(60)
    code, body = out["r"]
    assert code == 404, body
    assert cid not in [c["id"] for c in plugin.campaign._campaigns.documents()]
    assert not [r for r in plugin.runs.documents() if r.get("campaign") == cid]


def test_two_tests_measured_at_once_both_land(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    texts = [offline_trace(doc, n) for n in (1, 2)]
    with held_analysis() as (started, go):
        threads = [
            in_thread(lambda n=n: upload(app, plugin, tmp_path, cid, n, texts[n - 1], f"t{n}.csv"))
            for n in (1, 2)
        ]
        assert started.wait(30)
        go.set()
        for t, _ in threads:
            t.join(120)
    assert [out["r"][0] for _, out in threads] == [200, 200], [o["r"] for _, o in threads]
    stored = plugin.campaign._campaigns.get(cid)
    assert all(s["run"] for s in stored["steps"][:2]), stored["steps"][:2]


def test_the_same_test_twice_at_once_is_refused_without_an_orphan(app, plugin, tmp_path):
    doc = plan(app, plugin)
    cid = doc["id"]
    text = offline_trace(doc, 1)
    with held_analysis() as (started, go):
        first = in_thread(lambda: upload(app, plugin, tmp_path, cid, 1, text, "a.csv"))
        assert started.wait(30)
        second = in_thread(lambda: upload(app, plugin, tmp_path, cid, 1, text, "b.csv"))
        second[0].join(10)  # refused at once
        go.set()
        first[0].join(60)
    codes = sorted([first[1]["r"][0], second[1]["r"][0]])
    assert codes == [200, 409], (first[1], second[1])
    runs = [r for r in plugin.runs.documents() if r.get("campaign") == cid]
    assert len(runs) == 1  # no orphaned run
    assert plugin.campaign._campaigns.get(cid)["steps"][0]["run"] == runs[0]["id"]


def test_an_analysed_campaign_can_be_analysed_again(app, plugin, tmp_path):
    """The lock's check of an analysis stored meanwhile compares with the result the
    analysis started from: analysing an analysed campaign again (after a test was measured
    again, say) stores the new result; it was a 409 "analysed meanwhile" after the whole
    joint fit had run (issue 37's load probe: every re-analysis refused)."""
    doc = plan(app, plugin)
    cid = doc["id"]
    for n in (1, 2, 3):
        code, _ = upload(app, plugin, tmp_path, cid, n, offline_trace(doc, n), f"t{n}.csv")
        assert code == 200
    code, first = call(app, plugin.campaign.analyze, cid)
    assert code == 200, first
    before = plugin.campaign._campaigns.get(cid)["result"]
    code, again = call(app, plugin.campaign.analyze, cid)
    assert code == 200, again
    after = plugin.campaign._campaigns.get(cid)["result"]
    assert after and after != before and plugin.runs.get(after)["source"] == "campaign"
