"""Small helpers for KinComp's HTTP endpoints, used within a Flask request.

Routes are declared where they are handled: ``@route(rule, method, needs=(...))`` on a
method of a feature's piece marks it as the view of ``rule`` and guards it with the
OctoPrint permissions it needs (403 otherwise, checked before the method runs, also when it
is called directly); :func:`register` adds a piece's routes to the plugin's blueprint.
Besides: JSON error responses (``{"error": message}`` with a status code), the JSON body, boolean
flags, permission checks (403), texts in the requesting user's language, and the
permission KinComp adds to OctoPrint (``PLUGIN_KINCOMP_ADMIN``).
"""

from __future__ import annotations

import errno
import functools
import os
import re
from typing import Any, Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple

import flask
from flask_babel import gettext
from octoprint.access import ADMIN_GROUP
from octoprint.access.permissions import Permissions

from ..core.messages import as_dict, error_message, translate
from ..core.numbers import finite
from ..service.notify import N_


def permissions() -> List[Dict[str, Any]]:
    """What the octoprint.access.permissions hook registers (as PLUGIN_KINCOMP_ADMIN)."""
    return [
        {
            "key": "ADMIN",
            "name": "KinComp admin",
            "description": N_(
                "Change KinComp's parameters, run and apply calibrations and compensate files"
            ),
            "roles": ["admin"],
            "dangerous": True,
            "default_groups": [ADMIN_GROUP],
        }
    ]


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


MAX_JSON_DEPTH = 32  # nesting levels of a request body (ours need fewer than 10)


class BadRequest(ValueError):
    """A request field of the wrong type (answered 400 with this message)."""


class Refused(Exception):
    """A change refused with ``response`` (e.g. a 403) before anything was stored."""

    def __init__(self, response):
        super().__init__("refused")
        self.response = response


def expected_profile(data: Dict[str, Any]) -> Optional[str]:
    """``expected_profile`` taken out of a request ``data`` (the printer profile the page
    was loaded for; None: not given); BadRequest when it is not a text."""
    expected = data.pop("expected_profile", None)
    if expected is not None and not isinstance(expected, str):
        raise BadRequest(gettext("'%(key)s' must be a string", key="expected_profile"))
    return expected


def profile_changed(exc, names: Optional[Dict[str, str]]):
    """409 for a :class:`.settings_store.ProfileChanged`: the page was loaded for printer
    profile ``exc.expected`` but ``exc.current``'s set is in force now; nothing was saved.
    ``names``: the profiles' names by id, if known."""
    names = names or {}
    resp = flask.jsonify(
        error=gettext(
            "This page shows the settings of printer profile %(expected)s, but "
            "printer profile %(current)s is in force now. Reload the page to see and "
            "change %(current)s's settings.",
            expected=names.get(exc.expected) or exc.expected or "-",
            current=names.get(exc.current) or exc.current or "-",
        ),
        profile_changed={"expected": exc.expected, "current": exc.current},
    )
    return flask.make_response(resp, 409)


DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or the user's quota) is full."""
    return isinstance(exc, OSError) and exc.errno in DISK_FULL


# the request header KinComp's upload handler (files/upload_handler.py) sets when the
# uploaded file could not be written (the error's number: ENOSPC for a full disk; the file
# is not there then)
UPLOAD_FAILED = "X-KinComp-Upload-Error"


def upload_failed(headers) -> Optional[OSError]:
    """The error KinComp's upload handler met writing this request's file, if any."""
    value = headers.get(UPLOAD_FAILED)
    if value is None:
        return None
    num = int(value) if value.isdigit() else errno.EIO
    return OSError(num, os.strerror(num))


def os_error(exc: OSError):
    """The blueprint's handler of an OSError that reached it: 507 with a message when the
    disk is full (whatever was being written was not kept: every write is atomic), else
    re-raised (a 500: a fault of KinComp's own)."""
    if disk_full(exc):
        return error(
            gettext(
                "The disk is full: KinComp could not store this (nothing was "
                "changed). Free some space and try again."
            ),
            507,
        )
    raise exc


