"""The compiled kernel of the transform (``csrc/``), where it could be built.

``Kernel.line(line)`` compensates one plain absolute ``G0``/``G1`` line, or a ``G2``/``G3``
kept as arcs, of an affine model exactly as the reference path (``core/path.py``,
``core/arcpath.py``) would: the same arithmetic in the same order, Python's own number
rules, so the same text; where it does not decide (a limit touched, anything unusual) it
returns None having changed nothing, and the reference path takes the line.
``Kernel.feed(buf, pos)`` runs it over the complete lines of a block of a file, with blank
lines and ``;`` comments, up to the first line it does not take (``contract.py``).

It owns the stream state while it takes lines: a typed C record (``csrc/kernel.h`` ``State``)
in the Kernel object, which crosses to Python only as a tuple of plain values (:data:`RECORD`;
:func:`record` to take it, :func:`adopt` to hand it back, ``release()`` when
``Compensator.state`` is read). C never touches a Python object's internals, so it holds on
any CPython 3.8+, the free-threaded build included. Threads: one at a time uses a Kernel
(the queuing hook holds its lock around every call; a file job owns its compensator); the
module keeps no global state and does not declare ``Py_mod_gil``, so a free-threaded CPython
turns the GIL on when it loads it (a warning): nothing here runs in parallel anyway.

The extension is optional: the package installs and works without it (no compiler, e.g.),
only slower. Before it is used it must write, on a fixed program full of rounding traps,
exactly what the reference path writes (:func:`self_check`): a platform where it would not
(a compiler that fuses multiply-adds, say) runs without it. ``engines.select`` decides once
whether it runs.
"""

from __future__ import annotations

import logging
import math
import random
from operator import attrgetter
from typing import Callable, List, Optional

from ..core import gcode_table as gt
from ..core.compensator import Compensator, Options
from ..core.params import Params
from ..core.state import StreamState

_log = logging.getLogger(__name__)

try:  # built by setup.py when a C compiler is there
    from . import _kernel as _ext
except ImportError:  # pragma: no cover - depends on the installation
    _ext = None

MAX_POINTS = _ext.MAX_POINTS if _ext is not None else 64  # backlash table points it takes

# The record's fields, in the order of its tuple: StreamState's own (core/state.py
# StreamState.FIELDS), its backlash state's, and the report's counters that the kernel keeps
# (a nested tuple). The extension declares the same names (``_ext.RECORD``): a kernel built
# with another record is not used (:func:`self_check`).
MODES = ("absolute", "inches", "e_absolute_mode", "plane", "ij_absolute")
COUNTS = ("lines", "moves", "moves_compensated", "lines_out", "takeup_moves", "arcs_kept")
COUNTS += ("arcs_split", "arcs_linearised", "arc_segments")
HEAD = MODES + ("m", "fw", "fw_text", "w", "g", "q_last", "limit_recheck", "backlash.dir")
HEAD += ("backlash.anchor", "lineno", "e_pos", "feed")
TAIL = ("report.arc_max_deviation_um", "report.max_correction_um")
RECORD = HEAD + (tuple("report." + a for a in COUNTS),) + TAIL
_head, _counts, _tail = attrgetter(*HEAD), attrgetter(*COUNTS), attrgetter(*TAIL)


def record_names(fields=RECORD) -> str:
    """``fields`` as the extension writes its RECORD: names by blanks, a group in
    parentheses."""
    return " ".join(f if isinstance(f, str) else "(" + record_names(f) + ")" for f in fields)


def record(st: StreamState) -> Optional[tuple]:
    """``st`` as the kernel's record (:data:`RECORD`), or None where the kernel does not
    hold such a state (drives away from the desired position's command: ``q_drive``)."""
    if st.q_drive is not None:
        return None
    return _head(st) + (_counts(st.report),) + _tail(st)


