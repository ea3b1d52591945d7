"""Issue 37, row 10: KinComp's upload routes on its own Tornado handler
(``plugin/files/upload_handler.py``), run in Tornado's test server with a small WSGI app
behind it that says what Flask would get: a full disk while the file is written is a
request without the file and with the disk-full header (the route then answers 507: the
blueprint part below), never a dropped connection, and no temporary file is left; the
temporary files are named ``kincomp-upload-<pid>-*.tmp``, and those of a server that no
longer runs are removed at start-up, nobody else's."""

import asyncio
import errno
import json
import os
import subprocess
import sys
import tempfile
from unittest import mock

import pytest
import tornado.testing
import tornado.web
from octoprint.server.util.tornado import WsgiInputContainer
from werkzeug.wrappers import Request, Response

from octoprint_kincomp.core import atomic
from octoprint_kincomp.plugin import http
from octoprint_kincomp.plugin.files.upload_handler import UPLOAD_ROUTES, KinCompUploadHandler
from tests.support.blueprint import PREFIX, blueprint_client

DATA = b"t,x\n" + b"0.001,0.5\n" * 20000  # 200 kB


def _wsgi(environ, start_response):
    """What the route would see: the form fields, whether the file is there, the header."""
    req = Request(environ)
    path = req.form.get("file.path")
    body = {
        "form": sorted(req.form.keys()),
        "file_there": bool(path) and os.path.exists(path),
        "file_size": os.path.getsize(path) if path and os.path.exists(path) else None,
        "file_name": req.form.get("file.name"),
        "failed": req.headers.get(http.UPLOAD_FAILED),
        "field": req.form.get("force"),
    }
    return Response(json.dumps(body), mimetype="application/json")(environ, start_response)


def _multipart(data, name="t.csv", fields=None):
    boundary = "kctest0123456789"
    parts = [
        f'--{boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n{v}\r\n'.encode()
        for k, v in (fields or {}).items()
    ]
    parts.append(
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
        "Content-Type: text/csv\r\n\r\n".encode()
        + data
        + b"\r\n"
    )
    parts.append(f"--{boundary}--\r\n".encode())
    return b"".join(parts), f"multipart/form-data; boundary={boundary}"


class _Full:
    """A temporary file on a disk that fills after ``room`` bytes."""

    def __init__(self, real, room):
        self._real, self._room = real, room

    def write(self, data):
        if len(data) > self._room:
            self._real.write(data[: self._room])
            self._room = 0
            raise OSError(errno.ENOSPC, "No space left on device")
        self._room -= len(data)
        return self._real.write(data)

    def __getattr__(self, name):
        return getattr(self._real, name)


