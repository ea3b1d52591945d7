"""The compiled kernel (engines/kernel.py, engines/csrc/): built here, taking the lines it
should, and writing what the reference path writes, digit for digit, including the numbers
where rounding is decided by the exact binary value (ties and near-ties)."""

import io
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines import kernel as kernel_mod
from octoprint_kincomp.engines import select
from octoprint_kincomp.engines.file_loop import compensate_binary
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
    k = comp.fast
    # the compensated X of this point leaves the limits: the reference path counts it
    assert k.line("G1 X0 Y199.9") is None
    assert k.line("G1 X10 Y10 ; comment") is None
    assert k.line("M104 S200") is None
    assert state(comp) == before
    assert k.feed(b"G1 X0 Y199.9\nG1 X1 Y1\n", 0) == (b"", 0)
    assert state(comp) == before
    out, stop = k.feed(b"; c\n\nG1 X30 Y30\r\nM106\nG1 X1 Y1\n", 0)
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
        def line(line):
            return None

        @staticmethod
        def release():
            pass

    assert not kernel_mod.self_check(make=lambda comp: Declining())


def test_the_kernel_reads_g_code_as_the_table_does_and_the_self_check_holds_it_to_that():
    from octoprint_kincomp.core import gcode_table as gt

    ask = kernel_mod.classifier(make_compensator(SKEW))
    assert [ask(c) for c in ("G0", "G1", "G2", "G3")] == [gt.LINEAR, gt.LINEAR, gt.ARC, gt.ARC]
    assert {ask(c) for c in ("M82", "G92", "G28", "T0", "G1.1", "G91", "G20")} == {None}
    assert gt.check_engine(ask) == []

    class M83AsInert:  # the real kernel, but it passes M83 as written (the table: extruder)
        def __init__(self, comp):
            self.k = kernel_mod.build(comp)

        def line(self, line):
            return line if line.startswith("M83") else self.k.line(line)

        def __getattr__(self, name):
            return getattr(self.k, name)

    comp = Compensator(SKEW)
    comp.fast = M83AsInert(comp)
    assert gt.check_engine(kernel_mod.classifier(comp)) == [
        "M83: the engine takes it as inert, the table says extruder"
    ]
    assert not kernel_mod.self_check(make=M83AsInert)


def test_the_kernels_record_is_the_stream_states_fields_and_another_one_is_refused():
    from operator import attrgetter

    from octoprint_kincomp.core.state import BacklashState, Report, StreamState

    st = StreamState()
    flat = [f for f in kernel_mod.RECORD for f in ((f,) if isinstance(f, str) else f)]
    owners = {"": StreamState.FIELDS, "backlash": BacklashState.FIELDS, "report": Report.__slots__}
    for name in flat:  # every field names a declared field of the state
        owner, _, field = name.rpartition(".")
        assert field in owners[owner], name
        attrgetter(name)(st)
    got = kernel_mod.record(st)
    assert len(got) == len(kernel_mod.RECORD) and len(got[17]) == len(kernel_mod.COUNTS)
    assert kernel_mod._ext.RECORD == kernel_mod.record_names()  # the extension's own list
    swapped = kernel_mod.RECORD[1::-1] + kernel_mod.RECORD[2:]  # "inches absolute ..."
    with mock.patch.object(kernel_mod._ext, "RECORD", kernel_mod.record_names(swapped)):
        assert not kernel_mod.self_check()
    assert kernel_mod.self_check()


def test_a_state_the_kernel_cannot_hold_is_left_to_python():
    # drives away from the desired position's command (q_drive), or a number text longer
    # than the record holds: the reference path takes the line, and the state stays Python's
    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1"):
        comp.process(line)
    comp.state.fw_text[0] = "1" + "0" * 60
    assert comp.fast.line("G1 X20 Y20") is None
    assert comp.fast.get_state() is None  # (not held)
    # a value of a type the record does not take (a float plane): declined, not an error
    comp.state.fw_text[0] = None
    comp.state.plane = 17.0
    assert comp.fast.line("G1 X20 Y20") is None and comp.fast.get_state() is None
    comp = make_compensator(SKEW)
    comp.process("G28 X")  # (under XY skew: Y's drive is not at its command)
    assert comp.state.q_drive is not None
    assert comp.fast.line("G1 X20 Y20") is None


def test_negative_zero_anchor_is_written_like_python():
    # review finding: the kernel compared the anchor with ==, so -0.0 stayed where Python
    # writes 0.0 (no effect on the text, but the state must be the same)
    y_only = Params.from_dict({"backlash": {"y": 30.0}})
    lines = ["G28", "G1 X-0 Y10 Z-0", "G1 X-0 Y-0 Z-0", "G1 X0 Y0 Z0"]
    got, ref = run(lines, y_only), run(lines, y_only, compiled=False)
    assert got == ref
    assert [str(a) for a in got[1][4]] == [str(a) for a in ref[1][4]]


