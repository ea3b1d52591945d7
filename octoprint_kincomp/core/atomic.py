"""Writing a file so that readers see the old content or the new, never half of it: the
data goes to a hidden temporary file beside the target, named
``.kincomp-<pid>-<random><suffix>`` (``pid``: the writing process), which replaces the
target only when complete; on any error, and on SIGTERM/SIGINT where the program turns
them into exceptions (:func:`signals_raise`), it is removed and the target is untouched.

A temporary file of a process that was killed outright (SIGKILL, power loss) stays behind:
:func:`clean_stale` removes those of processes that no longer run. A symbolic link as the
target is followed: the file it points to gets the new content and the link stays a link.
Errors name the target, never the temporary file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import signal
import stat
import tempfile
import time
from typing import BinaryIO, Iterator, List, Optional, Set

TEMP_PREFIX = ".kincomp-"
# ours: the writer's pid, then mkstemp's random letters (never a '-'), then the suffix
_OURS = re.compile(r"\.kincomp-(\d+)-[a-z0-9_]+(\.[A-Za-z0-9]+)?\Z")
# those of versions before the pid was in the name: only removed once clearly abandoned
_LEGACY = re.compile(r"\.kincomp-[a-z0-9_]{8}\.(gcode|tmp)\Z")
LEGACY_STALE_S = 3600.0
# the temporary files of uploads to KinComp's routes (``plugin/files/upload_handler.py``):
# the server's pid, then tempfile's random letters, in the temporary folder
UPLOAD_PREFIX = "kincomp-upload-"
UPLOAD_SUFFIX = ".tmp"
_UPLOAD = re.compile(r"kincomp-upload-(\d+)-[a-z0-9_]+\.tmp\Z")


def _named(exc: OSError, target: str) -> OSError:
    """``exc`` about ``target`` (the user's file) rather than the temporary file."""
    return type(exc)(exc.errno, exc.strerror or os.strerror(exc.errno or 0), target)


@contextlib.contextmanager
def replacing(target: str, suffix: str = ".tmp") -> Iterator[BinaryIO]:
    """A binary file to write the new content of ``target`` into; on leaving the block it
    replaces ``target`` (keeping its permission bits; through a symbolic link: the file the
    link points to), or, on an error, is removed."""
    target = os.path.realpath(target)
    directory = os.path.dirname(target) or "."
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f"{TEMP_PREFIX}{os.getpid()}-", suffix=suffix, dir=directory
        )
    except OSError as exc:
        raise _named(exc, target) from None
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
        if os.path.exists(target):
            try:
                os.chmod(tmp, os.stat(target).st_mode & 0o777)
            except OSError:
                pass
        try:
            os.replace(tmp, target)
        except OSError as exc:
            raise _named(exc, target) from None
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_atomic(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with replacing(path) as f:
        f.write(data)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    except OSError as exc:
        return exc.errno != errno.ESRCH
    return True


def clean_stale(directory: str) -> List[str]:
    """Remove the temporary files of this module in ``directory`` (not below it) whose
    writer no longer runs; those of older versions (no pid in the name) once untouched for
    an hour. Only this module's own name pattern is touched. Returns the removed paths."""
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    now = time.time()
    for name in names:
        if not name.startswith(TEMP_PREFIX):
            continue
        path = os.path.join(directory, name)
        m = _OURS.match(name)
        try:
            if m is not None:
                stale = int(m.group(1)) != os.getpid() and not _alive(int(m.group(1)))
            elif _LEGACY.match(name):
                stale = now - os.lstat(path).st_mtime > LEGACY_STALE_S
            else:
                continue
            if stale and os.path.isfile(path) and not os.path.islink(path):
                os.unlink(path)
                removed.append(path)
        except OSError:
            continue
    return removed


def clean_stale_uploads(directory: str) -> List[str]:
    """Remove the temporary files of uploads to KinComp's routes in ``directory`` (the
    temporary folder) whose server no longer runs (killed during an upload: nothing else
    removes them); another server's, and everything not named so, are left. Returns the
    removed paths."""
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    for name in names:
        m = _UPLOAD.match(name)
        if m is None:
            continue
        pid = int(m.group(1))
        path = os.path.join(directory, name)
        try:
            if pid != os.getpid() and not _alive(pid) and os.path.isfile(path):
                if not os.path.islink(path):
                    os.unlink(path)
                    removed.append(path)
        except OSError:
            continue
    return removed


# OctoPrint's own upload routes stream a body into ``octoprint-file-upload-<random>.tmp`` in
# the temporary folder and move it away when the request ends; a server killed during an
# upload leaves it, and OctoPrint never removes it. No pid in the name says whose it is, so
# such a file is only taken as abandoned when nobody can still be using it: last written
# over an hour ago, and open in no process.
_OCTOPRINT_UPLOAD = re.compile(r"octoprint-file-upload-[^/]*\.tmp\Z")
ABANDONED_UPLOAD_S = 3600.0


def open_files() -> Optional[Set[str]]:
    """The real paths of every file a process of this machine has open (Linux ``/proc``);
    None when that cannot be known (no ``/proc``, or a process whose files are not ours to
    read)."""
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return None
    found = set()
    for pid in pids:
        fds = os.path.join("/proc", pid, "fd")
        try:
            names = os.listdir(fds)
        except FileNotFoundError:
            continue  # (ended meanwhile)
        except OSError:
            return None
        for fd in names:
            try:
                found.add(os.readlink(os.path.join(fds, fd)))
            except OSError:
                continue
    return found


def clean_abandoned_octoprint_uploads(directory: str, now: Optional[float] = None) -> List[str]:
    """Remove OctoPrint's own upload temporary files in ``directory`` (the temporary folder)
    that were last written more than :data:`ABANDONED_UPLOAD_S` ago and that no process has
    open; nothing when the open files cannot be known. Returns the removed paths."""
    removed: List[str] = []
    try:
        names = [n for n in os.listdir(directory) if _OCTOPRINT_UPLOAD.match(n)]
    except OSError:
        return removed
    now = time.time() if now is None else now
    old = []
    for name in names:
        path = os.path.join(directory, name)
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if stat.S_ISREG(st.st_mode) and now - st.st_mtime > ABANDONED_UPLOAD_S:
            old.append(path)  # (a regular file: lstat does not follow a link)
    if not old:
        return removed
    in_use = open_files()
    if in_use is None:
        return removed
    for path in old:
        if os.path.realpath(path) in in_use:
            continue
        try:
            os.unlink(path)
            removed.append(path)
        except OSError:
            continue
    return removed


class Interrupted(BaseException):
    """SIGTERM or SIGHUP, raised where the program was (see :func:`signals_raise`)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def signals_raise() -> Iterator[None]:
    """Within the block SIGTERM and SIGHUP raise :class:`Interrupted` (SIGINT raises
    KeyboardInterrupt anyway), so that :func:`replacing` removes its temporary file; the
    previous handlers come back afterwards. Main thread only (a no-op elsewhere)."""

    def handler(signum, frame):
        raise Interrupted(signum)

    saved = {}
    try:
        for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if sig is not None:
                saved[sig] = signal.signal(sig, handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)