class UploadHandlerTest(tornado.testing.AsyncHTTPTestCase):
    """Tornado runs its own event loop on this thread. Playwright's synchronous API (the
    session's browser, when a browser test ran before in this process) leaves its loop set
    as the thread's running one between calls, and asyncio refuses to start a second: the
    test steps that loop aside while it runs and puts it back after."""

    def setUp(self):
        self._outer_loop = asyncio._get_running_loop()
        asyncio._set_running_loop(None)
        super().setUp()

    def tearDown(self):
        try:
            super().tearDown()
        finally:
            asyncio._set_running_loop(self._outer_loop)

    def get_app(self):
        self.tmp = tempfile.mkdtemp()
        kwargs = {
            "fallback": WsgiInputContainer(_wsgi),
            "file_prefix": f"{atomic.UPLOAD_PREFIX}{os.getpid()}-",
            "file_suffix": atomic.UPLOAD_SUFFIX,
            "path": self.tmp,
            "suffixes": {"name": "name", "path": "path"},
        }
        return tornado.web.Application(
            [(PREFIX + rule, KinCompUploadHandler, kwargs) for rule in UPLOAD_ROUTES]
        )

    def post(self, url, data, headers=None, fields=None):
        body, ctype = _multipart(data, fields=fields)
        resp = self.fetch(
            url,
            method="POST",
            body=body,
            headers=dict({"Content-Type": ctype}, **(headers or {})),
            raise_error=False,
        )
        return resp.code, json.loads(resp.body) if resp.body else None

    def left(self):
        return os.listdir(self.tmp)

    def test_an_upload_reaches_the_route_as_a_file_of_kincomps_name(self):
        seen = []
        real = tempfile.NamedTemporaryFile

        def spy(*args, **kwargs):
            f = real(*args, **kwargs)
            seen.append(os.path.basename(f.name))
            return f

        with mock.patch("tempfile.NamedTemporaryFile", spy):
            code, body = self.post(PREFIX + "/trace", DATA, fields={"force": "true"})
        assert code == 200, body
        assert body["file_there"] and body["file_size"] == len(DATA)
        assert body["file_name"] == "t.csv" and body["field"] == "true"
        assert body["failed"] is None
        (name,) = seen
        assert name.startswith(f"kincomp-upload-{os.getpid()}-") and name.endswith(".tmp")
        assert atomic._UPLOAD.match(name)
        assert self.left() == []  # removed after the request

    def test_a_full_disk_is_the_request_without_its_file_and_leaves_nothing(self):
        real = tempfile.NamedTemporaryFile
        for room in (0, 10, 70_000):  # at the first chunk, in it, at a later one
            with mock.patch(
                "tempfile.NamedTemporaryFile", lambda *a, **k: _Full(real(*a, **k), room)
            ):
                code, body = self.post(
                    PREFIX + "/campaigns/c1/steps/2/trace", DATA, fields={"force": "true"}
                )
            assert code == 200, body  # (answered by the route: 507, see below)
            assert body["failed"] == str(errno.ENOSPC) and body["file_there"] is False
            assert "file.path" not in body["form"] and body["field"] == "true"
            assert self.left() == []

    def test_no_room_even_for_the_temporary_file(self):
        def full(*a, **k):
            raise OSError(errno.ENOSPC, "No space left on device")

        with mock.patch("tempfile.NamedTemporaryFile", full):
            code, body = self.post(PREFIX + "/trace", DATA)
        assert (
            code == 200 and body["failed"] == str(errno.ENOSPC) and "file.path" not in body["form"]
        )
        assert self.left() == []

    def test_a_client_cannot_say_the_disk_was_full(self):
        code, body = self.post(
            PREFIX + "/trace", DATA, headers={http.UPLOAD_FAILED: str(errno.ENOSPC)}
        )
        assert code == 200 and body["failed"] is None and body["file_there"] is True

    def test_another_write_error_is_said_too(self):
        real = tempfile.NamedTemporaryFile

        class Broken(_Full):
            def write(self, data):
                raise OSError(errno.EIO, "I/O error")

        with mock.patch("tempfile.NamedTemporaryFile", lambda *a, **k: Broken(real(*a, **k), 0)):
            code, body = self.post(PREFIX + "/trace", DATA)
        assert code == 200 and body["failed"] == str(errno.EIO) and self.left() == []


@pytest.fixture
def api(tmp_path):
    ns = blueprint_client(str(tmp_path))
    yield ns
    ns.stop()


def test_the_routes_answer_507_when_the_handler_found_the_disk_full(api):
    plan = api.client.post(
        PREFIX + "/campaign/plan",
        data=json.dumps({"radius_xy": 50}),
        content_type="application/json",
    ).get_json()
    body, ctype = _multipart(b"")
    runs = api.client.get(PREFIX + "/runs").get_json()["runs"]
    for path in ("/trace", f"/campaigns/{plan['id']}/steps/1/trace"):
        resp = api.client.post(
            PREFIX + path,
            data=body,
            content_type=ctype,
            headers={http.UPLOAD_FAILED: str(errno.ENOSPC)},
        )
        assert resp.status_code == 507, resp.get_json()
        assert "The disk is full" in resp.get_json()["error"]
    resp = api.client.post(
        PREFIX + "/trace", data=body, content_type=ctype, headers={http.UPLOAD_FAILED: "5"}
    )
    assert resp.status_code == 500  # another write error: a fault, not a full disk
    assert api.client.get(PREFIX + "/runs").get_json()["runs"] == runs
    camp = api.client.get(PREFIX + f"/campaigns/{plan['id']}").get_json()
    assert camp["steps"][0]["run"] is None and camp["measured"] == 0


