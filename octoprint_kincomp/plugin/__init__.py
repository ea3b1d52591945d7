"""The OctoPrint side: the plugin class and its pieces (hooks, settings, calibration API,
background jobs, firmware watch, demo). Only this floor imports OctoPrint."""

from .kincomp import KinCompPlugin, plugin_hooks

__all__ = ["KinCompPlugin", "plugin_hooks"]
