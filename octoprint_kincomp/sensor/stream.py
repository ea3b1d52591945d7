"""A captured stream as it came from the sensor, and the native trace made from it.

:class:`RawStream` is what a capture keeps (also when it fails, for inspection): metadata
lines and ``time_s,reading_mm,line`` rows (time in s from the first sample, on the device's
clock or the host's arrival clock as ``timing`` says; reading in mm, positive = bar longer;
``line``: the line number in the sensor's stream, for re-timing host-stamped samples)::

    # kind: ballbar raw stream
    # timing: host arrival
    # sensor_protocol: plain
    time_s,reading_mm,line
    0.000000,1.0004120,17

:func:`trace_from_stream` re-times host-stamped samples (:mod:`.retime`), finds the runs
(:mod:`.run_detection`) and returns the ``calibration/ballbar/formats.py`` :class:`NativeTrace` the
analysis reads (rows ``direction,time_s,reading_mm``, the program's metadata plus the sensor's). The
same function serves the live capture and an offline re-run of a saved raw stream, so both give the
same trace.
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from ..calibration.ballbar.formats import NativeTrace, TraceError
from ..calibration.ballbar.program import TestSpec
from ..core.messages import Msg
from .retime import retime
from .run_detection import Detection, detect_runs, explain_failure
from .sensor_error import SensorError

RAW_HEADER = "time_s,reading_mm,line"
RAW_KIND = "ballbar raw stream"
MAX_RAW_BYTES = 128 * 1024 * 1024
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def clean_meta(meta: Dict[str, object]) -> Dict[str, str]:
    """Metadata safe for ``# key: value`` lines (valid keys, one printable line per value)."""
    out = {}
    for k, v in meta.items():
        if v is None or not _KEY.fullmatch(str(k)):
            continue
        if isinstance(v, float):
            v = f"{v:.6g}"
        text = "".join(c if 32 <= ord(c) < 127 else " " for c in str(v)).strip()
        out[str(k)] = text[:200]
    return out


@dataclass
class RawStream:
    meta: Dict[str, str]
    t: np.ndarray  # s from the first sample
    mm: np.ndarray  # bar length change, mm, + = longer
    line: np.ndarray  # line number in the sensor's stream
    notes: list = field(default_factory=list)

    @property
    def host_timed(self) -> bool:
        return self.meta.get("timing") == "host arrival"

    def __len__(self) -> int:
        return len(self.t)

    def to_text(self) -> str:
        buf = io.StringIO()
        meta = dict(self.meta)
        meta["kind"] = RAW_KIND
        for k, v in clean_meta(meta).items():
            buf.write(f"# {k}: {v}\n")
        buf.write(RAW_HEADER + "\n")
        for t, r, n in zip(self.t.tolist(), self.mm.tolist(), self.line.tolist()):
            buf.write(f"{t:.6f},{r:.7f},{int(n)}\n")
        return buf.getvalue()


def parse_raw_stream(text: str) -> RawStream:
    """Read :meth:`RawStream.to_text` back; raises TraceError naming the line at fault."""
    if len(text) > MAX_RAW_BYTES:
        raise TraceError(
            Msg("raw stream is larger than %(mb)s MB", mb=MAX_RAW_BYTES // (1024 * 1024))
        )
    meta: Dict[str, str] = {}
    rows = []
    header = False
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if ":" in line:
                k, v = line[1:].split(":", 1)
                meta[k.strip()] = v.strip()
            continue
        if not header:
            if line.replace(" ", "") != RAW_HEADER:
                raise TraceError(
                    Msg(
                        "line %(line)s: expected the header '%(header)s'",
                        line=lineno,
                        header=RAW_HEADER,
                    )
                )
            header = True
            continue
        parts = line.split(",")
        try:
            row = (float(parts[0]), float(parts[1]), int(parts[2]))
        except (ValueError, IndexError):
            raise TraceError(
                Msg("line %(line)s: expected time_s,reading_mm,line", line=lineno)
            ) from None
        if not (math.isfinite(row[0]) and math.isfinite(row[1])):
            raise TraceError(Msg("line %(line)s: NaN or infinite value", line=lineno))
        rows.append(row)
    if not header:
        raise TraceError(Msg("not a ballbar raw stream (no '%(header)s' line)", header=RAW_HEADER))
    arr = np.array(rows, dtype=float).reshape(-1, 3)
    meta.pop("kind", None)
    return RawStream(meta, arr[:, 0], arr[:, 1], arr[:, 2].astype(np.int64))


def stream_times(
    stream: RawStream, rate_hz: Optional[float] = None
) -> Tuple[np.ndarray, Dict[str, object]]:
    """The sample times to use (s): the device's own, or host arrival re-timed."""
    if not stream.host_timed:
        return stream.t, {}
    return retime(stream.line, stream.t, rate_hz)


def trace_from_stream(
    stream: RawStream, spec: TestSpec, program_hash: str = "", rate_hz: Optional[float] = None
) -> Tuple[NativeTrace, Detection]:
    """The native trace of the runs in ``stream``; SensorError saying why if they are not
    all there. ``rate_hz``: the device's declared rate for re-timing (else fitted)."""
    t, timing = stream_times(stream, rate_hz)
    r = stream.mm
    det = detect_runs(t, r, spec)
    if not det.complete:
        raise SensorError(explain_failure(t, r, spec, det) or Msg("no runs found"))
    t_ref = det.t_ref = float(t[det.runs[0].i0])
    rows = []
    for run in det.runs:
        rows.extend(
            (run.direction, tt - t_ref, rr)
            for tt, rr in zip(t[run.i0 : run.i1].tolist(), r[run.i0 : run.i1].tolist())
        )
    n = det.runs[-1].i1 - det.runs[0].i0
    span = float(t[det.runs[-1].i1 - 1] - t_ref)
    meta = dict(spec.metadata())
    meta.update(clean_meta(stream.meta))
    meta.update(clean_meta(timing))
    if span > 0:
        meta["sample_rate_hz"] = f"{(n - 1) / span:.6g}"
    meta["program_hash"] = program_hash
    meta.update({f"run_{run.direction}_feed_in_s": f"{run.t_in - t_ref:.4f}" for run in det.runs})
    meta.update({f"run_{run.direction}_feed_out_s": f"{run.t_out - t_ref:.4f}" for run in det.runs})
    return NativeTrace(meta=meta, rows=rows), det
