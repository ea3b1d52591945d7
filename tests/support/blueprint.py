"""The plugin's real blueprint in a Flask test app, on a mocked plugin (tests/support/
mocked_plugin.py) whose file manager is OctoPrint's own local storage in a temporary
uploads folder, and whose jobs run in the calling process (InProcessWorker). Permission
checks pass; ``valid_file_type`` knows .gcode. For the endpoint tests of issue 17."""

import os
from types import SimpleNamespace
from unittest import mock

from tests.support import permissions
from tests.support.mocked_plugin import api_app, mocked_plugin

PREFIX = "/plugin/kincomp"
# the clients not stopped yet (``stop`` takes a client off): a test that leaves one on
# would let every later test in the process pass its permission checks
OPEN = []
# the patches, on while any client is open: started by the first, stopped after the last
# (patches of each client stopped out of order would leave a mock in place for good)
_PATCHES = []


def _patches_on():
    if not _PATCHES:
        permissions.grant()
        _PATCHES.append(
            mock.patch(
                "octoprint_kincomp.plugin.files.files_api.valid_file_type",
                side_effect=lambda p, type=None: str(p).endswith(".gcode"),
            )
        )
        _PATCHES[0].start()


def _patches_off():
    _PATCHES.pop().stop()
    permissions.release()


PROFILE = {
    "volume": {"width": 220, "depth": 220, "height": 200, "origin": "lowerleft"},
    "axes": {"x": {"speed": 6000}, "y": {"speed": 6000}, "z": {"speed": 200}},
}


def blueprint_client(basedir: str, stored=None, profile=None, connected=True):
    """(namespace with plugin, client, uploads, storage, patches); stop the patches with
    ``ns.stop()``. ``stored``: KinComp's settings as written in config.yaml before start;
    ``profile``: OctoPrint's current printer profile (default: PROFILE, without an id);
    ``connected`` False: no printer connected at the start."""
    ns = SimpleNamespace()

    def stop():
        mine = [i for i, o in enumerate(OPEN) if o is ns]  # (by identity)
        if mine:
            del OPEN[mine[0]]
            if not OPEN:
                _patches_off()

    _patches_on()
    OPEN.append(ns)
    try:
        _build(ns, basedir, stored, profile, connected)
    except BaseException:
        stop()
        raise
    ns.stop = stop
    return ns


def _build(ns, basedir, stored, profile, connected):
    from octoprint.filemanager.storage import LocalFileStorage

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
    ns.plugin, ns.client, ns.app = plugin, app.test_client(), app
    ns.uploads, ns.storage = uploads, storage
