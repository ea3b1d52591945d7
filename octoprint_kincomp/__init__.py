"""KinComp: kinematic error compensation (squareness, scale, backlash) for OctoPrint.

The package's core modules import nothing from OctoPrint, so ``python -m octoprint_kincomp``
works without it. OctoPrint loads the plugin through :func:`__plugin_load__`, which is the
only place that imports the OctoPrint glue.
"""

from .core.version import HOMEPAGE, VERSION

__version__ = VERSION
__plugin_url__ = HOMEPAGE  # (written in core/version.py, which core and plugin/ import)

__plugin_author__ = "KinComp developers"
__plugin_license__ = "AGPL-3.0-or-later"  # as setup.py

__plugin_name__ = "KinComp"
__plugin_pythoncompat__ = ">=3.8,<4"
__plugin_description__ = (
    "Kinematic error compensation: squareness, per-axis scale and backlash, calibrated "
    "with a ballbar (ISO 230-4) circular test."
)


def __plugin_load__():
    from .plugin import KinCompPlugin, plugin_hooks

    global __plugin_implementation__, __plugin_hooks__
    __plugin_implementation__ = KinCompPlugin()
    __plugin_hooks__ = plugin_hooks(__plugin_implementation__)
