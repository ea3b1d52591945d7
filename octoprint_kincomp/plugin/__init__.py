"""The OctoPrint side: the plugin class (``kincomp_plugin``, start reading there) and its
pieces (settings store, print state, firmware check, demo mode, the endpoints, background
jobs and their worker process, notifications). Only this floor imports OctoPrint; the
plugin class is imported on first use, so that the worker process (``worker``, which
imports no OctoPrint) can start from this package without loading OctoPrint."""

__all__ = ["KinCompPlugin", "plugin_hooks"]


def __getattr__(name):
    if name in __all__:
        from . import kincomp_plugin

        return getattr(kincomp_plugin, name)
    raise AttributeError(name)
