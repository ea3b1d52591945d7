"""What KinComp tells the user and other plugins (no OctoPrint import here).

* UI notifications: sent as the English message id plus its parameters, translated in the
  browser (they can start on any thread, where there is no request and so no user language).
  ``N_`` marks such a message id for the catalog extraction.
* Plugin messages to KinComp's own view models (background job progress, demo trace ready).
* KinComp's custom events, fired on OctoPrint's event bus as ``plugin_kincomp_<name>``.
"""

from __future__ import annotations

from typing import Any, Dict, Sequence

from ..core.messages import Msg, as_dict

# registered through the octoprint.events.register_custom_events hook
CUSTOM_EVENTS = ("params_applied", "calibration_analysed")


def N_(message: str) -> str:
    """Marks a message for translation; the browser translates it (see Notifier.notify)."""
    return message


class Notifier:
    """Sends notifications, plugin messages and events for the plugin ``identifier``."""

    def __init__(self, plugin_manager, event_bus, identifier: str):
        self._plugin_manager = plugin_manager
        self._event_bus = event_bus
        self._identifier = identifier

    def notify(self, severity: str, msgid: str, tr_params: Sequence[str] = (), **params) -> None:
        """Tell the UI. ``severity`` decides how (the tab's view model, kincomp_tab.js):
        ``status`` is a line in the Calibration tab (for the record, nothing to act on);
        ``info``, ``success``, ``warning`` and ``error`` are pop-ups, for what the user
        should know or do wherever they are (errors stay until closed). The parameters named
        in ``tr_params`` (message ids themselves) and the core messages among the
        parameters (as template + parameters) are translated by the browser too."""
        self.message(
            {
                "type": "notify",
                "severity": severity,
                "msgid": msgid,
                "params": {k: as_dict(v) if isinstance(v, Msg) else v for k, v in params.items()},
                "translate": list(tr_params),
                "text": msgid % params if params else msgid,
            }
        )

    def message(self, data: Dict[str, Any]) -> None:
        """A plugin message to KinComp's view models."""
        self._plugin_manager.send_plugin_message(self._identifier, data)

    def event(self, name: str, payload: Dict[str, Any]) -> None:
        """Fires the custom event ``name`` (one of CUSTOM_EVENTS)."""
        self._event_bus.fire(f"plugin_{self._identifier}_{name}", payload)
