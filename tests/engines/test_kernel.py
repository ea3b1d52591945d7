"""The compiled kernel (engines/kernel.py, engines/csrc/): built here, taking the lines it
should, and writing what the reference path writes, digit for digit, including the numbers
where rounding is decided by the exact binary value (ties and near-ties)."""

import io
import sys
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines import kernel as kernel_mod
from octoprint_kincomp.engines import select
from octoprint_kincomp.engines.files import compensate_binary
from octoprint_kincomp.engines.select import make_compensator

SKEW = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": 1500.0, "xz": -200.0},
        "scale_ppm": {"x": 300.0, "y": -120.0},
        "backlash": {
            "x": [{"at_mm": 0, "um": 40.0}, {"at_mm": 100, "um": 10.0}, {"at_mm": 200, "um": 25.0}],
            "y": 12.0,
        },
    }
)
BACKLASH_ONLY = Params.from_dict({"backlash": {"x": 30.0}})  # identity model: q == p


def state(comp, caches=True):
    """The stream state; ``caches``: with the accelerated engines' own fields (q_last,
    limit_recheck), which the reference path resets on every line it handles."""
    st = comp.state
    bl = st.backlash
    own = (st.q_last, list(st.limit_recheck)) if caches else ()
    return (
        list(st.m),
        list(st.fw),
        list(st.fw_text),
        list(bl.dir),
        list(bl.anchor),
        st.lineno,
        st.e_pos,
        st.feed,
        st.report.to_dict(),
    ) + own


def run(lines, params, options=None, compiled=True):
    """The lines through the kernel (where it takes them) or the reference path alone."""
    comp = Compensator(params, options)
    if compiled:
        comp.fast = kernel_mod.build(comp)
        assert comp.fast is not None
    out = [comp.process(line) for line in lines]
    return [o if isinstance(o, str) else tuple(o) for o in out], state(comp, caches=False)


def test_the_kernel_is_built_in_the_test_environment():
    # the test set-up installs the package with its C extension; without this check a
    # missing compiler would make every "compiled" test quietly test Python twice
    assert kernel_mod.built() and select.available() == "compiled"
    assert make_compensator(SKEW).fast is not None
    with select.use("python"):
        assert make_compensator(SKEW).fast is None
    assert make_compensator(Params()).fast is None  # all zero: nothing to compensate
    assert Compensator(SKEW).fast is None  # the reference path by itself


def test_the_kernel_takes_the_plain_moves():
    lines = [
        "G28",
        "G1 X10 Y10 Z0.3 F3000",
        "G1 X20 Y12 E0.5",
        "G1 X5 Y12 E1.0",
        "G0 F9000 X50 Y60",
        "G1 Z0.5",
        "G1 E-0.8 F2400",
    ]
    ref = run(lines, SKEW, compiled=False)
    seen = []
    real = Compensator._dispatch

    def spy(self, cmd, line):
        seen.append(line)
        return real(self, cmd, line)

    with mock.patch.object(Compensator, "_dispatch", spy):
        assert run(lines, SKEW) == ref
    assert seen == ["G28"]  # every move went through the kernel


def test_a_line_the_kernel_leaves_changes_nothing():
    comp = make_compensator(SKEW, Options(limits=(0, 200, 0, 200, 0, 200)))
    for line in ("G28", "G1 X10 Y10 Z1", "G1 X20 Y20"):
        comp.process(line)
    before = state(comp)
    k, st = comp.fast, comp.state
    # the compensated X of this point leaves the limits: the reference path counts it
    assert k.line(st, "G1 X0 Y199.9") is None
    assert k.line(st, "G1 X10 Y10 ; comment") is None
    assert k.line(st, "M104 S200") is None
    assert state(comp) == before
    assert k.feed(st, b"G1 X0 Y199.9\nG1 X1 Y1\n", 0) == (b"", 0)
    assert state(comp) == before
    out, stop = k.feed(st, b"; c\n\nG1 X30 Y30\r\nM106\nG1 X1 Y1\n", 0)
    assert stop == len(b"; c\n\nG1 X30 Y30\r\n")
    assert out.startswith(b"; c\n\nG1 X") and out.endswith(b"\r\n")
    assert state(comp) != before


