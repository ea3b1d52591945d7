"""Issue 37 row 10, the low items, through the real blueprint (tests/support/blueprint.py):
a test program refused with 409 (printer not ready) writes no file; a second cancel of a
running job is 409; ``/steps/<Unicode digit>/`` is no test number; ``/artifact/sheet``
reads a stored file, so it needs OctoPrint's download permission as well as STATUS."""

from unittest import mock

import pytest

from tests.support.blueprint import PREFIX, blueprint_client


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path))
    yield ns
    ns.stop()


def _gcode_files(api):
    """The programs handed to OctoPrint's file manager."""
    return [c.args[1] for c in api.plugin._file_manager.add_file.call_args_list]


@pytest.mark.parametrize("route", ["/program", "/artifact/program"])
def test_a_program_refused_for_a_busy_printer_writes_no_file(api, route):
    api.plugin._printer.is_operational.return_value = True
    api.plugin._printer.is_printing.return_value = True  # busy
    resp = api.client.post(PREFIX + route, json={"print": True})
    assert resp.status_code == 409, resp.get_json()
    assert _gcode_files(api) == []
    resp = api.client.post(PREFIX + route, json={})  # without printing: written
    assert resp.status_code == 200, resp.get_json()
    assert len(_gcode_files(api)) == 1


def test_a_test_number_in_unicode_digits_is_no_test(api):
    plan = api.client.post(PREFIX + "/campaign/plan", json={"planes": ["XY"]})
    assert plan.status_code == 200, plan.get_json()
    cid = plan.get_json()["id"]
    for n in ("\u0661", "\uff11", "1\u0660"):  # Arabic-Indic one, fullwidth one, "10"
        resp = api.client.post(PREFIX + f"/campaigns/{cid}/steps/{n}/program", json={})
        assert resp.status_code == 404, (n, resp.get_json())
    resp = api.client.post(PREFIX + f"/campaigns/{cid}/steps/1/program", json={})
    assert resp.status_code == 200, resp.get_json()


def test_the_artifact_sheet_needs_the_download_permission(api):
    from octoprint_kincomp.plugin import http

    with mock.patch.object(http, "require") as require:
        api.client.get(PREFIX + "/artifact/sheet?path=none.gcode")
    asked = [c.args[0] for c in require.call_args_list]
    from octoprint.access.permissions import Permissions

    assert Permissions.FILES_DOWNLOAD in asked and Permissions.STATUS in asked


def test_kincomps_requests_are_rationed_while_a_print_runs(api):
    """Row 6: the before-request handler KinComp adds to OctoPrint's API blueprints
    (``ration_request``) answers a request over its ration 429 with ``Retry-After`` while a
    print runs; OctoPrint's own routes and any request without a print pass."""
    from octoprint_kincomp.service.request_gate import RequestGate

    plugin = api.plugin
    assert plugin.ration_request in plugin.before_api_request_hook()
    plugin.requests = RequestGate(
        lambda: plugin.queue.printing, per_user_burst=1, burst=1, max_wait_s=0.0
    )

    def asked(path):
        with api.app.test_request_context(path):
            return plugin.ration_request()

    assert asked(PREFIX + "/status") is None and asked(PREFIX + "/status") is None  # no print
    plugin.queue.printing = True
    try:
        assert asked(PREFIX + "/status") is None
        refused = asked(PREFIX + "/runs")
        assert refused.status_code == 429 and refused.headers["Retry-After"] == "1"
        assert "A print is running" in refused.get_json()["error"]
        assert asked("/api/version") is None  # OctoPrint's own: not KinComp's to ration
    finally:
        plugin.queue.printing = False


def test_a_users_scripts_and_pages_have_rations_of_their_own(api):
    """Row 6: a script asking in a loop with the user's API key must not leave the user's
    page (a login session, no key) waiting: each has a ration of its own."""
    from octoprint_kincomp.service.request_gate import RequestGate

    plugin = api.plugin
    plugin.requests = RequestGate(
        lambda: plugin.queue.printing, per_user_burst=1, burst=10, max_wait_s=0.0
    )

    def asked(headers=None, query=""):
        with api.app.test_request_context(PREFIX + "/status" + query, headers=headers or {}):
            resp = plugin.ration_request()
            return None if resp is None else resp.status_code

    plugin.queue.printing = True
    try:
        key = {"X-Api-Key": "ABC"}
        assert asked(key) is None and asked(key) == 429  # the script's ration spent
        assert asked(query="?apikey=ABC") == 429  # a key in the query is the script too
        assert asked() is None  # the page's own
        assert asked() == 429
    finally:
        plugin.queue.printing = False
