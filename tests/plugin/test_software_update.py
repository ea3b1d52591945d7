"""The software update hook (issue 14): OctoPrint's own version checks and pip updater take
KinComp's configuration; the update source is a validated setting."""

import http.server
import json
import threading

import pytest
from octoprint.plugins.softwareupdate.updaters import pip as pip_updater
from octoprint.plugins.softwareupdate.version_checks import github_release, jsondata

from octoprint_kincomp import __plugin_url__, __version__
from octoprint_kincomp.service.settings.schema import SettingsError, defaults, validate_settings
from octoprint_kincomp.service.settings.software_update import check_config
from tests.support import permissions
from tests.support.mocked_plugin import mocked_plugin


def test_the_hook_is_registered_and_reads_the_version_from_the_package(tmp_path):
    from octoprint_kincomp.plugin.kincomp_plugin import plugin_hooks

    plugin = mocked_plugin(str(tmp_path))
    hook = plugin_hooks(plugin)["octoprint.plugin.softwareupdate.check_config"]
    config = hook()["kincomp"]
    assert config["current"] == config["displayVersion"] == __version__
    assert config["type"] == "github_release"
    assert __plugin_url__.endswith("/" + config["user"] + "/" + config["repo"])
    assert config["pip"] == __plugin_url__ + "/archive/{target_version}.zip"


def test_github_release_config_is_valid_for_octoprints_check_and_pip_updater():
    check = check_config(defaults()["software_update"])["kincomp"]
    # offline, OctoPrint's check reads the local version and reports it current; a
    # malformed configuration (no user/repo) is refused before that
    info, is_current = github_release.get_latest("kincomp", check, online=False)
    assert info["local"]["value"] == __version__ and is_current
    broken = dict(check)
    del broken["repo"]
    with pytest.raises(Exception) as exc:
        github_release.get_latest("kincomp", broken, online=False)
    assert type(exc.value).__name__ == "ConfigurationInvalid"
    assert pip_updater.can_perform_update("kincomp", check)


class _Version(http.server.BaseHTTPRequestHandler):
    def do_GET(self):
        body = json.dumps({"version": "9.9.9"}).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def test_a_plain_archive_source_is_checked_by_octoprints_jsondata_check():
    s = validate_settings(
        {
            "software_update": {
                "type": "jsondata",
                "version_url": "https://example.org/kincomp.json",
                "archive_url": "https://example.org/kincomp-{target_version}.zip",
            }
        }
    )
    assert (
        check_config(s["software_update"])["kincomp"]["jsondata"]
        == "https://example.org/kincomp.json"
    )
    server = http.server.HTTPServer(("127.0.0.1", 0), _Version)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        # (the test's server speaks plain http on loopback: the setting itself takes https)
        url = f"http://127.0.0.1:{server.server_port}/kincomp.json"
        check = check_config(dict(s["software_update"], version_url=url))["kincomp"]
        info, is_current = jsondata.get_latest("kincomp", check, online=True)
        assert info["local"]["value"] == __version__ and info["remote"]["value"] == "9.9.9"
        assert is_current is False
        assert pip_updater.can_perform_update("kincomp", check)
    finally:
        server.shutdown()


@pytest.mark.parametrize(
    "value, field",
    [
        ({"type": "svn"}, "software_update.type"),
        (
            {
                "type": "jsondata",
                "version_url": "ftp://x/y",
                "archive_url": "https://a/{target_version}",
            },
            "software_update.version_url",
        ),
        (
            {
                "type": "jsondata",
                "version_url": "http://x/v.json",
                "archive_url": "https://a/{target_version}",
            },
            "software_update.version_url",
        ),
        (
            {
                "type": "jsondata",
                "version_url": "https://x/v.json",
                "archive_url": "http://a/{target_version}",
            },
            "software_update.archive_url",
        ),
        (
            {
                "type": "jsondata",
                "version_url": "https://x/v.json",
                "archive_url": "https://a/b.zip",
            },
            "software_update.archive_url",
        ),
        ({"type": "github_release", "branch": "x"}, "software_update"),
        ("github", "software_update"),
    ],
)
def test_a_bad_update_source_is_refused_naming_the_field(value, field):
    with pytest.raises(SettingsError) as exc:
        validate_settings({"software_update": value})
    assert exc.value.field == field


def test_changing_the_update_source_needs_octoprints_update_permission(tmp_path):
    """KinComp's own admin permission is not enough to change what pip will install."""
    from unittest import mock

    from tests.support.mocked_plugin import api_app

    plugin = mocked_plugin(str(tmp_path))
    body = {
        "software_update": {
            "type": "jsondata",
            "version_url": "https://e.org/v.json",
            "archive_url": "https://e.org/k-{target_version}.zip",
        }
    }
    app = api_app()
    for allowed, status in ((False, 403), (True, 200)):
        with permissions.granted(), mock.patch("octoprint.access.permissions.Permissions") as perms:
            perms.PLUGIN_SOFTWAREUPDATE_CONFIGURE.can.return_value = allowed
            with app.test_request_context("/settings", method="POST", json=body):
                resp = plugin.settings_api.save()
        assert getattr(resp, "status_code", 200) == status
        stored = plugin.store.current()["software_update"]["type"]
        assert stored == ("jsondata" if allowed else "github_release")
    # the rest of the settings needs no more than before
    with permissions.granted(), mock.patch("octoprint.access.permissions.Permissions") as perms:
        perms.PLUGIN_SOFTWAREUPDATE_CONFIGURE.can.return_value = False
        with app.test_request_context("/settings", method="POST", json={"enabled": True}):
            assert getattr(plugin.settings_api.save(), "status_code", 200) == 200


class _UnknownPermission:
    """What OctoPrint hands for a permission of a disabled plugin: asking it anything, even
    its truth, raises UnknownPermission."""

    def __bool__(self):
        from octoprint.access.permissions import UnknownPermission

        raise UnknownPermission("PLUGIN_SOFTWAREUPDATE_CONFIGURE")

    can = __bool__


def test_changing_the_update_source_with_the_update_plugin_disabled_is_a_409(tmp_path):
    """Issue 26: OctoPrint's software update plugin disabled, its permission is unknown
    (UnknownPermission was a 500): 409 on both ways in, nothing stored."""
    from unittest import mock

    from tests.support.mocked_plugin import api_app

    plugin = mocked_plugin(str(tmp_path))
    body = {
        "software_update": {
            "type": "jsondata",
            "version_url": "https://e.org/v.json",
            "archive_url": "https://e.org/k-{target_version}.zip",
        }
    }
    app = api_app()
    with permissions.granted(), mock.patch("octoprint.access.permissions.Permissions") as perms:
        perms.PLUGIN_SOFTWAREUPDATE_CONFIGURE = _UnknownPermission()
        with app.test_request_context("/settings", method="POST", json=body):
            resp = plugin.settings_api.save()
        assert resp.status_code == 409 and "disabled" in resp.get_json()["error"]
        with app.test_request_context(
            "/api/settings", method="POST", json={"plugins": {"kincomp": body}}
        ), mock.patch("octoprint_kincomp.plugin.settings.settings_store.Permissions"):
            resp = plugin.store.check_settings_request()
        assert resp.status_code == 409
    assert plugin.store.current()["software_update"]["type"] == "github_release"
