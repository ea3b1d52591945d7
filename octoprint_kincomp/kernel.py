"""The compiled fast path of the compensator (``_kernel.c``), where it could be built.

``Kernel.line(comp, line)`` is ``Compensator._fast_line`` compiled: the same lines, the same
arithmetic in the same order, Python's own number parser and formatter, so the same text
and the same state; where it does not decide (a limit touched, anything unusual) it returns
None having changed nothing, and the general path takes the line. ``Kernel.feed(comp, buf,
pos)`` runs it over the complete lines of a block of a file, with blank lines and ``;``
comments, up to the first line it does not take. Both read the compensator's state at the
start of a call and write it back at the end.

The extension is optional: the package installs and works without it (no compiler, e.g.),
on the pure-Python paths, only slower. ``KINCOMP_KERNEL=0`` in the environment turns it
off. The tests run every equivalence check with and without it.
"""

import contextlib
import os
from typing import Iterator, Optional

try:  # built by setup.py when a C compiler is there
    from . import _kernel
except ImportError:  # pragma: no cover - depends on the installation
    _kernel = None


def available() -> bool:
    return _kernel is not None and os.environ.get("KINCOMP_KERNEL", "1") != "0"


def for_compensator(comp) -> Optional[object]:
    """A kernel for ``comp``'s model and options, or None (not built, turned off, or a
    model outside the fast path: the Python paths then do everything)."""
    if not available() or not comp.fast_lines:
        return None
    bl = comp.backlash
    tables = tuple(tuple(bl.tables[k].points) if bl.active[k] else None for k in range(3))
    if any(t is not None and len(t) > 64 for t in tables):
        return None
    return _kernel.Kernel(comp._affine, tables, comp._half, bl.deadband,
                          comp.options.limits, comp.options.decimals)


@contextlib.contextmanager
def switched(on: bool) -> Iterator[None]:
    """Compensators made inside use the kernel (if built) or, ``on=False``, the pure-Python
    paths (what an installation without a C compiler runs): benchmarks and tests."""
    old = os.environ.get("KINCOMP_KERNEL")
    os.environ["KINCOMP_KERNEL"] = "1" if on else "0"
    try:
        yield
    finally:
        if old is None:
            del os.environ["KINCOMP_KERNEL"]
        else:
            os.environ["KINCOMP_KERNEL"] = old