def rationed(gate):
    """None when ``gate`` (a :class:`..service.request_gate.RequestGate`) admits the
    requesting user's request now (it may have waited for its turn), else 429 with
    ``Retry-After``."""
    # each user's scripts (an API key) and pages (a login session) have rations of their own:
    # a script asking in a loop must not leave the user's page waiting
    req = flask.request
    how = "key" if req.headers.get("X-Api-Key") or req.args.get("apikey") else "page"
    wait = gate.admit(f"{current_user()[0] or ''} ({how})")
    if wait is None:
        return None
    resp = error(
        gettext(
            "A print is running: KinComp answers a few requests a second then. "
            "Ask again in %(seconds)s s.",
            seconds=f"{wait:g}",
        ),
        429,
    )
    resp.headers["Retry-After"] = f"{wait:g}"
    return resp


def abort(status: int, message: str):
    """Ends the request with the JSON error response ``message`` (``status``)."""
    flask.abort(error(message, status))


def check_json(data: Any) -> None:
    """:class:`BadRequest` for a body nested deeper than MAX_JSON_DEPTH, holding a number
    that is not finite (NaN, Infinity, 1e400) or a text that is not valid Unicode (a lone
    surrogate), naming the field."""
    stack = [(data, "", 1)]
    while stack:
        value, where, depth = stack.pop()
        if (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and finite(value) is None
        ):
            raise BadRequest(gettext("'%(key)s' must be a finite number", key=where or "body"))
        if isinstance(value, str) and not _encodable(value):
            raise BadRequest(
                gettext("'%(key)s' is not valid text (a lone surrogate)", key=where or "body")
            )
        if isinstance(value, (dict, list)):
            if depth > MAX_JSON_DEPTH:
                raise BadRequest(
                    gettext(
                        "The request body is nested too deeply (at most %(n)s levels)",
                        n=MAX_JSON_DEPTH,
                    )
                )
            items = value.items() if isinstance(value, dict) else enumerate(value)
            for key, item in items:
                if isinstance(key, str) and not _encodable(key):
                    raise BadRequest(
                        gettext(
                            "'%(key)s' is not valid text (a lone surrogate)", key=where or "body"
                        )
                    )
                name = (
                    f"{where}[{key}]"
                    if isinstance(key, int)
                    else (f"{where}.{key}" if where else str(key))
                )
                stack.append((item, name, depth + 1))


def _encodable(text: str) -> bool:
    """Whether ``text`` is valid Unicode (JSON's \\ud800 escapes can make one that is not,
    and it could then be stored nowhere: config.yaml's writer fails on it)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def json_body() -> Any:
    """The request's JSON body (None if there is none or it is not JSON), checked with
    :func:`check_json`."""
    try:
        data = flask.request.get_json(silent=True)
    except RecursionError:
        raise BadRequest(
            gettext(
                "The request body is nested too deeply (at most %(n)s levels)", n=MAX_JSON_DEPTH
            )
        ) from None
    check_json(data)
    return data


def json_object() -> Optional[Dict[str, Any]]:
    """The request's JSON body if it is an object, else None (see :func:`json_body`)."""
    data = json_body()
    return data if isinstance(data, dict) else None


def bad_request(exc: BadRequest):
    """The blueprint's handler of :class:`BadRequest`: 400 with its message."""
    return error(str(exc), 400)


def flag(data: Dict[str, Any], key: str) -> bool:
    """A JSON boolean field, False when absent. A string such as "false" is refused, not
    taken as true: these flags print, or apply parameters mid-print."""
    value = data.get(key, False)
    if not isinstance(value, bool):
        raise BadRequest(gettext("'%(key)s' must be true or false", key=key))
    return value


def number(
    data: Dict[str, Any], key: str, default: Optional[float] = None, prefix: str = ""
) -> float:
    """A finite JSON number field (``default`` when absent; required when that is None)."""
    value = finite(data.get(key, default))
    if value is None:
        raise BadRequest(gettext("'%(key)s' must be a finite number", key=prefix + key))
    return value


def numbers(data: Dict[str, Any], key: str, n: int, default) -> List[float]:
    """A field holding a list of ``n`` finite numbers (``default`` when absent)."""
    value = data.get(key, default)
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise BadRequest(gettext("'%(key)s' must be a list of %(n)s numbers", key=key, n=n))
    return [number({key: v}, key) for v in value]


def choice(data: Dict[str, Any], key: str, choices, default: str) -> str:
    """A field holding one of ``choices`` (upper-case; any case accepted)."""
    value = data.get(key, default)
    if not isinstance(value, str) or value.upper() not in choices:
        raise BadRequest(
            gettext("'%(key)s' must be one of %(choices)s", key=key, choices=", ".join(choices))
        )
    return value.upper()


