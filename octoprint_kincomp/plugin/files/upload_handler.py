"""KinComp's own Tornado handler for the routes that take a file upload (``/trace``,
``/campaigns/<id>/steps/<n>/trace``), registered through OctoPrint's
``octoprint.server.http.routes`` hook ahead of OctoPrint's catch-all.

It is OctoPrint's ``UploadStorageFallbackHandler`` (the multipart body streamed into a
temporary file, the request then handed to Flask with the file's path in its form), with two
differences:

* **A full disk** while the file is written (ENOSPC, EDQUOT) is not a connection reset:
  OctoPrint's handler lets the ``OSError`` out of Tornado's ``data_received``, which drops the
  connection (and leaves the temporary file behind). Here the file is removed, the rest of the
  body is read and thrown away, and the request goes on to Flask without the file and with the
  header :data:`FAILED` holding the error's number (one a client sends is removed first): the
  route checks the user's permissions as ever and answers 507 for a full disk, 500 for another
  write error (``calibration_api.read_upload``).
* **Its temporary files are KinComp's:** ``kincomp-upload-<pid>-<random>.tmp`` in the same
  temporary folder as OctoPrint's (``$TMPDIR``, else the system's), so that a server killed
  during an upload (SIGKILL, power loss: nothing removes them) has its leftovers removed at
  the next start (``core.atomic.clean_stale_uploads``); those of another server still
  running are not touched. OctoPrint's own routes' files (``octoprint-file-upload-*.tmp``,
  no pid in the name) are removed only once abandoned: over an hour old and open in no
  process (``files_api.sweep_octoprint_uploads``).

Requests are handed to Flask on a small thread pool of their own (:data:`THREADS`), not on
OctoPrint's request threads.
"""

from __future__ import annotations

import errno
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Dict, List, Optional, Tuple

import tornado.escape
from octoprint.server.util.tornado import UploadStorageFallbackHandler, WsgiInputContainer

from ...core.atomic import UPLOAD_PREFIX, UPLOAD_SUFFIX
from .. import http

FAILED = http.UPLOAD_FAILED  # the request header that says it (the errno)
THREADS = 2
# the routes (below /plugin/kincomp) whose bodies carry a file
UPLOAD_ROUTES = (r"/trace", r"/campaigns/[^/]+/steps/[0-9]+/trace")


class KinCompUploadHandler(UploadStorageFallbackHandler):
    def prepare(self):
        if FAILED in self.request.headers:  # only this handler says it
            del self.request.headers[FAILED]
        self._kincomp_failed: Optional[int] = None
        return super().prepare()

    def _drop(self, part: Dict[str, Any], exc: OSError) -> None:
        """The file could not be written (``exc``; the disk is full): ``part``'s temporary
        file is closed and removed, the rest of its data will be thrown away, and the
        request goes on without it, the error's number in the header :data:`FAILED`."""
        self._kincomp_failed = exc.errno or errno.EIO
        handle = part.pop("file", None)
        if handle is not None:
            try:
                handle.close()  # (flushing what is left fails again: the file goes anyway)
            except OSError:
                pass
        path = part.pop("path", None)
        if path is not None:
            try:
                os.unlink(path)
            except OSError:
                pass
        part["kincomp_dropped"] = True

    def _on_part_start(self, name, content_type, filename=None):
        try:
            return super()._on_part_start(name, content_type, filename=filename)
        except OSError as exc:  # (no room even for the new file)
            if filename is None:
                raise
            utf8 = tornado.escape.utf8
            part = {
                "name": utf8(name),
                "filename": utf8(filename),
                "content_type": utf8(content_type),
            }
            self._drop(part, exc)
            return part

    def _on_part_data(self, part, data):
        if part.get("kincomp_dropped"):
            return
        try:
            super()._on_part_data(part, data)
        except OSError as exc:
            if "file" not in part:
                raise
            self._drop(part, exc)

    def _on_part_finish(self, part):
        if "file" in part:
            try:
                part["file"].flush()
            except OSError as exc:
                self._drop(part, exc)
        super()._on_part_finish(part)

    async def _handle_method(self, *args, **kwargs):
        if self._kincomp_failed is not None:
            self.request.headers[FAILED] = str(self._kincomp_failed)
        return await super()._handle_method(*args, **kwargs)

    # (OctoPrint's handler binds every method to its own _handle_method)
    get = post = put = patch = delete = head = options = _handle_method


def routes(settings_get) -> List[Tuple[str, type, Dict[str, Any]]]:
    """What KinComp's ``octoprint.server.http.routes`` hook returns: its upload routes on
    :class:`KinCompUploadHandler`, handing requests to OctoPrint's Flask app (its response
    headers as OctoPrint's own catch-all sets them). ``settings_get``: OctoPrint's
    ``settings().get``."""
    from octoprint.server import app

    added = {"X-Robots-Tag": "noindex, nofollow, noimageindex", "X-Content-Type-Options": "nosniff"}
    if not settings_get(["server", "allowFraming"]):
        added["X-Frame-Options"] = "sameorigin"
    fallback = WsgiInputContainer(
        app.wsgi_app,
        executor=ThreadPoolExecutor(max_workers=THREADS, thread_name_prefix="KinCompUpload"),
        headers=added,
        removed_headers=["Server"],
    )
    kwargs = {
        "fallback": fallback,
        "file_prefix": f"{UPLOAD_PREFIX}{os.getpid()}-",
        "file_suffix": UPLOAD_SUFFIX,
        "suffixes": {
            "name": settings_get(["server", "uploads", "nameSuffix"]),
            "path": settings_get(["server", "uploads", "pathSuffix"]),
        },
    }
    return [(rule, KinCompUploadHandler, dict(kwargs)) for rule in UPLOAD_ROUTES]
