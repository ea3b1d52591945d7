"""Trace formats: native CSV, angle CSV, .b5r XML, typed summary (issue 7)."""

import json
import time

import pytest

from octoprint_kincomp.calibration.ballbar.formats import (
    AngleTrace,
    NativeTrace,
    TraceError,
    load_any,
    parse_b5r,
    parse_csv_trace,
    parse_summary,
)

META = (
    "# plane: XY\n# radius_mm: 100\n# feed_mm_min: 1850\n# centre: 110,110,10\n"
    "# feed_in_mm: 1\n# overshoot_deg: 20\n# capture_deg: 360\n"
)


def test_native_round_trip():
    t = NativeTrace(
        meta={
            "plane": "XY",
            "radius_mm": "100",
            "feed_mm_min": "1850",
            "feed_in_mm": "1",
            "overshoot_deg": "20",
            "capture_deg": "360",
        },
        rows=[("ccw", 0.0, 1.0), ("ccw", 0.002, 0.9999995), ("cw", 5.0, 1.0)],
    )
    back = parse_csv_trace(t.to_text())
    assert isinstance(back, NativeTrace) and back.meta["plane"] == "XY"
    assert back.rows == [("ccw", 0.0, 1.0), ("ccw", 0.002, 0.9999995), ("cw", 5.0, 1.0)]


def test_angle_trace_parse():
    text = "# plane: XZ\n# radius_mm: 150\ndirection,angle_deg,deviation_um\nCW,10.5,-2.25\n"
    t = parse_csv_trace(text)
    assert isinstance(t, AngleTrace) and t.rows == [("cw", 10.5, -2.25)]


@pytest.mark.parametrize(
    "text, msg",
    [
        ("", "no header"),
        (META + "direction,time,reading\n", "line 8: expected the header"),
        (META + "direction,time_s,reading_mm\nccw,0.1\n", "line 9: expected 3"),
        (META + "direction,time_s,reading_mm\nup,0.1,0.2\n", "line 9: direction must be"),
        (META + "direction,time_s,reading_mm\nccw,abc,0.2\n", "line 9: not a number"),
        (META + "direction,time_s,reading_mm\nccw,nan,0.2\n", "line 9: NaN"),
        (META + "direction,time_s,reading_mm\n", "no samples"),
        ("# plane: QQ\n# radius_mm: 100\ndirection,angle_deg,deviation_um\nccw,1,1\n", "plane"),
        ("# plane: XY\ndirection,angle_deg,deviation_um\nccw,1,1\n", "'radius_mm' is missing"),
        (
            "# plane: XY\n# radius_mm: big\ndirection,angle_deg,deviation_um\nccw,1,1\n",
            "'radius_mm'",
        ),
        ("# plane: XY\n# radius_mm: 100\ndirection,time_s,reading_mm\nccw,1,1\n", "feed_mm_min"),
    ],
)
def test_malformed_traces_name_the_problem(text, msg):
    with pytest.raises(TraceError, match=msg):
        parse_csv_trace(text)


B5R = b"""<?xml version="1.0" encoding="utf-8"?>
<BALLBAR_DATA>
  <TEST_SPEC NAME="XY 360 150mm 20251218-194332"/>
  <MACHINE_TESTED NAME="Printer"/>
  <PLANE TEST_PLANE="{plane}"/>
  <DIAGNOSTICS>
    <FEATURE NAME="AF_SQUARENESS" DT="UT_SQUARENESS">-9.7</FEATURE>
    <FEATURE NAME="AF_SCALE_MISMATCH" DT="UT_LENGTH_UM">3.0</FEATURE>
    <FEATURE NAME="AF_SERVO_MISMATCH" DT="UT_SERVO_MISMATCH">-0.01</FEATURE>
    <FEATURE NAME="AF_BACKLASH_A_POS" DT="UT_LENGTH_UM">-1.5</FEATURE>
    <FEATURE NAME="AF_BACKLASH_A_NEG" DT="UT_LENGTH_UM">-0.9</FEATURE>
    <FEATURE NAME="AF_BACKLASH_B_POS" DT="UT_LENGTH_MM">0.0021</FEATURE>
    <FEATURE NAME="AF_LATERAL_PLAY_B_NEG" DT="UT_LENGTH_UM">1.2</FEATURE>
    <FEATURE NAME="AF_REVERSAL_SPIKES_A_POS" DT="UT_LENGTH_UM">0.7</FEATURE>
    <FEATURE NAME="AF_CIRCULARITY" DT="UT_LENGTH_UM">10.2</FEATURE>
    <FEATURE NAME="AF_SOMETHING_ELSE" DT="UT_RANKING">22</FEATURE>
  </DIAGNOSTICS>
</BALLBAR_DATA>"""


