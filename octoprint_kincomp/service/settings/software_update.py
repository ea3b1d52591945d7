"""How OctoPrint's software update plugin finds and installs new KinComp versions (the
``octoprint.plugin.softwareupdate.check_config`` hook), from the ``software_update`` setting:

* ``{"type": "github_release"}`` (default): the releases of the project's GitHub repository
  (``core.version.HOMEPAGE``), installed from the release's source archive;
* ``{"type": "jsondata", "version_url": ..., "archive_url": ...}``: a plain archive URL for
  mirrors and forks: ``version_url`` answers ``{"version": "x.y.z"}``, ``archive_url`` names
  the archive to install, with ``{target_version}`` where the version goes. Both https only;
  changing the source needs OctoPrint's permission to configure software updates (pip
  installs the archive as the user OctoPrint runs as), not only KinComp's admin permission.

The running version is ``core.version.VERSION``. No OctoPrint import here.
"""

from __future__ import annotations

from typing import Any, Dict
from urllib.parse import urlsplit

from ...core.messages import Msg
from ...core.version import HOMEPAGE, VERSION

TYPES = ("github_release", "jsondata")


class UpdateSettingsError(ValueError):
    def __init__(self, field: str, message: Msg):
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")


def default_settings() -> Dict[str, Any]:
    return {"type": "github_release", "version_url": "", "archive_url": ""}


def _url(value: Any, field: str, template: bool = False) -> str:
    # https only: pip installs what this names, as the user OctoPrint runs as
    if not isinstance(value, str) or len(value) > 500:
        raise UpdateSettingsError(field, Msg("must be an https address"))
    parts = urlsplit(value)
    if parts.scheme != "https" or not parts.netloc:
        raise UpdateSettingsError(field, Msg("must be an https address"))
    if template and "{target_version}" not in value:
        raise UpdateSettingsError(
            field, Msg("must contain {target_version} where the version goes")
        )
    return value


def validate(value: Any) -> Dict[str, Any]:
    """A checked copy of the ``software_update`` setting (UpdateSettingsError naming the
    field otherwise)."""
    if not isinstance(value, dict) or set(value) - set(default_settings()):
        raise UpdateSettingsError(
            "software_update", Msg("must be an object with 'type', 'version_url' and 'archive_url'")
        )
    out = dict(default_settings(), **value)
    if out["type"] not in TYPES:
        raise UpdateSettingsError(
            "software_update.type", Msg("must be one of %(choices)s", choices=", ".join(TYPES))
        )
    if out["type"] == "jsondata":
        out["version_url"] = _url(out["version_url"], "software_update.version_url")
        out["archive_url"] = _url(out["archive_url"], "software_update.archive_url", template=True)
    else:
        for key in ("version_url", "archive_url"):
            if not isinstance(out[key], str):
                raise UpdateSettingsError(f"software_update.{key}", Msg("must be text"))
    return out


def check_config(setting: Dict[str, Any], identifier: str = "kincomp") -> Dict[str, Any]:
    """The software update plugin's configuration for KinComp (``{identifier: {...}}``)."""
    common = {"displayName": "KinComp", "displayVersion": VERSION, "current": VERSION}
    if setting.get("type") == "jsondata":
        config = dict(
            common, type="jsondata", jsondata=setting["version_url"], pip=setting["archive_url"]
        )
    else:
        user, repo = HOMEPAGE.rstrip("/").split("/")[-2:]
        config = dict(
            common,
            type="github_release",
            user=user,
            repo=repo,
            pip=HOMEPAGE + "/archive/{target_version}.zip",
        )
    return {identifier: config}
