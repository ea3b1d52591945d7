"""The OctoPrint boundary: the plugin class (``kincomp_plugin``, start reading there), the
request helpers (``http``) and, one room per page of the manual, what needs OctoPrint or
Flask (``printing``, ``files``, ``calibration``, ``capture``, ``settings``); what does not is
in ``service/``. The plugin class is imported on first use, so that importing this package
loads no OctoPrint."""

__all__ = ["KinCompPlugin", "plugin_hooks"]


def __getattr__(name):
    if name in __all__:
        from . import kincomp_plugin

        return getattr(kincomp_plugin, name)
    raise AttributeError(name)