def test_b5r_features_by_name_and_unit():
    s = parse_b5r(B5R.replace(b"{plane}", b"XY"))
    d = s.diagnostics
    assert s.meta["plane"] == "XY" and s.meta["radius_mm"] == "150"
    assert d["squareness_um_per_m"] == -9.7
    assert d["scale_mismatch_ppm"] == pytest.approx(3.0 / 150 * 1000)
    assert d["servo_mismatch_ms"] == -0.01
    assert d["backlash_um"] == {"a_plus": -1.5, "a_minus": -0.9, "b_plus": pytest.approx(2.1)}
    assert d["lateral_play_um"] == {"b_minus": 1.2}
    assert d["reversal_spikes_um"] == {"a_plus": 0.7}
    assert d["circularity_um"] == {"bidirectional": 10.2}


def test_b5r_zx_plane_swaps_axes():
    d = parse_b5r(B5R.replace(b"{plane}", b"ZX")).diagnostics
    assert d["backlash_um"]["b_plus"] == -1.5 and d["backlash_um"]["a_plus"] == pytest.approx(2.1)
    assert d["servo_mismatch_ms"] == 0.01 and d["squareness_um_per_m"] == -9.7


@pytest.mark.parametrize(
    "data, msg",
    [
        (b"<BALLBAR_DATA><PLANE TEST_PLANE='XY'/>", "not well-formed"),
        (b"<BALLBAR_DATA><PLANE TEST_PLANE='QQ'/></BALLBAR_DATA>", "TEST_PLANE"),
        (b"<BALLBAR_DATA><PLANE TEST_PLANE='XY'/></BALLBAR_DATA>", "no known FEATURE"),
        (
            b"<B><PLANE TEST_PLANE='XY'/>"
            b"<FEATURE NAME='AF_SQUARENESS' DT='UT_SQUARENESS'>x</FEATURE></B>",
            "non-numeric",
        ),
        (
            b"<B><PLANE TEST_PLANE='XY'/>"
            b"<FEATURE NAME='AF_SQUARENESS' DT='UT_WHAT'>1</FEATURE></B>",
            "unknown unit",
        ),
    ],
)
def test_b5r_errors(data, msg):
    with pytest.raises(TraceError, match=msg):
        parse_b5r(data)


def test_xml_entity_bomb_refused_quickly():
    bomb = (
        b'<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
        + b"".join(b'<!ENTITY lol%d "' % (i + 1) + b"&lol%d;" % i * 10 + b'">' for i in range(9))
        + b"]><lolz>&lol9;</lolz>"
    )
    t0 = time.perf_counter()
    with pytest.raises(TraceError, match="DTD or entity"):
        parse_b5r(bomb)
    assert time.perf_counter() - t0 < 1.0


def test_oversized_xml_refused():
    with pytest.raises(TraceError, match="larger than"):
        parse_b5r(b"<a>" + b" " * (9 * 1024 * 1024) + b"</a>")


def test_typed_summary_json_and_lines():
    s = parse_summary(
        json.dumps(
            {
                "plane": "XY",
                "radius_mm": 100,
                "centre": [110, 110, 10],
                "squareness_um_per_m": 120,
                "backlash_um": {"a_plus": 5, "a_minus": 7},
            }
        )
    )
    assert s.diagnostics["squareness_um_per_m"] == 120
    assert s.diagnostics["backlash_um"] == {"a_plus": 5.0, "a_minus": 7.0}
    s = parse_summary(
        "plane: XZ\nsquareness_um_per_m: -9.7  # from the PDF\n"
        "servo_mismatch_ms = 0.2\nbacklash_b_plus: 3\n"
    )
    assert s.meta["plane"] == "XZ" and s.diagnostics["backlash_um"] == {"b_plus": 3.0}


@pytest.mark.parametrize(
    "data, msg",
    [
        ('{"squareness_um_per_m": 1}', "plane"),
        ('{"plane": "XY"}', "no diagnostic"),
        ('{"plane": "XY", "wobble": 1}', "'wobble' is unknown"),
        ('{"plane": "XY", "squareness_um_per_m": "abc"}', "is not a number"),
        ('{"plane": "XY", "backlash_um": {"a_plus": -2}}', "must be at least 0"),
        ('{"plane": "XY", "backlash_um": {"up": 2}}', "backlash_um.up"),
        ("just some words\n", "its line 1 is not"),
        ("[1, 2]", "object"),
    ],
)
def test_typed_summary_errors(data, msg):
    with pytest.raises(TraceError, match=msg):
        parse_summary(data)


def test_load_any_dispatch():
    assert load_any(B5R.replace(b"{plane}", b"XY")).kind == "summary"
    assert load_any((META + "direction,time_s,reading_mm\nccw,0,1\n").encode()).kind == "native"
    assert load_any(b'{"plane": "XY", "squareness_um_per_m": 3}').kind == "summary"
    with pytest.raises(TraceError, match="UTF-8"):
        load_any(b"\xff\xfe\x00garbage")