def adopt(st: StreamState, rec: tuple) -> None:
    """Write the kernel's record ``rec`` into ``st``: the fields the kernel changes (never the
    modes nor the G92 offsets); lists the reference path changes in place, in place."""
    m, st.fw[:], st.fw_text[:], _, _, st.q_last, recheck, st.backlash.dir[:] = rec[5:13]
    st.m, st.limit_recheck = list(m), list(recheck)
    st.backlash.anchor[:], st.lineno, st.e_pos, st.feed, counts, dev, maxc = rec[13:]
    rep = st.report
    for a, v in zip(COUNTS, counts):
        setattr(rep, a, v)
    rep.arc_max_deviation_um = dev
    rep.max_correction_um[:] = maxc


def built() -> bool:
    """The extension module was built and imports."""
    return _ext is not None


def build(comp: Compensator) -> Optional[object]:
    """A kernel for ``comp``'s model and options, or None (not built, or a model outside
    what the kernel does: the reference path then does everything)."""
    if _ext is None or not comp.accelerable:
        return None
    bl = comp.backlash
    tables = tuple(tuple(bl.tables[k].points) if bl.active[k] else None for k in range(3))
    if any(t is not None and len(t) > MAX_POINTS for t in tables):
        return None
    model = comp.model
    affine = tuple(v for row in model.inverse_rows for v in row) + tuple(model.offset_mm)
    aw = comp.arc_writer
    arcs = None
    if not comp.options.linearise_arcs:
        arcs = (
            comp.pure_translation,
            comp.options.chord_tol_mm,
            aw.k_dev,
            aw.budget,
            aw.sliver,
            aw.overshoot,
            aw.max_offset,
            tuple(float(v) for v in aw.breaks[17]),
        )
    st = comp._state  # (the object itself: not through ``state``, which asks the kernel)
    return _ext.Kernel(
        affine,
        tables,
        bl.half,
        bl.deadband,
        comp.options.limits,
        comp.options.decimals,
        arcs,
        get=lambda: record(st),
        put=lambda rec: adopt(st, rec),
    )


def _check_program() -> List[str]:
    """Moves whose numbers are rounding traps: exact ties at the output resolution, values
    that round differently with excess precision or fused multiply-adds, long and signed
    numbers, negative zero; with reversals (backlash take-ups), limits, F first, E tails,
    and an inch section."""
    rnd = random.Random(20261124)
    lines = ["G28", "G1 X10 Y10 Z0.3 F3000"]
    traps = "0.0625 0.1875 1.0005 0.002877 -0 +0.0 12.3456789012345678 123.4565 0.0635"
    traps = traps.split() + ["199.9995", "7.", ".5"]
    for i in range(240):
        if i % 3 == 0:
            x, y = rnd.choice(traps), rnd.choice(traps)
        else:
            x = "%.*f" % (rnd.randint(0, 6), rnd.uniform(-2, 205))
            y = "%.*f" % (rnd.randint(0, 6), rnd.uniform(-2, 205))
        tail = rnd.choice(["", " E%.5f" % rnd.uniform(0, 50), " E-0.8 F2400", " F1800"])
        lines.append(rnd.choice(["G1 X%s Y%s%s", "G0 X%s Y%s%s"]) % (x, y, tail))
        if i % 37 == 0:
            lines.append(
                "G1 F%d X%s Y%s Z%.2f" % (rnd.randint(600, 9000), y, x, rnd.uniform(0.2, 5))
            )
        if i % 11 == 0:  # an arc from here (kept as arcs: libm's trigonometry, the fit)
            r, a, b = rnd.uniform(1, 30), rnd.uniform(0, 6.28), rnd.uniform(-3, 3)
            lines.append("G1 X100 Y100")
            lines.append(
                "%s X%.3f Y%.3f I%.3f J%.3f E%.5f"
                % (
                    "G2" if b < 0 else "G3",
                    100 + r * math.cos(a) - r * math.cos(a + b),
                    100 + r * math.sin(a) - r * math.sin(a + b),
                    r * math.cos(a),
                    r * math.sin(a),
                    rnd.uniform(0, 50),
                )
            )
        if i == 200:
            lines += [
                "G20",
                "G1 X1.23456 Y2.34567",
                "G1 X0.5 Y3.25",
                "G3 X1.5 Y3.25 I0.5 J0 Z0.1",
                "G21",
                "M83",
                "G2 X120 Y100 I10 J0 E0.5",
                "G1 X100 Y100 E0.1",
                "M82",
            ]
    return lines + ["G21", "G1 X1 Y1", "G1 X-0.75 Y-0.25"]  # (ends below zero: the sign of fw)


