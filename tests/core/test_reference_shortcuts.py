"""The reference path's two shortcuts give what the general code gives (issue 38): a body as
slicers write it, split on spaces, has the words of the word-by-word scan; a one-segment
move written by ``PathWriter.straight`` has the lines and leaves the state of the general
``PathWriter.polyline``."""

import copy

from hypothesis import given, settings
from hypothesis import strategies as st

from octoprint_kincomp.core import gcode
from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.tools.benchmark import BENCH_PARAMS

NUMBER = st.from_regex(r"[-+]?(?:[0-9]{1,4}\.?[0-9]{0,5}|\.[0-9]{1,5})", fullmatch=True)
WORD = st.tuples(st.sampled_from("XYZEFIJKRPSxyzef"), NUMBER).map("".join)
PLAIN = st.lists(WORD, max_size=6).map(lambda ws: "".join(" " + w for w in ws))
ANY = st.text(st.sampled_from(list("XYZEFxyz0123456789.-+ \t\xa0*;e")), max_size=16)


@settings(max_examples=400, deadline=None)
@given(PLAIN)
def test_a_plain_body_split_on_spaces_is_the_word_scan(body):
    assert gcode._PLAIN_BODY.fullmatch(body)
    assert gcode._plain_words(body) == gcode._scan_words(body, False)
    assert gcode.parse_words(body) == gcode._scan_words(body, False)


@settings(max_examples=400, deadline=None)
@given(st.one_of(PLAIN, ANY, st.tuples(PLAIN, ANY).map("".join)), st.booleans())
def test_parse_words_is_the_word_scan(body, bare):
    assert gcode.parse_words(body, bare) == gcode._scan_words(body, bare)


PARAMS = [
    Params.from_dict(BENCH_PARAMS),
    Params.from_dict({"squareness_um_per_m": {"xy": 800.0, "xz": 300.0}}),
    Params.from_dict({"backlash": {"x": 50.0, "z": 20.0}, "scale_ppm": {"y": 300.0}}),
]
COORD = st.floats(-20.0, 220.0, allow_nan=False).map(lambda v: round(v, 3))


@settings(max_examples=150, deadline=None)
@given(
    st.sampled_from(range(len(PARAMS))),
    st.lists(st.tuples(COORD, COORD, st.one_of(st.none(), COORD)), min_size=1, max_size=8),
    st.tuples(COORD, COORD, COORD),
    st.sampled_from([(0,), (1,), (0, 1), (0, 1, 2), (2,)]),
    st.booleans(),
)
def test_straight_writes_what_polyline_writes(which, program, end, named, limits):
    """After the same program, one segment through ``straight`` and through ``polyline``
    (the same start, end, words): the same lines, the same state after."""
    options = Options(limits=(0, 200, 0, 200, 0, 150) if limits else None, policy="clamp")
    comp = Compensator(PARAMS[which], options)
    comp.process("G28")
    for x, y, z in program:
        comp.process(f"G1 X{x} Y{y}" + ("" if z is None else f" Z{z}") + " E1.5 F3000")
    twin = copy.deepcopy(comp)
    tail = gcode.parse_words(" E2.25 F1800")
    start = list(comp.state.m)
    a = comp.writer.straight("G1", list(start), end, list(named), tail, "; c")
    b = twin.writer.polyline("G1", list(start), [end], list(named), tail[0], tail, "; c", False)
    assert a == b
    for name in ("m", "fw", "fw_text", "q_drive"):
        assert getattr(comp.state, name) == getattr(twin.state, name), name
    for name in ("dir", "anchor", "ramping"):
        assert getattr(comp.state.backlash, name) == getattr(twin.state.backlash, name), name
    assert comp.report.to_dict() == twin.report.to_dict()
