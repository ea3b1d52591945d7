"""Writing a file so that readers see the old content or the new, never half of it: the
data goes to a hidden temporary file beside the target (``.kincomp-*``), which replaces
the target only when complete; on any error it is removed and the target is untouched."""

from __future__ import annotations

import contextlib
import os
import tempfile
from typing import BinaryIO, Iterator

TEMP_PREFIX = ".kincomp-"


@contextlib.contextmanager
def replacing(target: str, suffix: str = ".tmp") -> Iterator[BinaryIO]:
    """A binary file to write the new content of ``target`` into; on leaving the block it
    replaces ``target`` (keeping its permission bits), or, on an error, is removed."""
    directory = os.path.dirname(os.path.abspath(target)) or "."
    fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, suffix=suffix, dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
        if os.path.exists(target):
            try:
                os.chmod(tmp, os.stat(target).st_mode & 0o777)
            except OSError:
                pass
        os.replace(tmp, target)
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
