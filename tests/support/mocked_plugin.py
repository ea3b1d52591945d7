"""KinCompPlugin on a real OctoPrint settings object, with mocks for the printer, event bus,
plugin and file managers (the plugin-layer tests and benchmarks/plugin_hook.py); a Flask
app to call its views in; waiting for what the plugin's worker threads do."""

import os
import time
from unittest import mock

from octoprint_kincomp.service.settings.schema import defaults


def mocked_plugin(basedir: str, bed_mm: float = 200.0, stored=None, profile=None, connected=True):
    """A started plugin (initialize + on_after_startup) keeping its files under ``basedir``;
    the printer prints, the profile's bed is ``bed_mm`` square and high. ``stored``:
    KinComp's settings in config.yaml before the start (as a user may have edited them).
    ``profile``: OctoPrint's current printer profile (a dict with its ``id``) from the
    start on, instead of a default one without an id; ``connected`` False: no printer is
    connected at the start (OctoPrint has no current profile then)."""
    import yaml
    from octoprint.plugin import PluginSettings
    from octoprint.settings import Settings

    if stored is not None:
        os.makedirs(os.path.join(basedir, "base"), exist_ok=True)
        with open(os.path.join(basedir, "base", "config.yaml"), "w") as f:
            yaml.safe_dump({"plugins": {"kincomp": stored}}, f)
    from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin

    p = KinCompPlugin()
    p._identifier = "kincomp"
    p._plugin_name = "KinComp"
    p._plugin_version = "test"
    p._basefolder = basedir
    p._logger = mock.MagicMock()
    p._settings = PluginSettings(
        Settings(basedir=os.path.join(basedir, "base")), "kincomp", defaults=defaults()
    )
    p._plugin_manager = mock.MagicMock()
    p._event_bus = mock.MagicMock()
    p._printer = mock.MagicMock()
    p._printer.is_printing.return_value = True
    p._printer.is_pausing.return_value = False
    p._printer.is_paused.return_value = False
    p._file_manager = mock.MagicMock()
    # a path, not a MagicMock: open(MagicMock()) opens (and closes) file descriptor 1 (its
    # __index__), which a later pseudo-terminal may then get and lose
    p._file_manager.path_on_disk.return_value = os.path.join(basedir, "no-such-file.gcode")
    p._printer_profile_manager = mock.MagicMock()
    p._printer_profile_manager.get_current_or_default.return_value = {
        "volume": {"width": bed_mm, "depth": bed_mm, "height": bed_mm, "origin": "lowerleft"}
    }
    if profile is not None:
        p._printer_profile_manager.get_current.return_value = profile
        p._printer_profile_manager.get_current_or_default.return_value = profile
    if not connected:
        p._printer_profile_manager.get_current.return_value = None
    data = os.path.join(basedir, "data")
    os.makedirs(data, exist_ok=True)
    p._data_folder = data
    p.get_plugin_data_folder = lambda: data
    p.initialize()
    p.on_after_startup()
    return p


def api_app():
    """A Flask app to call the plugin's views in (flask_babel set up: English messages)."""
    import flask
    import flask_babel

    app = flask.Flask("t")
    flask_babel.Babel(app)
    return app


def wait_for(condition, timeout: float = 5.0) -> None:
    """Waits until ``condition()`` is true (a worker thread's doing); fails after
    ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def queue_lines(plugin, lines, comm=None) -> None:
    """``lines`` of a printed file through KinComp's queuing hook (comments stripped as
    OctoPrint does)."""
    for line in lines:
        cmd = line.split(";")[0].strip()
        if cmd:
            plugin.queuing_hook(comm, "queuing", cmd, None, cmd.split()[0], tags={"source:file"})
