"""Sensor protocol parsers (issue 15): the three protocols, units and sign, and every fault
case: garbage, binary, wrong baud rate, over-long lines, out of range, NaN/inf, clock."""

import random

import pytest

from octoprint_kincomp.sensor.config import SensorConfig
from octoprint_kincomp.sensor.convention import Convention
from octoprint_kincomp.sensor.diagnostics import Diagnostics
from octoprint_kincomp.sensor.line_splitter import LineSplitter
from octoprint_kincomp.sensor.protocol_kincomp import KinCompParser
from octoprint_kincomp.sensor.protocol_pattern import PatternParser
from octoprint_kincomp.sensor.protocol_plain import PlainParser
from octoprint_kincomp.sensor.sensor_error import SensorError

HEADER = b"KINCOMP-BALLBAR 1\n# sensor: DIY LVDT\n# sample_rate_hz: 500\n"


def feed_all(parser, data: bytes, t=0.0, chunk=7):
    """Feed in small chunks (lines split across reads, as from a real port)."""
    out = []
    for i in range(0, len(data), chunk):
        out += parser.feed(data[i : i + chunk], t)
    return out


# ---- line splitting ------------------------------------------------------------------------


def test_lines_end_with_lf_cr_or_crlf_across_chunks():
    sp = LineSplitter()
    got = []
    for part in (b"a\r\nb", b"b\rc", b"cc\n\n\r\n", b"d"):
        got += sp.feed(part)
    assert got == [b"a", b"bb", b"ccc"]
    assert sp.pending() == 1


def test_a_stream_without_line_end_stays_bounded_and_is_reported():
    sp = LineSplitter(max_line=100)
    reports = []
    for _ in range(100):
        reports += sp.feed(b"x" * 97)
        assert sp.pending() <= 100
    assert reports and all(r is None for r in reports)
    assert len(reports) == pytest.approx(9700 / 100, abs=2)
    end = sp.feed(b"tail\nok\n")  # the rest of the long line is dropped, then lines again
    assert end[-1] == b"ok" and set(end[:-1]) <= {None}


# ---- KinComp protocol ----------------------------------------------------------------------


def test_kincomp_header_meta_and_samples():
    p = KinCompParser()
    data = (
        HEADER + b"# units: um\n# positive: shorter\n# range: -2500,2500\n# x_temp: 21.5\n"
        b"1000,12.5\n3000,-7.25,extra-field\n"
    )
    s = feed_all(p, data, t=99.0)
    assert [(round(x.t, 6), x.mm) for x in s] == [(0.001, -0.0125), (0.003, 0.00725)]
    info = p.info()
    assert info["sensor_name"] == "DIY LVDT" and info["sensor_x_temp"] == "21.5"
    assert info["sensor_units"] == "um" and info["sensor_positive"] == "shorter"
    assert info["sensor_protocol"] == "KINCOMP-BALLBAR 1" and info["timing"] == "device clock"
    assert p.diagnostics.bad_lines == 0 and p.diagnostics.samples == 2


def test_kincomp_unwraps_the_32_bit_microsecond_clock():
    p = KinCompParser()
    start = (1 << 32) - 3000
    lines = [f"{(start + 2000 * k) % (1 << 32)},0.5" for k in range(6)]
    s = feed_all(p, HEADER + ("\n".join(lines) + "\n").encode())
    dts = [round((b.t - a.t) * 1e6) for a, b in zip(s, s[1:])]
    assert dts == [2000] * 5 and p.diagnostics.counts["clock"] == 0


def test_kincomp_clock_going_backwards_is_a_counted_fault():
    p = KinCompParser()
    s = feed_all(p, HEADER + b"5000,1\n7000,1\n6000,1\n9000,1\n")
    assert [round(x.t * 1e6) for x in s] == [5000, 7000, 9000]
    assert p.diagnostics.counts["clock"] == 1
    assert p.diagnostics.examples["clock"] == ["6000,1"]


def test_kincomp_restart_after_a_repeated_header_is_noted_not_a_fault():
    p = KinCompParser()
    s = feed_all(p, HEADER + b"900000,1\n902000,1\n" + HEADER + b"10,1\n2010,1\n")
    assert len(s) == 4 and all(b.t > a.t for a, b in zip(s, s[1:]))
    assert p.diagnostics.counts["clock"] == 0 and p.restarts == 1
    assert any("restarted" in n for n in p.diagnostics.notes)


def test_kincomp_forward_jump_needs_confirmation():
    p = KinCompParser()
    glitch = feed_all(p, HEADER + b"1000,1\n999999999,1\n3000,1\n")
    assert [round(x.t * 1e6) for x in glitch] == [1000, 3000]  # a single wild time stamp
    assert p.diagnostics.counts["clock"] == 1
    p = KinCompParser()
    paused = feed_all(p, HEADER + b"1000,1\n60001000,1\n60003000,1\n")
    assert [round(x.t * 1e6) for x in paused] == [1000, 60003000]  # confirmed gap