def current_user() -> Tuple[Optional[str], bool]:
    """(name, has KinComp's admin permission) of the requesting user; (None, False) where
    there is none (no login, no request)."""
    try:
        import flask_login

        user = flask_login.current_user
        name = user.get_name() if user is not None and not user.is_anonymous else None
    except Exception:
        name = None
    try:
        admin = bool(Permissions.PLUGIN_KINCOMP_ADMIN.can())
    except Exception:
        admin = False
    return name, admin


def require(permission) -> None:
    """Aborts the request with 403 unless the user has ``permission``."""
    if not permission.can():
        flask.abort(403)


# the permissions a route may need, by their names in OctoPrint's Permissions (KinComp's own
# is registered by the permissions hook, after this module is imported: looked up per request)
PLUGIN_KINCOMP_ADMIN = "PLUGIN_KINCOMP_ADMIN"
STATUS = "STATUS"
FILES_LIST = "FILES_LIST"
FILES_UPLOAD = "FILES_UPLOAD"
FILES_DOWNLOAD = "FILES_DOWNLOAD"


class Route(NamedTuple):
    rule: str  # Flask's rule, relative to /plugin/kincomp
    method: str  # GET, POST, DELETE
    needs: Tuple[str, ...]  # names in OctoPrint's Permissions, each required


def route(rule: str, method: str, needs: Sequence[str]) -> Callable:
    """Declares a piece's method the view of ``rule`` (``method``), allowed only to a user
    with every permission of ``needs`` (names of :data:`PLUGIN_KINCOMP_ADMIN`, :data:`STATUS`
    ...); the check runs before the method whichever way it is called."""

    ints = _INT_PART.findall(rule)

    def mark(fn):
        @functools.wraps(fn)
        def guarded(*args, **kwargs):
            for name in needs:
                require(getattr(Permissions, name))
            for key in ints:  # (registered as text: Werkzeug's int takes any Unicode digit)
                if key in kwargs:
                    kwargs[key] = ascii_int(kwargs[key])
            return fn(*args, **kwargs)

        guarded.kincomp_route = Route(rule, method, tuple(needs))
        return guarded

    return mark


_INT_PART = re.compile(r"<int:(\w+)>")


def ascii_int(value: Any) -> int:
    """A rule's ``<int:..>`` part: ASCII digits only (``/steps/\u0663/`` is no test 3: 404)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value.isascii() and value.isdigit():
        return int(value)
    flask.abort(404)


def routes_of(piece: Any) -> List[Tuple[Route, Callable]]:
    """(route, bound view) of every method of ``piece`` declared with :func:`route`."""
    out = []
    for name in dir(type(piece)):
        declared = getattr(getattr(type(piece), name, None), "kincomp_route", None)
        if declared is not None:
            out.append((declared, getattr(piece, name)))
    return sorted(out, key=lambda rv: (rv[0].rule, rv[0].method))


def register(blueprint, piece: Any) -> None:
    """Adds the routes of ``piece`` to ``blueprint`` (each endpoint named by the piece's
    class and method)."""
    for declared, view in routes_of(piece):
        endpoint = f"{type(piece).__name__}_{view.__name__}"
        rule = _INT_PART.sub(r"<\1>", declared.rule)
        blueprint.add_url_rule(rule, endpoint=endpoint, view_func=view, methods=[declared.method])


def update_source_refused(old: Dict[str, Any], new: Dict[str, Any]):
    """403 if the request changes where KinComp's updates come from (the archive pip will
    install as OctoPrint's admin) without OctoPrint's own permission to configure software
    updates (an administrator's, not KinComp's); 409 while OctoPrint's software update
    plugin is disabled (its permission is unknown then); None otherwise."""
    if old.get("software_update") == new.get("software_update"):
        return None
    from octoprint.access.permissions import UnknownPermission

    try:  # (even the truth of an unknown plugin permission raises: no "or" here)
        needed = getattr(Permissions, "PLUGIN_SOFTWAREUPDATE_CONFIGURE", None)
        allowed = (Permissions.ADMIN if needed is None else needed).can()
    except UnknownPermission:  # the software update plugin is disabled: nothing to check by
        return error(
            gettext(
                "OctoPrint's software update plugin is disabled: enable it to "
                "change where KinComp's updates come from"
            ),
            409,
        )
    if allowed:
        return None
    return error(
        gettext(
            "Changing where KinComp's updates come from needs OctoPrint's "
            "permission to configure software updates"
        ),
        403,
    )
