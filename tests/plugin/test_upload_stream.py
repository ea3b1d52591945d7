"""The upload preprocessor's stream (OctoPrint's LineProcessorStream): the same bytes as the
offline file engine, the marker first, and a file already marked anywhere in its first
lines passed through untouched (issue 3)."""

import io
import os

from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.marker import MARKER_SCAN_LINES
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.file_loop import compensate_binary, marker_line
from octoprint_kincomp.plugin.files.upload import CompensatingStream
from tests.support import DATA as DATA

PARAMS = Params.from_dict(
    {
        "squareness_um_per_m": {"xy": -3638.6, "xz": 120.0},
        "scale_ppm": {"x": -451.7, "y": 287.0},
        "backlash": {"x": 20.0, "y": [{"at_mm": 10, "um": 5}, {"at_mm": 200, "um": 11}]},
    }
)


def stream(data: bytes, read_size=-1) -> bytes:
    s = CompensatingStream(io.BytesIO(data), PARAMS, Options())
    if read_size < 0:
        return s.read()
    out = bytearray()
    while True:  # OctoPrint's storage reads in chunks
        chunk = s.read(read_size)
        if not chunk:
            return bytes(out)
        out += chunk


def offline(data: bytes) -> bytes:
    dst = io.BytesIO()
    compensate_binary(io.BytesIO(data), dst, PARAMS, Options())
    return dst.getvalue()


def test_same_bytes_as_the_offline_engine_on_a_real_file():
    with open(os.path.join(DATA, "bambustudio-a1-hook.gcode"), "rb") as f:
        data = f.read()
    got = stream(data, 65536)
    assert got == offline(data)
    assert got.startswith(marker_line(PARAMS).encode() + b"\n")


def test_odd_endings_and_bytes():
    data = b"G28\r\nG1 X10 Y10 Z1\r\n; \xff\xfe\rG1 X20 Y5\nG2 X30 Y5 I5 J0\nG1 X1 Y1"
    assert stream(data, 7) == offline(data)
    assert stream(b"") == b"" == offline(b"")


def test_a_marked_file_passes_untouched_wherever_the_marker_is_in_the_head():
    marker = marker_line(PARAMS).encode()
    for before in (0, 3, MARKER_SCAN_LINES - 1):
        data = (
            b"; added by another preprocessor\n" * before
            + marker
            + b"\n"
            + b"G28\nG1 X10 Y100 Z1\n"
        )
        assert stream(data, 5) == data, before
    # beyond the scanned head a marker is just a comment: the file is compensated
    data = b"; pad\n" * MARKER_SCAN_LINES + marker + b"\nG28\nG1 X10 Y100 Z1\n"
    got = stream(data)
    assert got != data and got == offline(data)
