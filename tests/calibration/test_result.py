"""The result document and its verdict (calibration/result.py): one shape for every
analysis, and the decision decided in one place, also for stored runs."""

import pytest

from octoprint_kincomp.calibration import findings as F
from octoprint_kincomp.calibration.result import DECISIONS, result_document, verdict
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.service.calibration.findings_view import verdict_of
from octoprint_kincomp.service.calibration.run_store import RunStore


def _found(*severities):
    return [F.Finding(f"c.{i}", s, f"{s} {i}") for i, s in enumerate(severities)]


@pytest.mark.parametrize(
    "severities, decision, reason",
    [
        ((), "apply", None),
        (("info", "info"), "apply", None),
        (("info", "warning", "warning"), "apply_with_care", "warning 1"),
        (("warning", "error", "info"), "do_not_apply", "error 1"),
    ],
)
def test_the_verdict_follows_the_worst_finding(severities, decision, reason):
    found = _found(*severities)
    assert verdict(found) == {"decision": decision, "reason": reason}
    # the same from the findings' dicts, in any order
    dicts = [f.to_dict() for f in reversed(found)]
    assert verdict(dicts)["decision"] == decision


def test_every_analysis_returns_the_same_document():
    doc = result_document({"plane": "XY"}, Params(), _found("info", "warning"), ["a note"])
    assert set(doc) == {
        "diagnostics",
        "parameters",
        "firmware",
        "findings",
        "findings_i18n",
        "trusted",
        "verdict",
        "notes",
        "plot",
        "needs_confirmation",
    }
    assert doc["needs_confirmation"] is None
    assert [f["severity"] for f in doc["findings"]] == ["warning", "info"]
    assert doc["trusted"] is True
    assert doc["verdict"]["decision"] == "apply_with_care"
    assert doc["verdict"]["reason"]["text"] == "warning 1"
    assert doc["verdict"]["decision"] in DECISIONS


def test_a_stored_run_carries_its_verdict_and_an_old_one_gets_it(tmp_path):
    runs = RunStore(str(tmp_path))
    wire = [f.to_wire() for f in _found("error")]
    run = {"id": runs.new_id(), "findings": wire, "trusted": False, "diagnostics": {}}
    runs.save(run)
    assert runs.get(run["id"])["verdict"]["decision"] == "do_not_apply"
    # a run stored before verdicts (written by hand here): decided when read
    old = {"id": runs.new_id(), "notes": ["from an old version"], "diagnostics": {}}
    runs.save(old)
    path = runs._path(old["id"])
    text = open(path).read().replace('"verdict"', '"no_verdict"')
    open(path, "w").write(text)
    assert runs.get(old["id"])["verdict"] == {"decision": "apply", "reason": None}
    assert runs.summary(runs.get(run["id"]))["verdict"] == "do_not_apply"


def test_a_run_said_untrusted_is_never_to_be_applied():
    run = {"findings": [f.to_wire() for f in _found("warning")], "trusted": False}
    assert verdict_of(run)["decision"] == "do_not_apply"
