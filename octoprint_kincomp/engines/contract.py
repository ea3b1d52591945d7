"""The engine contract: what an accelerated engine takes, what it returns, how it hands a
line back to the reference path, and which lines are offered to it (decided here only).

An engine (today the one compiled kernel, ``engines/kernel.py``) serves one
:class:`~..core.compensator.Compensator` and its model:

* ``line(line) -> None | line | [str, ...]``: one line without its ending. The very same
  string: send it unchanged; a list: the replacement lines; None: declined, the reference
  path (``Compensator.process_declined``) takes it, and the stream state is as before.
* ``feed(buf, pos) -> (out, stop)``: the complete lines of a block of a file (bytes) from
  ``pos`` on, compensated into ``out`` (bytes, endings kept), up to the first line it does
  not take, which starts at ``stop`` (``len(buf)``: all taken); the caller runs that line
  through ``Compensator.process`` and feeds on after it (``engines/file_loop.py`` FileEngine).
* ``release()``: the stream state back into the compensator's :class:`StreamState`.

The engine owns the stream state while it takes lines, and hands it back (once, however
many lines follow that it declines) before it declines one, when ``feed`` stops, and when
``Compensator.state`` is read; it takes it again with the next line it may take. Its output
and report are the reference path's, byte for byte (the tests and its start-up self-check
compare them). One thread at a time uses a compensator and its engine, reading its state
included (that hands the state over): the queue holds its lock; a file job owns its own.
"""

from __future__ import annotations

from typing import Callable, Optional, Union

from ..core.compensator import Compensator

LineFn = Callable[[str], Union[None, str, list]]


def attach(comp: Compensator, engine) -> Compensator:
    """``comp`` compensates with ``engine`` first (None: the reference path alone)."""
    comp.fast = engine
    return comp


def line_route(comp: Compensator, bypass: bool = False) -> Optional[LineFn]:
    """The function a caller that offers lines itself (the queuing hook) calls first,
    handing a declined line to ``comp.process_declined``; None: call ``comp.process``.
    None where there is no engine, where ``bypass`` (the caller lets lines past the
    compensator or must see them itself: compensation off, a pre-compensated file passing
    through, a halted print, a home question open), and under the limits policy "error"
    (``process`` runs the engine inside its snapshot, so that a refused line changes
    nothing)."""
    if bypass or comp.fast is None or comp.guarded:
        return None
    return comp.fast.line


def block_route(comp: Compensator) -> Optional[Callable[[bytes, int], tuple]]:
    """The engine's ``feed`` for whole files, or None: every line through
    ``comp.process``."""
    return None if comp.fast is None else comp.fast.feed