# number texts: signs, leading zeros, bare dots, many digits (past 2**53 and the Python
# parser's fast path), and ties at the output resolution (x.xxx5, 0.0625 exactly)
digits = st.text("0123456789", min_size=1, max_size=18)
number = st.one_of(
    st.builds(
        lambda s, i, f: f"{s}{i}.{f}",
        st.sampled_from(["", "-", "+"]),
        digits,
        st.text("0123456789", max_size=24),
    ),
    st.builds(lambda s, f: f"{s}.{f}", st.sampled_from(["", "-"]), digits),
    st.builds(
        lambda i, d: f"{i}.{d}5", st.integers(0, 250), st.text("0123456789", min_size=2, max_size=8)
    ),
    st.sampled_from(
        [
            "0.0625",
            "-0.0625",
            "0.0005",
            "-0.0004",
            "1e3",
            "1.2.3",
            "-",
            ".",
            "00012.5000",
            "-0",
            "+0.0",
            "9" * 40,
        ]
    ),
    st.floats(-300, 300).map(repr),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    st.lists(
        st.tuples(number, number, st.sampled_from(["", " E1.5", " E-0.25 F1800"])),
        min_size=1,
        max_size=12,
    ),
    st.sampled_from([SKEW, BACKLASH_ONLY]),
    st.integers(3, 8),
    st.sampled_from(["G21", "G20"]),
)
def test_the_kernel_and_the_reference_path_write_the_same(moves, params, decimals, units):
    lines = ["G28", units, "G1 X10 Y10 Z1"]
    lines += [f"G1 X{x} Y{y}{tail}" for x, y, tail in moves] + ["G1 X1 Y1"]
    options = Options(decimals=decimals)
    ref = run(lines, params, options, compiled=False)
    assert run(lines, params, options) == ref
    text = "\n".join(lines) + "\n"
    outs = []
    for name in select.ENGINES:
        dst = io.BytesIO()
        with select.use(name):
            rep = compensate_binary(io.BytesIO(text.encode(ENCODING, ERRORS)), dst, params, options)
        outs.append((dst.getvalue(), rep.to_dict()))
    assert outs[0] == outs[1]


@pytest.mark.parametrize(
    "text,want",
    [
        ("0.0625", "X0.062"),  # an exact tie: to even, as Python writes it
        ("0.1875", "X0.188"),  # an exact tie: to even (up)
        ("0.0635", "X0.064"),  # 0.06350000000000000005... in binary: up
        ("1.0005", "X1"),  # 1.000499999999999989... in binary: down (zeros not written)
        ("-0.0004", "X0"),  # no negative zero
        ("2.0996", "X2.1"),  # rounded up to trailing zeros: written as slicers do
        ("-12.0001", "X-12"),
    ],
)
def test_rounding_at_ties_is_pythons(text, want):
    z_only = Params.from_dict({"backlash": {"z": 30.0}})  # X and Y are written as given
    lines = ["G28", "G1 X10 Y10 Z1", f"G1 X{text} Y10"]
    out, _ = run(lines, z_only)
    assert out[-1] == ("G1 " + want + " Y10",)
    assert run(lines, z_only, compiled=False)[0] == out


def test_the_self_check_passes_here_and_catches_a_kernel_that_rounds_otherwise():
    assert kernel_mod.self_check()

    def shifted(comp):  # a kernel whose model is off by 0.1 um in X: some texts differ
        model = comp.model
        saved = model.offset_mm
        model.offset_mm = (saved[0] + 1e-4,) + saved[1:]
        try:
            return kernel_mod.build(comp)
        finally:
            model.offset_mm = saved

    assert not kernel_mod.self_check(make=shifted)

    class Declining:  # writes nothing wrong, but leaves every line to the Python paths
        @staticmethod
        def line(state, line):
            return None

    assert not kernel_mod.self_check(make=lambda comp: Declining())


def test_state_the_kernel_cannot_write_back_is_left_to_python():
    # review finding: a tuple where the kernel writes in place (it never is one in practice)
    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1"):
        comp.process(line)
    comp.state.fw = tuple(comp.state.fw)
    assert comp.fast.line(comp.state, "G1 X20 Y20") is None


def test_negative_zero_anchor_is_written_like_python():
    # review finding: the kernel compared the anchor with ==, so -0.0 stayed where Python
    # writes 0.0 (no effect on the text, but the state must be the same)
    y_only = Params.from_dict({"backlash": {"y": 30.0}})
    lines = ["G28", "G1 X-0 Y10 Z-0", "G1 X-0 Y-0 Z-0", "G1 X0 Y0 Z0"]
    got, ref = run(lines, y_only), run(lines, y_only, compiled=False)
    assert got == ref
    assert [str(a) for a in got[1][4]] == [str(a) for a in ref[1][4]]


def test_the_kernel_reads_only_the_declared_state_classes():
    # the kernel reads and writes the state's slots at offsets found once (layout): an
    # object of another class - a subclass with a __dict__, say - is left to the reference
    # path, unchanged; a class without those slots is refused when the layout is given
    from octoprint_kincomp.core.state import BacklashState, Report, StreamState

    class Annotated(StreamState):
        pass

    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1"):
        comp.process(line)
    assert comp.fast.line(comp.state, "G1 X20 Y20") is not None  # the declared class: taken
    other = Annotated()
    other.take_over(comp.state)
    before = (list(other.m), list(other.fw), other.lineno, other.report.to_dict())
    assert comp.fast.line(other, "G1 X30 Y30") is None
    assert (list(other.m), list(other.fw), other.lineno, other.report.to_dict()) == before

    class Plain:
        m = None

    # classes that have every slot but in another order, and a report without its last one:
    # a layout taken in part would leave the real classes' slots read at the wrong places
    Shuffled = type("Shuffled", (), {"__slots__": tuple(reversed(StreamState.__slots__))})
    Partial = type(
        "Partial", (), {"__slots__": tuple(n for n in Report.__slots__ if n != "max_correction_um")}
    )
    for classes in (
        (Plain, BacklashState, Report),
        (StreamState, BacklashState, Annotated),
        (StreamState, Report, BacklashState),
        (Shuffled, BacklashState, Partial),
    ):
        with pytest.raises(TypeError):
            kernel_mod._ext.layout(*classes)
    # a refused layout leaves the one before in place
    ref = Compensator(SKEW)
    ref.state.take_over(comp.state, backlash_axes=(0, 1, 2))
    ref.state.q_last = comp.state.q_last
    assert comp.fast.line(comp.state, "G1 X40 Y45") == ref.process("G1 X40 Y45")


