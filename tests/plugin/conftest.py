"""The plugin layer's tests (a mocked OctoPrint around the real plugin)."""

import pytest


@pytest.fixture(autouse=True)
def analyses_answer_in_the_request(monkeypatch):
    """An analysis comes in the request's answer however loaded the machine is (the 20 s
    after which a real server answers 202 with the job is about the user's wait, not what
    these tests check; the 202 path has tests of its own in tests/e2e)."""
    from octoprint_kincomp.plugin.calibration import calibration_api

    monkeypatch.setattr(calibration_api, "TRACE_WAIT_S", 600.0)
