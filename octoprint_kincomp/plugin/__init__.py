"""The OctoPrint side: the plugin class (``kincomp_plugin``, start reading there) and its
pieces (settings store, print state, firmware check, demo mode, the endpoints, background
jobs, notifications). Only this floor imports OctoPrint."""

from .kincomp_plugin import KinCompPlugin, plugin_hooks

__all__ = ["KinCompPlugin", "plugin_hooks"]