def test_kincomp_samples_before_the_header_are_held_back():
    p = KinCompParser()
    assert feed_all(p, b"1000,0.5\n3000,0.5\n") == []
    assert p.waiting_for_header == 2 and p.diagnostics.bad_lines == 0
    assert len(feed_all(p, b"# units: mm\n" + HEADER + b"5000,0.5\n")) == 1


def test_kincomp_unsupported_version_is_refused():
    with pytest.raises(SensorError, match="version 2"):
        feed_all(KinCompParser(), b"KINCOMP-BALLBAR 2\n")
    p = KinCompParser()
    feed_all(p, b"KINCOMP-BALLBAR 1.3 firmware 0.9\n1,1\n")
    assert p.version == "1.3" and p.diagnostics.samples == 1


@pytest.mark.parametrize(
    "line",
    [
        b"KINCOMP-BALLBAR one",
        b"# units: furlong",
        b"# positive: sideways",
        b"# range: 5,1",
        b"# sample_rate_hz: -3",
        b"# resolution_um: abc",
    ],
)
def test_kincomp_bad_header_lines_are_counted(line):
    p = KinCompParser()
    feed_all(p, HEADER + line + b"\n")
    assert p.diagnostics.counts["header"] == 1


def test_kincomp_convention_change_mid_stream_fails():
    p = KinCompParser()
    feed_all(p, HEADER + b"1000,0.5\n")
    with pytest.raises(SensorError, match="units"):
        feed_all(p, b"# units: um\n")
    same = KinCompParser()
    feed_all(
        same,
        HEADER + b"# range: -2,2\n1000,0.5\n" + HEADER + b"# units: mm\n"
        b"# positive: LONGER\n# range: -2.0, 2\n3000,0.5\n",
    )
    assert same.diagnostics.samples == 2  # the same (or the default) again is fine


@pytest.mark.parametrize(
    "line,kind",
    [
        (b"1000,nan", "not_finite"),
        (b"1000,-inf", "not_finite"),
        (b"1000,1e999", "not_finite"),
        (b"1000,abc", "garbage"),
        (b"hello world", "garbage"),
        (b"-5,1.0", "garbage"),
        (b"1000,3.5", "out_of_range"),
        (b"1000,-1e6", "out_of_range"),
        (b"1000,\x00\x01", "unreadable"),
        (b"\xc3\xa9\xff\xfe", "unreadable"),
    ],
)
def test_kincomp_fault_lines(line, kind):
    p = KinCompParser()
    assert feed_all(p, HEADER + b"# range: -2.5,2.5\n" + line + b"\n2000,0.1\n")[-1].mm == 0.1
    assert p.diagnostics.counts[kind] == 1 and p.diagnostics.bad_lines == 1


# ---- plain and pattern ---------------------------------------------------------------------


def test_plain_readings_are_host_timed_and_converted():
    p = PlainParser(convention=Convention("inch", longer_positive=False))
    s = p.feed(b"# comment\n0.5\n+1e-1\nbad\n-.25\n", 12.5)
    assert [x.mm for x in s] == pytest.approx([-12.7, -2.54, 6.35])
    assert {x.t for x in s} == {12.5}
    assert [x.seq for x in s] == [1, 2, 4]  # bad lines keep their place, comments do not
    assert p.info()["timing"] == "host arrival"


def test_plain_range_is_in_the_sensors_own_units():
    p = PlainParser(convention=Convention("um"), range_raw=(-100.0, 100.0))
    s = p.feed(b"50\n150\n-99\n", 0.0)
    assert [x.mm for x in s] == pytest.approx([0.05, -0.099])
    assert p.diagnostics.counts["out_of_range"] == 1


@pytest.mark.parametrize(
    "pattern,scale,line,mm",
    [
        (r"(?P<value>[+-]\d+\.\d+)", 1.0, b"+00.0123", 0.0123),
        (r"01A(?P<value>[+-]\d{8})", 0.0001, b"01A+00001234", 0.1234),
        (r"01A(?P<value>[+-]\d{8})", 0.0001, b"01A-00012345", -1.2345),
        (r"ST,(?P<value>[+-] *\d+\.\d+) ?mm", 1.0, b"  ST,- 1.500 mm  ", -1.5),
    ],
)
def test_pattern_examples(pattern, scale, line, mm):
    p = PatternParser(pattern, scale)
    s = p.feed(line + b"\r\n", 3.0)
    assert len(s) == 1 and s[0].mm == pytest.approx(mm) and s[0].t == 3.0


def test_pattern_mismatch_is_garbage():
    p = PatternParser(r"01A(?P<value>[+-]\d{8})", 0.0001)
    p.feed(b"01A+0000123\n01B+00001234\n+00001234\n", 0.0)
    assert p.diagnostics.counts["garbage"] == 3


