"""Small helpers for KinComp's HTTP endpoints, used within a Flask request.

JSON error responses (``{"error": message}`` with a status code), the JSON body, boolean
flags, permission checks (403), texts in the requesting user's language, and the
permission KinComp adds to OctoPrint (``PLUGIN_KINCOMP_ADMIN``).
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional

import flask
from flask_babel import gettext
from octoprint.access import ADMIN_GROUP

from ..core.messages import as_dict, error_message, translate
from .notify import N_


def permissions() -> List[Dict[str, Any]]:
    """What the octoprint.access.permissions hook registers (as PLUGIN_KINCOMP_ADMIN)."""
    return [{
        "key": "ADMIN",
        "name": "KinComp admin",
        "description": N_("Change KinComp's parameters, run and apply calibrations and "
                          "compensate files"),
        "roles": ["admin"],
        "dangerous": True,
        "default_groups": [ADMIN_GROUP],
    }]


def error(message: str, status: int = 400):
    """A JSON error response."""
    return flask.make_response(flask.jsonify(error=message), status)


def tr(text) -> str:
    """A core message (messages.Msg) or exception in the requesting user's language."""
    if isinstance(text, BaseException):
        text = error_message(text)
    return translate(text, gettext)


def with_i18n(eq: Dict[str, Any]) -> Dict[str, Any]:
    """Firmware equivalents with their notes also as translatable templates."""
    return dict(eq, notes_i18n=[as_dict(n) for n in eq.get("notes", [])])


def json_object() -> Optional[Dict[str, Any]]:
    """The request's JSON body if it is an object, else None."""
    data = flask.request.get_json(silent=True)
    return data if isinstance(data, dict) else None


class BadRequest(ValueError):
    """A request field of the wrong type (answered 400 with this message)."""


def flag(data: Dict[str, Any], key: str) -> bool:
    """A JSON boolean field, False when absent. A string such as "false" is refused, not
    taken as true: these flags print, or apply parameters mid-print."""
    value = data.get(key, False)
    if not isinstance(value, bool):
        raise BadRequest(gettext("'%(key)s' must be true or false", key=key))
    return value


def require(permission) -> None:
    """Aborts the request with 403 unless the user has ``permission``."""
    if not permission.can():
        flask.abort(403)


def update_source_refused(old: Dict[str, Any], new: Dict[str, Any]):
    """403 if the request changes where KinComp's updates come from (the archive pip will
    install as OctoPrint's admin) without OctoPrint's own permission to configure software
    updates (an administrator's, not KinComp's); None otherwise."""
    if old.get("software_update") == new.get("software_update"):
        return None
    from octoprint.access.permissions import Permissions

    needed = getattr(Permissions, "PLUGIN_SOFTWAREUPDATE_CONFIGURE", None) or Permissions.ADMIN
    if needed.can():
        return None
    return error(gettext("Changing where KinComp's updates come from needs OctoPrint's "
                         "permission to configure software updates"), 403)