def classifier(comp: Compensator) -> Callable[[str], Optional[str]]:
    """The kernel's own classification of a code (the question of ``gcode_table.
    check_engine``), asked by behaviour: from a known position, a line opening with the code
    and carrying X/Y (then X/Y/I/J) words is offered to ``comp``'s kernel; declined: None;
    taken and the desired position moved: ``linear`` (``arc`` for the line with I/J); taken
    and nothing moved nor re-framed: ``inert``; anything else: ``changes state``."""
    for line in ("G90", "G21", "M82", "G1 X50 Y50 Z5"):
        comp.process(line)
    kernel = comp.fast
    kernel.set_state(record(comp.state))
    start = kernel.get_state()  # (as the kernel writes it: tuples)

    m, w, g = (RECORD.index(name) for name in ("m", "w", "g"))

    def frame(rec: tuple) -> tuple:  # (the modes and the G92 offsets)
        return rec[: len(MODES)] + (rec[w], rec[g])

    def classify(code: str) -> Optional[str]:
        for words, moved in ((" X60 Y55", gt.LINEAR), (" X60 Y50 I5 J0", gt.ARC)):
            kernel.set_state(start)
            if kernel.line(code + words) is not None:
                after = kernel.get_state()
                if after[m] != start[m]:
                    return moved
                return gt.INERT if frame(after) == frame(start) else "changes state"
        return None

    return classify


def self_check(make: Optional[Callable] = None) -> bool:
    """True if a kernel (made by ``make``, default :func:`build`) writes on the check
    program exactly what the reference path writes (every line, the report and the state)
    and takes most of its lines itself (a kernel that declined them all would pass the
    comparison while the Python paths did the work)."""
    params = Params.from_dict(
        {
            "squareness_um_per_m": {"xy": -1234.5, "xz": 210.0, "yz": -80.0},
            "scale_ppm": {"x": 333.3, "y": -287.0, "z": 50.0},
            "backlash": {
                "x": [
                    {"at_mm": 0, "um": 40.0},
                    {"at_mm": 100, "um": 12.5},
                    {"at_mm": 200, "um": 30.0},
                ],
                "y": 17.0,
                "fraction": 0.8,
            },
        }
    )
    if getattr(_ext, "RECORD", None) != record_names():
        _log.warning(
            "KinComp: the compiled kernel keeps another stream state (%s) than this "
            "package (%s): rebuild it",
            getattr(_ext, "RECORD", None),
            record_names(),
        )
        return False
    options = Options(limits=(-1.0, 201.0, -1.0, 201.0, 0.0, 200.0), policy="clamp")
    program = _check_program()
    taken = 0
    try:
        ref = Compensator(params, options)
        got = Compensator(params, options)
        kernel = got.fast = (make or build)(got)
        if kernel is None:
            return False
        for line in program:
            out = kernel.line(line)
            if out is None:
                out = got.process_declined(line)
            else:
                taken += 1
            if ref.process(line) != out:
                return False
        checker = Compensator(params, options)
        checker.fast = (make or build)(checker)
        problems = gt.check_engine(classifier(checker))
    except Exception:
        _log.exception("KinComp: the compiled kernel failed its self-check")
        return False
    if problems:
        _log.warning("KinComp: the compiled kernel reads G-code unlike the table: %s", problems)
        return False
    a, b = ref.state, got.state
    return (
        2 * taken > len(program)
        and a.report.to_dict() == b.report.to_dict()
        and a.m == b.m
        and a.fw == b.fw
        and a.fw_text == b.fw_text
        and a.backlash.dir == b.backlash.dir
    )