def _flip_x_direction(st):
    st.backlash.dir[0] = -st.backlash.dir[0] or 1


IN_PLACE_CHANGES = {
    "forget X": lambda st: st.forget_position([0]),
    "work offset": lambda st: st.w.__setitem__(0, 5.0),
    "backlash direction": _flip_x_direction,
    "largest correction": lambda st: st.report.max_correction_um.__setitem__(0, 0.0),
    "limit recheck": lambda st: st.limit_recheck.__setitem__(1, False),
    "firmware text": lambda st: st.fw_text.__setitem__(1, "12.000"),
}


@pytest.mark.parametrize("change", sorted(IN_PLACE_CHANGES))
def test_the_kernel_sees_what_python_changed_in_place_between_its_calls(change):
    # a change the Python side makes in place between two kernel lines (an item of one of
    # the state's lists, some of which the kernel itself writes in place) is seen by the
    # next one: the kernel reads the state afresh on every call
    before = ["G28", "G1 X10 Y10 Z0.3 F3000", "G1 X20 Y12 E0.5"]
    after = ["G1 X30 Y14 E1", "G1 X5 Y20 E1.5", "G2 X15 Y30 I10 J0 E2", "G1 X40 Y5"]

    def go(compiled):
        comp = Compensator(SKEW)
        if compiled:
            comp.fast = kernel_mod.build(comp)
        for line in before:
            comp.process(line)
        IN_PLACE_CHANGES[change](comp.state)
        out = [comp.process(line) for line in after]
        return [o if isinstance(o, str) else tuple(o) for o in out], state(comp, caches=False)

    assert go(True) == go(False)


def _primed():
    """A compensator after some 300 moves (counters past CPython's shared small ints)."""
    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1 F3000", "G1 X20 Y15 E1", "G1 X30 Y20 E2"):
        comp.process(line)
    for n in range(300):
        comp.process("G1 X%d Y20 E%d" % (30 + n % 2, 3 + n))
    return comp


# (X37.123 gives an X text of the length of the last one: the string could be written over)
NEXT = "G1 X37.123 Y40.5 E400 F1200"


@pytest.mark.parametrize("hold", ["containers", "items"])
def test_the_kernel_changes_in_place_only_what_nobody_else_holds(hold):
    # writing back, the kernel changes a number or string in place where its slot (or
    # list) is its only holder (csrc/state.c): whoever holds one of them, or a list or
    # tuple of them, still sees the old value after the next line
    comp = _primed()
    st = comp.state
    rep, bl = st.report, st.backlash
    if hold == "containers":
        held = {"m": st.m, "q_last": st.q_last}
    else:  # (the lists and tuples themselves not held: they may be reused)
        held = {
            "m[0]": st.m[0],
            "q_last[0]": st.q_last[0],
            "fw[0]": st.fw[0],
            "fw_text[0]": st.fw_text[0],
            "e_pos": st.e_pos,
            "feed": st.feed,
            "lines": rep.lines,
            "lineno": st.lineno,
            "max_correction_um[0]": rep.max_correction_um[0],
            "anchor[0]": bl.anchor[0],
        }
    values = {k: repr(v) for k, v in held.items()}
    out = comp.fast.line(st, NEXT)
    assert out is not None and out != NEXT
    for k, v in held.items():
        assert repr(v) == values[k], k
    now = {
        "m": st.m,
        "q_last": st.q_last,
        "m[0]": st.m[0],
        "q_last[0]": st.q_last[0],
        "fw[0]": st.fw[0],
        "fw_text[0]": st.fw_text[0],
        "e_pos": st.e_pos,
        "feed": st.feed,
        "lines": rep.lines,
        "lineno": st.lineno,
    }
    for k in set(held) & set(now):  # (the line did change them: written, not left)
        assert repr(now[k]) != values[k], k
    assert len(st.fw_text[0]) == len(held.get("fw_text[0]", st.fw_text[0]))


def test_a_number_text_python_has_hashed_is_not_written_over():
    # a string whose hash CPython has cached (a dict lookup, an interning) must not get new
    # characters under the old hash: the kernel writes a new string then
    comp = _primed()
    st = comp.state
    old = "".join(st.fw_text[0])  # (an equal string of our own: the state's stays unshared)
    hash(st.fw_text[0])
    sys.intern(st.fw_text[1])
    comp.fast.line(st, NEXT)
    for k in (0, 1):
        text = st.fw_text[k]
        assert hash(text) == hash("".join(text)), k
    assert len(st.fw_text[0]) == len(old) and st.fw_text[0] != old
