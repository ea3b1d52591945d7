"""Translatable messages of the core (no OctoPrint or Babel import here).

The core speaks English: exceptions, analysis notes and command-line output. A :class:`Msg`
is such an English text that also keeps its template and parameters, so that the OctoPrint
layer can show it in the user's language (:func:`translate` on the server, or the template
and parameters sent to the browser, see :func:`as_dict`). Templates use ``%(name)s`` only
(numbers are formatted into the parameters), which Python and the browser's ``sprintf``
both understand; Babel extracts them with the keyword ``Msg`` (scripts/translations.sh).
"""

from __future__ import annotations

from typing import Any, Callable, Dict, Union


class Msg(str):
    """English text of ``template % params`` that remembers both."""

    template: str
    params: Dict[str, Any]

    def __new__(cls, template: str, **params: Any) -> Msg:
        obj = super().__new__(cls, template % params if params else template)
        obj.template = template
        obj.params = params
        return obj

    def __reduce__(self):  # pickles (and deep-copies) as the Msg it is
        return (_rebuild, (self.template, self.params))


def _rebuild(template: str, params: Dict[str, Any]) -> Msg:
    return Msg(template, **params)


def joined(items) -> Union[str, Msg]:
    """Several messages as one, separated by "; " (each stays translatable)."""
    items = list(items)
    if len(items) == 1:
        return items[0]
    return Msg("%(first)s; %(rest)s", first=items[0], rest=joined(items[1:]))


def translate(text: Union[str, Msg], gettext: Callable[[str], str]) -> str:
    """``text`` in the language of ``gettext`` if it is a :class:`Msg` (parameters that are
    messages too are translated as well); any other text as it is."""
    if not isinstance(text, Msg):
        return str(text)
    params = {k: translate(v, gettext) if isinstance(v, Msg) else v for k, v in text.params.items()}
    return gettext(text.template) % params if params else gettext(text.template)


def as_dict(text: Union[str, Msg]) -> Dict[str, Any]:
    """JSON form for the browser: ``{"text", "template", "params"}`` (nested messages as
    such dicts); a plain text has no template."""
    if not isinstance(text, Msg):
        return {"text": str(text)}
    return {
        "text": str(text),
        "template": text.template,
        "params": {k: as_dict(v) if isinstance(v, Msg) else v for k, v in text.params.items()},
    }


def error_message(exc: BaseException) -> Union[str, Msg]:
    """The message of a core exception: ``field: message`` when it names a field."""
    message = getattr(exc, "message", None)
    if message is None:
        message = exc.args[0] if exc.args and isinstance(exc.args[0], str) else str(exc)
    field = getattr(exc, "field", "")
    if field:
        return Msg("%(field)s: %(message)s", field=field, message=message)
    return message
