"""Fuzzing the ballbar trace importers (formats.py): hostile files fail with TraceError only.

Valid seeds (a SIMULATED native trace, an angle-domain trace, a Renishaw-style .b5r, typed
summaries as JSON and as ``key: value`` lines) are mutated by hypothesis; random bytes too.
Whatever comes in, ``load_any`` either returns a usable, finite result or raises
:class:`TraceError` with a message that, for line or field errors, names the line or field.
XML entity bombs and external entities are refused without being expanded (checked with
tracemalloc, never with wall-clock time), and oversized input is refused before parsing.
"""

import json
import math
import os
import re
import tracemalloc

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from octoprint_kincomp.calibration.ballbar import formats
from octoprint_kincomp.calibration.ballbar.formats import (
    ANGLE_HEADER,
    NATIVE_HEADER,
    PLANES,
    AngleTrace,
    NativeTrace,
    Summary,
    TraceError,
    load_any,
    parse_b5r,
    parse_csv_trace,
    parse_summary,
)
from octoprint_kincomp.calibration.ballbar.program import TestSpec, generate
from octoprint_kincomp.simulator.printer import paper_truth, simulate_program
from tests.calibration.test_formats import B5R

# Reproducible in CI: no example database, derandomised generation, no deadline (slow
# runners); the example counts keep this module at a few seconds. KINCOMP_FUZZ_SCALE=N runs
# N times the examples with fresh random seeds (deeper, not reproducible).
SCALE = int(os.environ.get("KINCOMP_FUZZ_SCALE", "0") or 0)
FUZZ = settings(
    max_examples=150 * max(1, SCALE),
    deadline=None,
    derandomize=not SCALE,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
FEW = settings(FUZZ, max_examples=40 * max(1, SCALE))

MB = 1024 * 1024


# -- valid seed files ------------------------------------------------------------------------


def _native_seed() -> bytes:
    spec = TestSpec(radius_mm=20, feed_mm_min=3000, capture_deg=90, overshoot_deg=5, dwell_s=0.1)
    trace = simulate_program(generate(spec), paper_truth(noise_um=0.3, sample_rate_hz=50))
    # keep it short: fuzzing cost grows with the file, coverage does not
    trace.rows = trace.rows[:40]
    return trace.to_text().encode()


def _angle_seed() -> bytes:
    rows = [
        (d, a, 3.0 * math.sin(math.radians(2 * a)) + (0.5 if d == "cw" else -0.5))
        for d in ("ccw", "cw")
        for a in range(0, 360, 15)
    ]
    return (
        AngleTrace(meta={"plane": "XZ", "radius_mm": "150", "centre": "110,110,80"}, rows=rows)
        .to_text()
        .encode()
    )


SUMMARY_DICT = {
    "plane": "XY",
    "radius_mm": 100,
    "centre": [110, 110, 10],
    "feed_mm_min": 1850,
    "squareness_um_per_m": -3638.6,
    "scale_mismatch_ppm": -738.7,
    "servo_mismatch_ms": 0.62,
    "backlash_um": {"a_plus": 4.4, "a_minus": 37.4, "b_plus": 11.3, "b_minus": 5.4},
    "circularity_um": {"cw": 40.1, "ccw": 41.2, "bidirectional": 55.0},
}

SEEDS = {
    "native": (_native_seed(), "run1.csv"),
    "angle": (_angle_seed(), "angle.csv"),
    "b5r": (B5R.replace(b"{plane}", b"XY"), "test.b5r"),
    "b5r_zx": (B5R.replace(b"{plane}", b"ZX"), ""),
    "json": (json.dumps(SUMMARY_DICT, indent=1).encode(), "summary.json"),
    "lines": (
        b"plane: XZ\nradius_mm = 150\nsquareness_um_per_m: -9.7  # from the PDF\n"
        b"servo_mismatch_ms = 0.2\nbacklash_b_plus: 3\nbacklash_a_minus: 1.5\n",
        "summary.txt",
    ),
}


def test_seeds_are_valid():
    """The fuzzing starts from files every reader accepts (else the mutations prove little)."""
    kinds = {name: load_any(data, fn) for name, (data, fn) in SEEDS.items()}
    assert isinstance(kinds["native"], NativeTrace) and len(kinds["native"].rows) == 40
    assert isinstance(kinds["angle"], AngleTrace)
    for name in ("b5r", "b5r_zx", "json", "lines"):
        assert isinstance(kinds[name], Summary), name


# -- checks ----------------------------------------------------------------------------------


def _n_lines(data: bytes) -> int:
    return max(1, len(data.decode("utf-8", "replace").splitlines()))


def _finite_leaves(obj) -> bool:
    if isinstance(obj, dict):
        return all(_finite_leaves(v) for v in obj.values())
    return isinstance(obj, float) and math.isfinite(obj)


def check_load(data: bytes, filename: str = ""):
    """load_any's contract: a usable result, or TraceError with a helpful message."""
    try:
        result = load_any(data, filename)
    except TraceError as exc:
        msg = str(exc)
        assert msg.strip(), "empty TraceError message"
        for m in re.finditer(r"\bline (\d+)", msg):
            assert 1 <= int(m.group(1)) <= _n_lines(data) + 1, (msg, _n_lines(data))
        return exc
    # a result must be usable: finite numbers, known plane, known directions
    assert result.meta.get("plane") in PLANES, result.meta
    if isinstance(result, (NativeTrace, AngleTrace)):
        assert result.rows
        for d, a, b in result.rows:
            assert d in ("cw", "ccw") and math.isfinite(a) and math.isfinite(b)
        assert math.isfinite(float(result.meta["radius_mm"]))
    else:
        assert isinstance(result, Summary)
        assert result.diagnostics and _finite_leaves(result.diagnostics), result.diagnostics
    return result


# -- mutations -------------------------------------------------------------------------------

NASTY_TOKENS = [
    b"",
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"1e999",
    b"-1e999",
    b"1e308",
    b"-1e308",
    b"1e-320",
    b"abc",
    b"0x1F",
    b"1_000",
    b"1,5",
    b"--1",
    b"\xff\xfe",
    b"\x00",
    b"9" * 400,
    b"9" * 5000,
    b"0." + b"0" * 400 + b"1",
    b"true",
    b"null",
    b"[1]",
    b"{}",
    b'"1"',
    b"\xe2\x80\xa8",
    b"0",
    b"-0",
    b"1e-3",
    b"1E3",
]
NASTY_SNIPPETS = [
    b"\n",
    b"\r",
    b"\r\n",
    b",",
    b",,",
    b"#",
    b"# plane: QQ\n",
    b":",
    b"=",
    b"<",
    b">",
    b"</FEATURE>",
    b"<FEATURE NAME='AF_SQUARENESS' DT='UT_SQUARENESS'>",
    b"&amp;",
    b"&#0;",
    b"&#x110000;",
    b"<![CDATA[1]]>",
    b"<?pi x?>",
    b"<!-- c -->",
    b"]]>",
    b'"',
    b"{",
    b"}",
    b"[",
    b"]",
    b"\\u0000",
    b"\xef\xbb\xbf",
    b"\xc0\x80",
    b"\xed\xa0\x80",
    NATIVE_HEADER.encode(),
    ANGLE_HEADER.encode(),
    b"direction,time_s,reading_mm\nccw,1,1\n",
]
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


@st.composite
def mutations(draw, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(
            st.sampled_from(
                [
                    "flip",
                    "insert",
                    "snippet",
                    "delete",
                    "dup",
                    "truncate",
                    "token",
                    "deep",
                    "swap_lines",
                ]
            )
        )
        pos = draw(st.integers(0, len(buf)))
        if op == "flip" and buf:
            buf[min(pos, len(buf) - 1)] = draw(st.integers(0, 255))
        elif op == "insert":
            buf[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "snippet":
            buf[pos:pos] = draw(st.sampled_from(NASTY_SNIPPETS))
        elif op == "delete":
            buf[pos : pos + draw(st.integers(1, 64))] = b""
        elif op == "dup":
            n = draw(st.integers(1, 200))
            buf[pos:pos] = buf[pos : pos + n]
        elif op == "truncate":
            del buf[pos:]
        elif op in ("token", "deep"):
            nums = list(_NUMBER.finditer(bytes(buf)))
            if not nums:
                continue
            m = nums[draw(st.integers(0, len(nums) - 1))]
            if op == "token":
                new = draw(st.sampled_from(NASTY_TOKENS))
            else:  # nest the number in brackets/braces (JSON recursion)
                depth = draw(st.sampled_from([1, 3, 100, 5000]))
                opener, closer = draw(st.sampled_from([(b"[", b"]"), (b'{"a":', b"}")]))
                new = opener * depth + m.group(0) + closer * depth
            buf[m.start() : m.end()] = new
        elif op == "swap_lines":
            lines = bytes(buf).split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            buf = bytearray(b"\n".join(lines))
    return bytes(buf)


@st.composite
def mutated_seed(draw):
    name = draw(st.sampled_from(sorted(SEEDS)))
    data, filename = SEEDS[name]
    filename = draw(st.sampled_from([filename, "", "x.b5r", "trace.CSV"]))
    return draw(mutations(data)), filename


@FUZZ
@given(mutated_seed())
@example((b"[" * 50000, ""))  # JSON nested past the recursion limit
@example((b'{"plane": "XY", "radius_mm": ' + b"9" * 5000 + b"}", ""))  # int digit limit
@example((b'{"plane": "XY", "squareness_um_per_m": ' + b"9" * 400 + b"}", ""))  # int > float
@example((b'<?xml version="1.0" encoding="no-such-codec"?><B/>', ""))
@example((b'<?xml version="1.0" encoding="utf-7"?><B/>', ""))
@example((B5R.replace(b"{plane}", b"XY").replace(b"150mm", b"0mm"), ""))  # um over radius 0
@example((B5R.replace(b"{plane}", b"XY").replace(b"0.0021", b"1e308"), ""))  # mm -> um = inf
def test_mutated_files_raise_only_trace_error(case):
    data, filename = case
    check_load(data, filename)


@FUZZ
@given(st.binary(max_size=512), st.sampled_from(["", "a.b5r", "a.csv"]))
def test_random_bytes_raise_only_trace_error(data, filename):
    check_load(data, filename)


@FEW
@given(st.text(max_size=300), st.sampled_from(["", "a.b5r"]))
def test_random_text_raise_only_trace_error(text, filename):
    check_load(text.encode("utf-8", "surrogatepass"), filename)


# -- the error names the line or the field ---------------------------------------------------

BAD_FIELDS = [b"up", b"", b"nan", b"inf", b"1e999", b"abc", b"1.2.3", b"0x10"]


@FUZZ
@given(st.sampled_from(["native", "angle"]), st.data())
def test_bad_csv_row_is_named_by_its_line(kind, data):
    text = SEEDS[kind][0].decode()
    lines = text.split("\n")
    header = lines.index(NATIVE_HEADER if kind == "native" else ANGLE_HEADER)
    row = data.draw(st.integers(header + 1, len([x for x in lines if x]) - 1), label="row")
    fields = lines[row].split(",")
    how = data.draw(st.sampled_from(["field", "drop", "extra"]), label="how")
    if how == "field":
        i = data.draw(st.integers(0, 2), label="field")
        fields[i] = data.draw(st.sampled_from(BAD_FIELDS), label="value").decode()
    elif how == "drop":
        fields.pop(data.draw(st.integers(0, 2), label="dropped"))
    else:
        fields.append("1")
    lines[row] = ",".join(fields)
    with pytest.raises(TraceError, match=rf"^line {row + 1}: "):
        load_any("\n".join(lines).encode(), "trace.csv")


@FUZZ
@given(
    st.sampled_from(
        ["plane", "radius_mm", "feed_mm_min", "feed_in_mm", "overshoot_deg", "capture_deg"]
    ),
    st.sampled_from([b"", b"abc", b"nan", b"inf", b"1e999", b"QQ", b"-"]),
    st.booleans(),
)
def test_bad_or_missing_metadata_is_named(key, value, drop):
    text = SEEDS["native"][0]
    line = re.search(rb"^# " + key.encode() + rb":[^\n]*\n", text, re.M)
    new = b"" if drop else b"# " + key.encode() + b": " + value + b"\n"
    with pytest.raises(TraceError, match=f"'{key}'"):
        load_any(text[: line.start()] + new + text[line.end() :], "trace.csv")


SUMMARY_FIELDS = [
    "radius_mm",
    "feed_mm_min",
    "squareness_um_per_m",
    "scale_mismatch_ppm",
    "servo_mismatch_ms",
    "backlash_um.a_plus",
    "backlash_um.b_minus",
    "circularity_um.cw",
]


@FUZZ
@given(
    st.sampled_from(SUMMARY_FIELDS),
    st.sampled_from(
        ["abc", "", None, True, [1], {"x": 1}, 1e308 * 10, "nan", "1e999", 10**400, "9" * 5000]
    ),
)
def test_bad_summary_field_is_named(key, value):
    doc = json.loads(json.dumps(SUMMARY_DICT))
    if "." in key:
        group, sub = key.split(".")
        doc[group][sub] = value
        names = (f"{group}.{sub}", f"{group.rsplit('_', 1)[0]}_{sub}")
    else:
        doc[key] = value
        names = (key,)
    # allow_nan: json.dumps writes inf as Infinity, which Python's json reads back
    text = json.dumps(doc)
    with pytest.raises(TraceError) as exc:
        load_any(text.encode(), "summary.json")
    assert any(f"'{n}'" in str(exc.value) for n in names), str(exc.value)


B5R_FEATURES = re.findall(rb'NAME="(AF_[A-Z_]+)"', B5R)


@FUZZ
@given(
    st.sampled_from([n for n in B5R_FEATURES if n != b"AF_SOMETHING_ELSE"]),
    st.sampled_from([b"", b"abc", b"nan", b"inf", b"-inf", b"1e999", b"1,5", b"&#49;x"]),
)
def test_bad_b5r_feature_is_named(name, value):
    data = re.sub(
        rb'(NAME="' + name + rb'"[^>]*>)[^<]*<',
        lambda m: m.group(1) + value + b"<",
        B5R.replace(b"{plane}", b"XY"),
    )
    with pytest.raises(TraceError, match=name.decode()):
        load_any(data, "test.b5r")


# -- XML attacks and oversized input ---------------------------------------------------------


def _peak_during(fn):
    """Run fn() under tracemalloc; returns (result or exception, peak bytes allocated)."""
    tracemalloc.start()
    try:
        try:
            out = fn()
        except BaseException as exc:
            out = exc
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak


def _refused(data: bytes, filename: str, limit=50 * MB) -> TraceError:
    out, peak = _peak_during(lambda: load_any(data, filename))
    assert isinstance(out, TraceError), repr(out)
    assert str(out).strip()
    assert peak < limit, f"peak {peak / MB:.1f} MB"
    return out


LAUGHS = (
    b'<!DOCTYPE lolz [<!ENTITY lol "lol">'
    + b"".join(
        b'<!ENTITY lol%d "%s">'
        % (i + 1, b"".join(b"&lol%d;" % i if i else b"&lol;" for _ in range(10)))
        for i in range(9)
    )
    + b"]>"
)
LAUGHS_BODY = (
    b'<BALLBAR_DATA><PLANE TEST_PLANE="XY"/><FEATURE NAME="AF_SQUARENESS" '
    b'DT="UT_SQUARENESS">&lol9;</FEATURE></BALLBAR_DATA>'
)
XXE = (
    b'<!DOCTYPE b [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>'
    b'<BALLBAR_DATA><PLANE TEST_PLANE="XY"/><TEST_SPEC NAME="&xxe;"/>'
    b'<FEATURE NAME="AF_SQUARENESS" DT="UT_SQUARENESS">1</FEATURE></BALLBAR_DATA>'
)
PARAM_XXE = (
    b'<!DOCTYPE b [<!ENTITY % p SYSTEM "http://127.0.0.1:9/x.dtd"> %p;]>'
    b'<BALLBAR_DATA><PLANE TEST_PLANE="XY"/></BALLBAR_DATA>'
)
EXTERNAL_DTD = (
    b'<!DOCTYPE BALLBAR_DATA SYSTEM "file:///etc/passwd">'
    b'<BALLBAR_DATA><PLANE TEST_PLANE="XY"/></BALLBAR_DATA>'
)
QUADRATIC = (
    b'<!DOCTYPE q [<!ENTITY a "'
    + b"x" * 50000
    + b'">]><BALLBAR_DATA>'
    + b"&a;" * 100000
    + b"</BALLBAR_DATA>"
)
DECL = b'<?xml version="1.0" encoding="utf-8"?>\n'


@pytest.mark.parametrize(
    "doc",
    [
        DECL + LAUGHS + LAUGHS_BODY,
        LAUGHS + LAUGHS_BODY,  # no XML declaration
        DECL + b"<!--" + b"c" * 10000 + b"-->" + LAUGHS + LAUGHS_BODY,  # DTD after 4 kB
        b"\xef\xbb\xbf" + DECL + LAUGHS + LAUGHS_BODY,  # UTF-8 BOM
        b"  \n\t" + LAUGHS + LAUGHS_BODY,  # leading whitespace
        LAUGHS.replace(b"DOCTYPE", b"DOCTYPE\n") + LAUGHS_BODY,
        (b'<?xml version="1.0" encoding="utf-16"?>' + LAUGHS + LAUGHS_BODY)
        .decode()
        .encode("utf-16"),
        QUADRATIC,
        DECL + XXE,
        XXE,
        PARAM_XXE,
        EXTERNAL_DTD,
    ],
    ids=[
        "laughs",
        "laughs-nodecl",
        "laughs-late",
        "laughs-bom",
        "laughs-ws",
        "laughs-nl",
        "laughs-utf16",
        "quadratic",
        "xxe-decl",
        "xxe",
        "param-xxe",
        "external-dtd",
    ],
)
@pytest.mark.parametrize("filename", ["test.b5r", ""])
def test_xml_entity_attacks_refused_without_expansion(doc, filename):
    exc = _refused(doc, filename)
    assert "root:" not in str(exc)  # nothing of the external file leaks into the message
    if filename:  # read as .b5r whatever the content: the DTD check must be what refuses it
        assert "DTD" in str(exc) or "not text XML" in str(exc), str(exc)


def test_xml_attack_through_parse_b5r_directly():
    exc = _refused_fn(lambda: parse_b5r(DECL + LAUGHS + LAUGHS_BODY))
    assert "DTD" in str(exc)


def _refused_fn(fn, limit=50 * MB):
    out, peak = _peak_during(fn)
    assert isinstance(out, TraceError), repr(out)
    assert peak < limit, f"peak {peak / MB:.1f} MB"
    return out


@pytest.mark.parametrize(
    "filler, filename",
    [
        (b"#", "trace.csv"),  # looks like a comment-only CSV
        (b" ", "trace.csv"),  # whitespace: lstrip would copy it
        (b"a", "summary.txt"),
        (b"<", "test.b5r"),
    ],
)
def test_oversized_input_refused_before_parsing(filler, filename):
    data = filler * (formats.MAX_TRACE_BYTES + 1)
    exc = _refused(data, filename, limit=8 * MB)
    assert "larger than" in str(exc) or "too long" in str(exc), str(exc)
    del data


def test_oversized_pieces_refused_by_each_reader():
    xml = b"<a>" + b" " * formats.MAX_XML_BYTES + b"</a>"  # built outside the traced call
    exc = _refused_fn(lambda: parse_b5r(xml), limit=8 * MB)
    assert "larger than" in str(exc)
    text = "#" * (formats.MAX_TRACE_BYTES + 1)
    exc = _refused_fn(lambda: parse_csv_trace(text), limit=8 * MB)
    assert "larger than" in str(exc)
    with pytest.raises(TraceError, match="too long"):
        parse_summary("a" * 100_001)


def test_a_b5r_within_the_size_limit_is_still_read():
    pad = b"<!--" + b"p" * (formats.MAX_XML_BYTES - len(B5R) - 64) + b"-->"
    data = B5R.replace(b"{plane}", b"XY").replace(b"<BALLBAR_DATA>", pad + b"<BALLBAR_DATA>")
    assert len(data) <= formats.MAX_XML_BYTES
    assert load_any(data, "big.b5r").diagnostics["squareness_um_per_m"] == -9.7