@pytest.mark.parametrize(
    "pattern,scale,field,text",
    [
        ("", 1, "pattern", "needed"),
        ("(?P<value>[0-9", 1, "pattern", "not a valid regular expression"),
        (r"(\d+)", 1, "pattern", "named group"),
        ("x" * 201, 1, "pattern", "longer than"),
        (r"(?P<value>\d+)", 0, "scale", "not zero"),
        (r"(?P<value>\d+)", float("nan"), "scale", "finite"),
        (r"(?P<value>\d+)", "ten", "scale", "a number"),
    ],
)
def test_pattern_settings_are_validated(pattern, scale, field, text):
    with pytest.raises(SensorError, match=text) as exc:
        PatternParser(pattern, scale)
    assert exc.value.field == field


# ---- limits --------------------------------------------------------------------------------


def test_a_bounded_number_of_bad_lines_is_tolerated():
    p = PlainParser(diagnostics=Diagnostics(max_bad=5))
    for k in range(6):
        p.feed(b"0.1\n" * 30 + b"oops\n", float(k))
        if k < 5:
            assert p.diagnostics.fatal() is None
    msg = p.diagnostics.fatal()
    assert "too many bad lines" in msg and "'oops'" in msg
    assert p.diagnostics.fatal(total_limit=False) is None  # no burst: a preview goes on


def test_wrong_baud_rate_mojibake_fails_fast_with_a_hint():
    rng = random.Random(4)
    junk = bytes(rng.choice([0x0A] + list(range(0x80, 0x100))) for _ in range(4000))
    p = KinCompParser()
    p.feed(HEADER, 0.0)
    p.feed(junk, 0.0)
    msg = p.diagnostics.fatal(total_limit=False)
    assert msg is not None and "baud rate" in msg
    assert p.diagnostics.counts["unreadable"] > 20


def test_no_line_end_fails_and_memory_stays_bounded():
    p = PlainParser()
    for _ in range(50):
        p.feed(b"0123456789" * 100, 0.0)
        assert p._lines.pending() <= p._lines.max_line
    assert "line end" in p.diagnostics.fatal(total_limit=False)


def test_diagnostics_keep_only_a_few_short_examples():
    p = PlainParser(diagnostics=Diagnostics(max_bad=10_000))
    p.feed(b"".join(b"garbage line %d %s\n" % (k, b"y" * 150) for k in range(500)), 0.0)
    d = p.diagnostics.as_dict()
    assert d["counts"] == {"garbage": 500}
    assert len(d["examples"]["garbage"]) == 3
    assert all(len(e) <= 43 for e in d["examples"]["garbage"])


# ---- settings ------------------------------------------------------------------------------


def test_config_defaults_and_parsers():
    cfg = SensorConfig.from_dict({"port": "loop://"})
    assert isinstance(cfg.make_parser(), KinCompParser)
    cfg = SensorConfig.from_dict(
        {
            "port": "/dev/ttyACM0",
            "protocol": "pattern",
            "pattern": r"(?P<value>\d+)",
            "scale": "0.001",
            "units": "um",
            "positive": "shorter",
            "range": "0,12700",
        }
    )
    p = cfg.make_parser()
    assert isinstance(p, PatternParser) and p.feed(b"5000\n", 0.0)[0].mm == pytest.approx(-0.005)
    assert SensorConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize(
    "d,field",
    [
        ({"speed": 1}, "speed"),
        ({"protocol": "modbus"}, "protocol"),
        ({"baudrate": 0}, "baudrate"),
        ({"baudrate": "fast"}, "baudrate"),
        ({"baudrate": 9600.5}, "baudrate"),
        ({"units": "cm"}, "units"),
        ({"positive": "up"}, "positive"),
        ({"range": "1"}, "range"),
        ({"range": "3,1"}, "range"),
        ({"sample_rate_hz": -1}, "sample_rate_hz"),
        ({"sample_rate_hz": 0.5}, "sample_rate_hz"),
        ({"protocol": "pattern"}, "pattern"),
        ({"no_data_timeout_s": 0}, "no_data_timeout_s"),
        ({"max_bad_lines": True}, "max_bad_lines"),
        ({"port": 5}, "port"),
    ],
)
def test_config_errors_name_the_setting(d, field):
    with pytest.raises(SensorError) as exc:
        SensorConfig.from_dict(d)
    assert exc.value.field == field


def test_the_documented_example_parses_as_documented():
    import os

    from tests.support import ROOT

    # the manual's page on live capture (it was the README's section until issue 25)
    text = open(os.path.join(ROOT, "docs", "live-capture.md"), encoding="utf-8").read()
    block = text.split("```text\n")[1].split("```")[0]
    p = KinCompParser()
    s = p.feed(block.encode("ascii"), 0.0)
    assert len(s) == 4 and p.diagnostics.bad_lines == 0
    assert [round((b.t - a.t) * 1e6) for a, b in zip(s, s[1:])] == [2000] * 3  # across the wrap
    assert p.info()["sensor_range"] == "-2,2" and p.info()["sensor_name"].startswith("DIY")
