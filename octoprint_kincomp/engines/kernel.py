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
off. Before its first use it must write, on a fixed program full of rounding traps, exactly
what the Python path writes (``self_check``): a platform where it would not (a compiler that
fuses multiply-adds, say) runs on the Python paths. The tests run every equivalence check
with and without it.
"""

import contextlib
import logging
import os
import random
from typing import Callable, Iterator, List, Optional

try:  # built by setup.py when a C compiler is there
    from . import _kernel
except ImportError:  # pragma: no cover - depends on the installation
    _kernel = None

_log = logging.getLogger(__name__)
_checked: Optional[bool] = None  # the result of self_check, once run


def available() -> bool:
    """The kernel is built, not turned off, and passed its self-check."""
    global _checked
    if _kernel is None or os.environ.get("KINCOMP_KERNEL", "1") == "0":
        return False
    if _checked is None:
        _checked = False  # (while the check runs, its reference compensators use Python)
        _checked = self_check()
        if not _checked:
            _log.warning("KinComp: the compiled kernel disagrees with the Python path on "
                         "this platform; the pure-Python paths are used")
    return _checked


def for_compensator(comp) -> Optional[object]:
    """A kernel for ``comp``'s model and options, or None (not built, turned off, or a
    model outside the fast path: the Python paths then do everything)."""
    if not comp.fast_lines or not available():
        return None
    return _make(comp)


def _make(comp) -> Optional[object]:
    bl = comp.backlash
    tables = tuple(tuple(bl.tables[k].points) if bl.active[k] else None for k in range(3))
    if any(t is not None and len(t) > _kernel.MAX_POINTS for t in tables):
        return None
    return _kernel.Kernel(comp._affine, tables, comp._half, bl.deadband,
                          comp.options.limits, comp.options.decimals)


def _check_program() -> List[str]:
    """Moves whose numbers are rounding traps: exact ties at the output resolution, values
    that round differently with excess precision or fused multiply-adds, long and signed
    numbers, negative zero; with reversals (backlash take-ups), limits, F first, E tails,
    and an inch section."""
    rnd = random.Random(20261124)
    lines = ["G28", "G1 X10 Y10 Z0.3 F3000"]
    traps = ["0.0625", "0.1875", "1.0005", "0.002877", "-0", "+0.0", "12.3456789012345678",
             "123.4565", "0.0635", "199.9995", "7.", ".5"]
    for i in range(240):
        if i % 3 == 0:
            x, y = rnd.choice(traps), rnd.choice(traps)
        else:
            x = "%.*f" % (rnd.randint(0, 6), rnd.uniform(-2, 205))
            y = "%.*f" % (rnd.randint(0, 6), rnd.uniform(-2, 205))
        tail = rnd.choice(["", " E%.5f" % rnd.uniform(0, 50), " E-0.8 F2400", " F1800"])
        lines.append(rnd.choice(["G1 X%s Y%s%s", "G0 X%s Y%s%s"]) % (x, y, tail))
        if i % 37 == 0:
            lines.append("G1 F%d X%s Y%s Z%.2f" % (rnd.randint(600, 9000), y, x,
                                                   rnd.uniform(0.2, 5)))
        if i == 200:
            lines += ["G20", "G1 X1.23456 Y2.34567", "G1 X0.5 Y3.25"]
    return lines + ["G21", "G1 X1 Y1"]


def self_check(make: Optional[Callable] = None) -> bool:
    """True if a kernel (made by ``make``, default the real one) writes on the check program
    exactly what the Python fast path writes: every line, the report and the state."""
    from ..core.compensator import Compensator, Options
    from ..core.params import Params

    params = Params.from_dict({
        "squareness_um_per_m": {"xy": -1234.5, "xz": 210.0, "yz": -80.0},
        "scale_ppm": {"x": 333.3, "y": -287.0, "z": 50.0},
        "backlash": {"x": [{"at_mm": 0, "um": 40.0}, {"at_mm": 100, "um": 12.5},
                           {"at_mm": 200, "um": 30.0}], "y": 17.0, "fraction": 0.8}})
    options = Options(limits=(-1.0, 201.0, -1.0, 201.0, 0.0, 200.0), policy="clamp")
    try:
        ref = Compensator(params, options)
        ref._kernel = None
        got = Compensator(params, options)
        got._kernel = (make or _make)(got)
        if got._kernel is None:
            return False
        for line in _check_program():
            if ref.process(line) != got.process(line):
                return False
    except Exception:  # noqa: BLE001 - a kernel that raises fails its check
        _log.exception("KinComp: the compiled kernel failed its self-check")
        return False
    return (ref.report.to_dict() == got.report.to_dict() and ref.m == got.m
            and ref.fw_text == got.fw_text and ref.backlash.dir == got.backlash.dir)


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
