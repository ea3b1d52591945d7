"""Which engine runs, decided once, here: the compiled kernel where it was built and passed
its self-check (``engines/kernel.py``), otherwise the reference path (the reference
compensator, line by line, for the hook and for whole files). ``KINCOMP_KERNEL=0`` in the
environment turns the kernel off; which lines go to it: ``engines/contract.py``. Everything
that compensates (the queuing hook, uploads, background jobs, the command line, the closed
loop, the benchmark) gets its compensator from :func:`make_compensator`; tests and the
benchmark run each engine with :func:`use`.
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Iterator, Optional

from ..core.compensator import Compensator, Options
from ..core.params import Params
from . import kernel
from .contract import attach

ENGINES = ("compiled", "python")
_log = logging.getLogger(__name__)


def _decide() -> str:
    if not kernel.built() or os.environ.get("KINCOMP_KERNEL", "1") == "0":
        return "python"
    if not kernel.self_check():
        _log.warning(
            "KinComp: the compiled kernel disagrees with the reference path on "
            "this platform; the pure-Python paths are used"
        )
        return "python"
    return "compiled"


_available = _decide()  # what this installation can run, decided at import
_engine = _available


def engine() -> str:
    """The engine in use: ``"compiled"`` or ``"python"``."""
    return _engine


def available() -> str:
    """The best engine this installation runs (``"compiled"`` if the kernel works)."""
    return _available


def make_compensator(params: Params, options: Optional[Options] = None) -> Compensator:
    """A compensator for ``params`` on the engine in use."""
    comp = Compensator(params, options)
    return attach(comp, kernel.build(comp) if _engine == "compiled" else None)


@contextlib.contextmanager
def use(name: str) -> Iterator[None]:
    """Compensators made inside run on engine ``name`` (tests and benchmarks). Asking for
    the compiled engine where it does not run is an error, not a silent fallback."""
    global _engine
    if name not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}")
    if name == "compiled" and _available != "compiled":
        raise RuntimeError("the compiled kernel is not available here")
    old = _engine
    _engine = name
    try:
        yield
    finally:
        _engine = old