def test_start_up_removes_the_upload_files_of_servers_that_no_longer_run(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True
    )
    dead_pid = int(dead.stdout)
    names = {
        f"kincomp-upload-{dead_pid}-ab_cd12x.tmp": False,  # a killed server's: removed
        f"kincomp-upload-{os.getpid()}-zz9_k2mq.tmp": True,  # this server's own, in flight
        f"kincomp-upload-{os.getppid()}-qq1_aa2b.tmp": True,  # another running server's
        "octoprint-file-upload-abcd1234.tmp": True,  # OctoPrint's own routes' (not ours)
        f"kincomp-upload-{dead_pid}-ab.gcode": True,  # not our pattern
    }
    for name in names:
        (tmp_path / name).write_bytes(b"x")
    removed = atomic.clean_stale_uploads(str(tmp_path))
    assert [os.path.basename(p) for p in removed] == [f"kincomp-upload-{dead_pid}-ab_cd12x.tmp"]
    assert sorted(os.listdir(tmp_path)) == sorted(n for n, kept in names.items() if kept)


def test_the_plugin_cleans_the_temporary_folder_at_start_up(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    os.makedirs(tmp_path / "tmp")
    stale = tmp_path / "tmp" / "kincomp-upload-999999999-ab_cd12x.tmp"
    stale.write_bytes(b"x")
    ns = blueprint_client(str(tmp_path / "op"))
    try:
        assert not stale.exists()
    finally:
        ns.stop()


def test_octoprints_own_abandoned_upload_files_are_removed_and_nothing_in_use(tmp_path):
    """Issue 37 row 10: OctoPrint's own upload routes leave ``octoprint-file-upload-*.tmp``
    behind when the server is killed during an upload, and OctoPrint never removes them.
    Their name says nothing of whose they are: one is removed only when last written over an
    hour ago and open in no process (a slow upload still being written, or one that another
    server holds open, stays)."""
    hour = atomic.ABANDONED_UPLOAD_S
    now = 1_000_000_000.0

    def make(name, age_s):
        path = tmp_path / name
        path.write_bytes(b"x" * 10)
        os.utime(path, (now - age_s, now - age_s))
        return path

    abandoned = make("octoprint-file-upload-aaaa1111.tmp", hour + 60)
    recent = make("octoprint-file-upload-bbbb2222.tmp", hour - 60)  # an upload in flight
    held = make("octoprint-file-upload-cccc3333.tmp", hour + 60)
    other = make("octoprint-file-upload-dddd4444.gcode", hour + 60)  # not the pattern
    (tmp_path / "octoprint-file-upload-eeee5555.tmp").symlink_to(other)
    os.utime(tmp_path / "octoprint-file-upload-eeee5555.tmp", (0, 0), follow_symlinks=False)
    with open(held, "rb"):  # some process has it open
        removed = atomic.clean_abandoned_octoprint_uploads(str(tmp_path), now=now)
    assert removed == [str(abandoned)]
    assert recent.exists() and held.exists() and other.exists()
    assert (tmp_path / "octoprint-file-upload-eeee5555.tmp").is_symlink()
    # where the open files cannot be known, nothing is removed
    make("octoprint-file-upload-ffff6666.tmp", hour + 60)
    with mock.patch.object(atomic, "open_files", return_value=None):
        assert atomic.clean_abandoned_octoprint_uploads(str(tmp_path), now=now) == []


def test_the_plugin_sweeps_octoprints_abandoned_upload_files_at_start_up(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    os.makedirs(tmp_path / "tmp")
    left = tmp_path / "tmp" / "octoprint-file-upload-abcd1234.tmp"
    left.write_bytes(b"x")
    old = os.stat(left).st_mtime - 2 * atomic.ABANDONED_UPLOAD_S
    os.utime(left, (old, old))
    ns = blueprint_client(str(tmp_path / "op"))
    try:
        assert not left.exists()
    finally:
        ns.stop()
