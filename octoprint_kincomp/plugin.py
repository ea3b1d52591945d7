"""OctoPrint glue for KinComp (minimal for now: the plugin loads; integration comes next)."""

import octoprint.plugin


class KinCompPlugin(octoprint.plugin.StartupPlugin):
    def on_after_startup(self):
        self._logger.info("KinComp loaded")
