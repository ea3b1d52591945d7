"""The plugin's real blueprint in a Flask test app, on a mocked plugin (tests/support/
mocked_plugin.py) whose file manager is OctoPrint's own local storage in a temporary
uploads folder, and whose jobs run in the calling process (InProcessWorker). Permission
checks pass; ``valid_file_type`` knows .gcode. For the endpoint tests of issue 17."""

import os
from types import SimpleNamespace
from unittest import mock

from tests.support.mocked_plugin import api_app, mocked_plugin

PREFIX = "/plugin/kincomp"
PROFILE = {
    "volume": {"width": 220, "depth": 220, "height": 200, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 200}},
}


def blueprint_client(basedir: str, stored=None, profile=None, connected=True):
    """(namespace with plugin, client, uploads, storage, patches); stop the patches with
    ``ns.stop()``. ``stored``: KinComp's settings as written in config.yaml before start;
    ``profile``: OctoPrint's current printer profile (default: PROFILE, without an id);
    ``connected`` False: no printer connected at the start."""
    from octoprint.filemanager.storage import LocalFileStorage

    patches = [
        mock.patch("octoprint_kincomp.plugin.http.require"),
        mock.patch(
            "octoprint_kincomp.plugin.files.files_api.valid_file_type",
            side_effect=lambda p, type=None: str(p).endswith(".gcode"),
        ),
    ]
    for p in patches:
        p.start()
    plugin = mocked_plugin(basedir, stored=stored, profile=profile, connected=connected)
    if profile is None:
        plugin._printer_profile_manager.get_current_or_default.return_value = PROFILE
    try:
        from octoprint_kincomp.service.files.worker import InProcessWorker

        plugin.jobs.worker = InProcessWorker()
    except ImportError:  # (before issue 17 there was no worker: work ran in the request)
        pass
    uploads = os.path.join(basedir, "uploads")
    os.makedirs(uploads, exist_ok=True)
    storage = LocalFileStorage(uploads)
    fm = plugin._file_manager
    fm.file_exists.side_effect = lambda dest, p: storage.file_exists(p)
    fm.path_on_disk.side_effect = lambda dest, p: storage.path_on_disk(p)
    app = api_app()
    app.register_blueprint(plugin.get_blueprint(), url_prefix=PREFIX)

    def stop():
        for p in patches:
            p.stop()

    return SimpleNamespace(
        plugin=plugin,
        client=app.test_client(),
        app=app,
        uploads=uploads,
        storage=storage,
        stop=stop,
    )