def test_the_state_crosses_only_as_the_declared_record():
    # the kernel holds the state while it takes lines; Python gets it back as the record
    # (a tuple of plain values, kernel.RECORD's order) when it reads comp.state
    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1 F3000", "G1 X20 Y15 E1"):
        comp.process(line)
    k = comp.fast
    assert k.get_state() is not None  # held: the last line was the kernel's
    rec = k.get_state()
    assert len(rec) == len(kernel_mod.RECORD)
    st = comp.state  # (hands it back)
    assert k.get_state() is None
    assert rec == tuple(tuple(v) if isinstance(v, list) else v for v in kernel_mod.record(st))
    # set and read back: the same values; a malformed record is an error, not a guess
    assert k.set_state(rec) is True and k.get_state() == rec
    with pytest.raises(TypeError):
        k.set_state(rec[:-1])
    with pytest.raises(TypeError):
        k.set_state(rec[:5] + ("not three",) + rec[6:])
    k.release()
    # a record held but not changed is not written back: Python's state stays the truth
    before = state(comp)
    comp.state.m[0] = 11.0
    assert k.set_state(kernel_mod.record(comp.state)) is True
    k.release()
    assert comp.state.m[0] == 11.0 and state(comp)[1:] == before[1:]


def test_consecutive_declined_lines_hand_the_state_over_once():
    comp = make_compensator(SKEW)
    for line in ("G28", "G1 X10 Y10 Z1 F3000"):
        comp.process(line)
    assert comp.state.lineno == 2  # (handed back: Python holds it)
    calls = []
    real = kernel_mod.adopt
    with mock.patch.object(kernel_mod, "adopt", lambda st, rec: calls.append(1) or real(st, rec)):
        for line in ("G1 X20 Y15 E1", "G1 X21 Y15 E2", "; a comment", ""):
            assert comp.process(line) is not None
        assert calls == []  # (the comment and the blank line taken while held)
        for line in ("M106 S255", "M107", "G92 E0", "M400"):
            comp.process(line)
        assert calls == [1]  # the four declined lines: one hand-back
        comp.process("G1 X22 Y15 E1")
        assert comp.report.lines == 11 and calls == [1, 1]


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
    # the state's lists) is seen by the next one: reading comp.state takes the state back
    # from the kernel, which takes it afresh with the next line
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


def _values(st) -> dict:
    """The state's values a caller may hold: two containers, then single items."""
    rep, bl = st.report, st.backlash
    return {
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
        "max_correction_um[0]": rep.max_correction_um[0],
        "anchor[0]": bl.anchor[0],
    }


CONTAINERS = ("m", "q_last")
UNCHANGED_BY_NEXT = ("max_correction_um[0]", "anchor[0]")


@pytest.mark.parametrize("hold", ["containers", "items"])
def test_values_held_from_the_state_do_not_change_under_their_holder(hold):
    # handing the state back, the kernel writes new values (csrc/state.c builds them):
    # whoever holds one of the old ones, or a list or tuple of them, still sees the old
    # value after the next line
    comp = _primed()
    st = comp.state
    # (holding items, the lists and tuples themselves are not held: they may be reused)
    held = {k: v for k, v in _values(st).items() if (k in CONTAINERS) == (hold == "containers")}
    values = {k: repr(v) for k, v in held.items()}
    out = comp.fast.line(NEXT)
    assert out is not None and out != NEXT
    assert comp.state is st  # (the same objects, their values handed back)
    for k, v in held.items():
        assert repr(v) == values[k], k
    now = _values(st)
    for k in set(held) - set(UNCHANGED_BY_NEXT):  # (the line did change them: written, not left)
        assert repr(now[k]) != values[k], k
    assert len(st.fw_text[0]) == len(held.get("fw_text[0]", st.fw_text[0]))


def test_the_kernel_source_reaches_into_no_python_object():
    # csrc/ uses the public C API only (the state crosses as a tuple of plain values): no
    # reference counts read or set, no object's internals (int digits, float or string
    # buffers, list items in place, member descriptors, slot offsets), no branch on the
    # CPython version - what keeps it right on any CPython 3.8+, free-threaded builds too
    import glob
    import os

    forbidden = ["ob_refcnt", "Py_REFCNT", "Py_SET_REFCNT", "ob_digit", "ob_item", "ob_fval"]
    forbidden += ["PyUnicode_DATA", "1BYTE_DATA", "PyMemberDescr", "structmember", "wstr"]
    forbidden += ["PY_VERSION_HEX", "->hash", "PyFloat_AS_DOUBLE"]
    csrc = os.path.join(os.path.dirname(kernel_mod.__file__), "csrc")
    files = glob.glob(os.path.join(csrc, "*.[ch]"))
    assert len(files) >= 6
    for path in files:
        with open(path) as f:
            text = f.read()
        for word in forbidden:
            assert word not in text, (os.path.basename(path), word)
