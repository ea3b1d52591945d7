"""The one exception of the sensor floor.

:class:`SensorError` carries a translatable :class:`~..core.messages.Msg` and, for a bad
setting, the name of the setting at fault (``field``), like ``core.params.ParamsError``.
"""

from __future__ import annotations


class SensorError(ValueError):
    """A sensor setting, port or stream cannot be used; ``field`` names the setting at fault."""

    def __init__(self, message: str, field: str = ""):
        self.field = field
        self.message = message  # a messages.Msg: translatable by the plugin
        super().__init__(f"{field}: {message}" if field else message)
