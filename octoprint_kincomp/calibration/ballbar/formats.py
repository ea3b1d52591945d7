"""Ballbar result formats KinComp reads (and the two CSV formats it writes).

1. Native time series (what the simulator and a DIY logger write)::

       # plane: XY
       # radius_mm: 100
       # feed_mm_min: 1850
       # centre: 110,110,10
       # sample_rate_hz: 500
       # feed_in_mm: 1
       # overshoot_deg: 20
       # capture_deg: 360
       # start_deg: 0
       # program_hash: 209bcee40c77
       direction,time_s,reading_mm
       ccw,0.000000,1.000412

   ``reading_mm`` is the change of bar length (positive = longer) against its zero length.
2. Angle domain (what ballbar software exports after processing): the same metadata and
   ``direction,angle_deg,deviation_um``; angle from +A towards +B (A, B = the plane's first and
   second axis: XY -> X, Y; XZ -> X, Z; YZ -> Y, Z).
3. Renishaw ``.b5r`` (XML): ``FEATURE`` elements read by ``NAME`` and unit ``DT``. Parsed
   without DTDs or entities, size-limited. Assumed conventions (Renishaw's own are not
   published): squareness has KinComp's sign; ``AF_SCALE_MISMATCH`` in um is the difference of
   the A and B radius, so ppm = um / radius_mm * 1000; POS/NEG are the +/- ends of an axis; a
   ``ZX`` plane is read as A = Z, B = X and mapped onto KinComp's XZ (A/B swapped).
4. A typed summary (the numbers of a ballbar report): JSON with the diagnostic keys of
   :mod:`analysis`, or ``key: value`` lines.

Every reader raises :class:`TraceError` with the line or field at fault; nothing else escapes.
"""

from __future__ import annotations

import io
import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

from ...core.messages import Msg

MAX_TRACE_BYTES = 64 * 1024 * 1024
MAX_ROWS = 2_000_000
MAX_XML_BYTES = 8 * 1024 * 1024
NATIVE_HEADER = "direction,time_s,reading_mm"
ANGLE_HEADER = "direction,angle_deg,deviation_um"
PLANES = ("XY", "XZ", "YZ")


class TraceError(ValueError):
    """A ballbar file cannot be used; the message names the line or field."""


@dataclass
class NativeTrace:
    meta: Dict[str, str]
    rows: List[Tuple[str, float, float]]  # (direction, time_s, reading_mm)
    kind: str = "native"

    def write(self, f) -> None:
        _write(f, self.meta, NATIVE_HEADER, ((d, f"{t:.6f}", f"{r:.7f}") for d, t, r in self.rows))

    def to_text(self) -> str:
        buf = io.StringIO()
        self.write(buf)
        return buf.getvalue()


@dataclass
class AngleTrace:
    meta: Dict[str, str]
    rows: List[Tuple[str, float, float]]  # (direction, angle_deg, deviation_um)
    kind: str = "angle"

    def write(self, f) -> None:
        _write(f, self.meta, ANGLE_HEADER, ((d, f"{a:.4f}", f"{v:.4f}") for d, a, v in self.rows))

    def to_text(self) -> str:
        buf = io.StringIO()
        self.write(buf)
        return buf.getvalue()


@dataclass
class Summary:
    """Diagnostics without a trace (.b5r or typed numbers); keys as in analysis output."""

    meta: Dict[str, str]
    diagnostics: Dict[str, object]
    kind: str = "summary"
    notes: List[str] = field(default_factory=list)


def _write(f, meta, header, rows) -> None:
    for k, v in meta.items():
        f.write(f"# {k}: {v}\n")
    f.write(header + "\n")
    for row in rows:
        f.write(",".join(row) + "\n")


# ---------------------------------------------------------------------------------------
# metadata helpers


def meta_float(meta: Dict[str, str], key: str, default: Optional[float] = None) -> float:
    if key not in meta:
        if default is None:
            raise TraceError(Msg("metadata '%(key)s' is missing", key=key))
        return default
    try:
        v = float(meta[key])
    except ValueError:
        raise TraceError(
            Msg("metadata '%(key)s': %(value)s is not a number", key=key, value=repr(meta[key]))
        ) from None
    if not math.isfinite(v):
        raise TraceError(Msg("metadata '%(key)s' must be finite", key=key))
    return v


def meta_plane(meta: Dict[str, str]) -> str:
    plane = meta.get("plane", "").strip().upper()
    if plane == "ZX":
        plane = "XZ"
    if plane not in PLANES:
        raise TraceError(
            Msg(
                "metadata 'plane' must be one of %(choices)s, got %(plane)s",
                choices=", ".join(PLANES),
                plane=repr(meta.get("plane")),
            )
        )
    return plane


def meta_centre(meta: Dict[str, str]) -> Optional[Tuple[float, float, float]]:
    if "centre" not in meta:
        return None
    try:
        c = tuple(float(v) for v in meta["centre"].split(","))
    except ValueError:
        raise TraceError(
            Msg("metadata 'centre': %(value)s is not X,Y,Z", value=repr(meta["centre"]))
        ) from None
    if len(c) != 3 or not all(math.isfinite(v) for v in c):
        raise TraceError(Msg("metadata 'centre' needs three finite numbers X,Y,Z"))
    return c


# ---------------------------------------------------------------------------------------
# CSV traces


def parse_csv_trace(text: str):
    """Parse a native or angle-domain CSV trace (format chosen by its header line)."""
    if len(text) > MAX_TRACE_BYTES:
        raise TraceError(Msg("trace is larger than %(mb)s MB", mb=MAX_TRACE_BYTES // (1024 * 1024)))
    meta: Dict[str, str] = {}
    header = None
    rows: List[Tuple[str, float, float]] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            body = line[1:].strip()
            if ":" in body:
                k, v = body.split(":", 1)
                k = k.strip()
                if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", k):
                    raise TraceError(
                        Msg("line %(line)s: bad metadata key %(key)s", line=lineno, key=repr(k))
                    )
                meta[k] = v.strip()
            continue
        if header is None:
            norm = line.replace(" ", "").lower()
            if norm not in (NATIVE_HEADER, ANGLE_HEADER):
                raise TraceError(
                    Msg(
                        "line %(line)s: expected the header '%(native)s' or '%(angle)s', got "
                        "%(got)s",
                        line=lineno,
                        native=NATIVE_HEADER,
                        angle=ANGLE_HEADER,
                        got=repr(line[:60]),
                    )
                )
            header = norm
            continue
        parts = line.split(",")
        if len(parts) != 3:
            raise TraceError(
                Msg(
                    "line %(line)s: expected 3 comma-separated fields, got %(n)s",
                    line=lineno,
                    n=len(parts),
                )
            )
        d = parts[0].strip().lower()
        if d not in ("cw", "ccw"):
            raise TraceError(
                Msg(
                    "line %(line)s: direction must be 'cw' or 'ccw', got %(got)s",
                    line=lineno,
                    got=repr(parts[0]),
                )
            )
        try:
            a, b = float(parts[1]), float(parts[2])
        except ValueError:
            raise TraceError(
                Msg("line %(line)s: not a number in %(text)s", line=lineno, text=repr(line[:60]))
            ) from None
        if not (math.isfinite(a) and math.isfinite(b)):
            raise TraceError(Msg("line %(line)s: NaN or infinite value", line=lineno))
        rows.append((d, a, b))
        if len(rows) > MAX_ROWS:
            raise TraceError(Msg("more than %(n)s samples", n=MAX_ROWS))
    if header is None:
        raise TraceError(
            Msg(
                "no header line (direction,time_s,reading_mm or "
                "direction,angle_deg,deviation_um) found"
            )
        )
    if not rows:
        raise TraceError(Msg("the trace has no samples"))
    meta_plane(meta)
    meta_float(meta, "radius_mm")
    if header == NATIVE_HEADER:
        for key in ("feed_mm_min", "feed_in_mm", "overshoot_deg", "capture_deg"):
            meta_float(meta, key)
        return NativeTrace(meta=meta, rows=rows)
    return AngleTrace(meta=meta, rows=rows)


# ---------------------------------------------------------------------------------------
# Renishaw .b5r


_B5R_NAMES = {
    "AF_SQUARENESS": ("squareness_um_per_m", None),
    "AF_SCALE_MISMATCH": ("scale_mismatch", None),
    "AF_SERVO_MISMATCH": ("servo_mismatch_ms", None),
    "AF_CIRCULARITY": ("circularity_um", "bidirectional"),
    "AF_STRAIGHTNESS_A": ("straightness_um", "a"),
    "AF_STRAIGHTNESS_B": ("straightness_um", "b"),
    "AF_CYCLIC_ERROR_A_FWD": ("cyclic_error_um", "a"),
    "AF_CYCLIC_ERROR_B_FWD": ("cyclic_error_um", "b"),
}
for _axis in ("A", "B"):
    for _side, _key in (("POS", "plus"), ("NEG", "minus")):
        _B5R_NAMES[f"AF_BACKLASH_{_axis}_{_side}"] = ("backlash_um", f"{_axis.lower()}_{_key}")
        _B5R_NAMES[f"AF_LATERAL_PLAY_{_axis}_{_side}"] = (
            "lateral_play_um",
            f"{_axis.lower()}_{_key}",
        )
        _B5R_NAMES[f"AF_REVERSAL_SPIKES_{_axis}_{_side}"] = (
            "reversal_spikes_um",
            f"{_axis.lower()}_{_key}",
        )

_UNIT_TO = {  # DT -> (kind, factor to KinComp's unit)
    "UT_LENGTH_UM": ("length", 1.0),
    "UT_LENGTH_MM": ("length", 1000.0),
    "UT_LENGTH_M": ("length", 1e6),
    "UT_SQUARENESS": ("squareness", 1.0),
    "UT_SERVO_MISMATCH": ("time", 1.0),
    "UT_SCALE_ERROR": ("ppm", 1.0),
    "UT_PERCENT": ("percent", 1.0),
    "UT_RANKING": ("percent", 1.0),
}


def parse_b5r(data: bytes, radius_mm: Optional[float] = None) -> Summary:
    """Read the diagnostics of a Renishaw ``.b5r`` XML file (no DTDs, no entities)."""
    root = _b5r_root(data)
    meta: Dict[str, str] = {"source": ".b5r (Renishaw)"}
    plane_el = root.find(".//PLANE")
    raw_plane = (plane_el.get("TEST_PLANE") if plane_el is not None else None) or ""
    raw_plane = raw_plane.strip().upper()
    swap = raw_plane == "ZX"
    if raw_plane not in ("XY", "YZ", "ZX", "XZ"):
        raise TraceError(
            Msg(".b5r: PLANE/@TEST_PLANE must be XY, YZ or ZX, got %(got)s", got=repr(raw_plane))
        )
    meta["plane"] = "XZ" if raw_plane in ("ZX", "XZ") else raw_plane
    spec = root.find(".//TEST_SPEC")
    if spec is not None and spec.get("NAME"):
        meta["test_name"] = spec.get("NAME")[:200]
        m = re.search(r"(\d+(?:\.\d+)?)\s*mm", spec.get("NAME"))
        if m and radius_mm is None and 0.0 < float(m.group(1)) < math.inf:
            # free text: "0mm" (or 400 digits) is no radius; the um -> ppm conversion
            # below divides by it
            radius_mm = float(m.group(1))
    if radius_mm is not None:
        meta["radius_mm"] = f"{radius_mm:g}"
    diag: Dict[str, object] = {}
    notes = []
    for feat in root.iter("FEATURE"):
        name = (feat.get("NAME") or "").strip()
        if name in _B5R_NAMES:
            _b5r_feature(feat, name, radius_mm, diag, notes)
    if not diag:
        raise TraceError(Msg(".b5r: no known FEATURE diagnostics found"))
    if swap:
        _swap_ab(diag)
        notes.append(Msg("ZX plane read as A=Z, B=X and mapped to XZ (A/B swapped)"))
    return Summary(meta=meta, diagnostics=diag, notes=notes)


def _b5r_root(data: bytes):
    """The XML root of a ``.b5r`` file, refused (:class:`TraceError`) when it is too large,
    declares a DTD or entities, is not text XML or not well-formed."""
    if len(data) > MAX_XML_BYTES:
        raise TraceError(
            Msg(".b5r file is larger than %(mb)s MB", mb=MAX_XML_BYTES // (1024 * 1024))
        )
    head = data[:4096].lower()
    if b"<!doctype" in data.lower() or b"<!entity" in data.lower():
        raise TraceError(Msg(".b5r file contains a DTD or entity declarations; refused for safety"))
    if b"\x00" in head:
        raise TraceError(
            Msg(".b5r file is not text XML (binary or UTF-16 files are not supported)")
        )
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise TraceError(Msg(".b5r is not well-formed XML: %(error)s", error=str(exc))) from None
    except (LookupError, ValueError) as exc:
        # expat raises these (not ParseError) for an XML declaration naming an unknown
        # codec (LookupError) or a multi-byte one such as utf-7 (ValueError)
        raise TraceError(
            Msg(".b5r: unsupported XML encoding (%(error)s)", error=str(exc))
        ) from None


def _b5r_feature(feat, name: str, radius_mm: Optional[float], diag: dict, notes: list) -> None:
    """One known FEATURE of a ``.b5r`` file into ``diag`` (lengths in um, scale mismatch in
    ppm: a length over the test radius ``radius_mm`` converted, said in ``notes``)."""
    dt = (feat.get("DT") or "").strip()
    text = (feat.text or "").strip()
    try:
        value = float(text)
    except ValueError:
        raise TraceError(
            Msg(
                ".b5r: FEATURE %(name)s has a non-numeric value %(value)s",
                name=name,
                value=repr(text[:30]),
            )
        ) from None
    if not math.isfinite(value):
        raise TraceError(Msg(".b5r: FEATURE %(name)s is not finite", name=name))
    key, sub = _B5R_NAMES[name]
    kind, factor = _UNIT_TO.get(dt, (None, 1.0))
    if key == "scale_mismatch":
        diag["scale_mismatch_ppm"] = _b5r_mismatch_ppm(
            name, value, dt, kind, factor, radius_mm, notes
        )
        return
    if kind == "length":
        value *= factor
        if not math.isfinite(value):  # e.g. 1e308 mm in um
            raise TraceError(Msg(".b5r: FEATURE %(name)s is out of range", name=name))
    elif kind is None:
        raise TraceError(
            Msg(".b5r: FEATURE %(name)s has an unknown unit %(unit)s", name=name, unit=repr(dt))
        )
    if sub is None:
        diag[key] = value
    else:
        diag.setdefault(key, {})[sub] = value


def _b5r_mismatch_ppm(name, value, dt, kind, factor, radius_mm, notes) -> float:
    """A ``.b5r`` scale mismatch in ppm (given in ppm, or as a length over the radius)."""
    if kind == "ppm":
        ppm = value
    elif kind == "length":
        if radius_mm is None or not 0.0 < radius_mm < math.inf:
            raise TraceError(
                Msg(
                    ".b5r: scale mismatch given in µm but the test radius "
                    "is unknown; give the radius"
                )
            )
        ppm = value * factor / radius_mm * 1000.0
        notes.append(
            Msg("scale mismatch converted from µm to ppm assuming µm over the test radius")
        )
    else:
        raise TraceError(
            Msg(
                ".b5r: FEATURE %(name)s has an unexpected unit %(unit)s",
                name=name,
                unit=repr(dt),
            )
        )
    if not math.isfinite(ppm):  # a finite value can overflow in the conversion
        raise TraceError(Msg(".b5r: FEATURE %(name)s is out of range", name=name))
    return ppm


def _swap_ab(diag: Dict[str, object]) -> None:
    for key, val in list(diag.items()):
        if isinstance(val, dict):
            swapped = {}
            for k, v in val.items():
                if k.startswith("a"):
                    swapped["b" + k[1:]] = v
                elif k.startswith("b"):
                    swapped["a" + k[1:]] = v
                else:
                    swapped[k] = v
            diag[key] = swapped
    for key in ("scale_mismatch_ppm", "servo_mismatch_ms"):
        if key in diag:
            diag[key] = -diag[key]


# ---------------------------------------------------------------------------------------
# typed summary

SUMMARY_NUMBER_KEYS = (
    "squareness_um_per_m",
    "scale_mismatch_ppm",
    "servo_mismatch_ms",
    "radius_mm",
    "feed_mm_min",
)
SUMMARY_GROUPS = {
    "backlash_um": ("a_plus", "a_minus", "b_plus", "b_minus"),
    "circularity_um": ("cw", "ccw", "bidirectional"),
}


def parse_summary(data) -> Summary:
    """A typed report summary: a dict/JSON text, or ``key: value`` lines.

    Keys: ``plane`` (required), ``radius_mm``, ``centre`` ("x,y,z" or list), ``feed_mm_min``,
    ``squareness_um_per_m``, ``scale_mismatch_ppm``, ``servo_mismatch_ms``, ``backlash_um``
    {a_plus, a_minus, b_plus, b_minus} (or flat ``backlash_a_plus`` ...), ``circularity_um``.
    """
    if isinstance(data, (bytes, str)):
        text = data.decode("utf-8", "replace") if isinstance(data, bytes) else data
        if len(text) > 100_000:
            raise TraceError(Msg("summary is too long"))
        try:
            obj = json.loads(text)
        except RecursionError:  # "[[[[..." nested deeper than the interpreter's stack
            raise TraceError(Msg("summary JSON is nested too deeply")) from None
        except json.JSONDecodeError:
            obj = {}
            for lineno, raw in enumerate(text.splitlines(), 1):
                line = raw.split("#", 1)[0].strip()
                if not line:
                    continue
                if ":" not in line and "=" not in line:
                    raise TraceError(
                        Msg(
                            "KinComp cannot read this file: it is not a ballbar trace (a CSV "
                            "file whose first line names its columns, direction,time_s,"
                            "reading_mm or direction,angle_deg,deviation_um), not a Renishaw "
                            ".b5r file, and not a report summary either (its line %(line)s is "
                            "not a 'name: value' line).",
                            line=lineno,
                        )
                    ) from None
                k, v = re.split(r"[:=]", line, maxsplit=1)
                obj[k.strip()] = v.strip()
        except ValueError as exc:
            # valid JSON syntax that json still refuses (an integer of more than 4300
            # digits); JSONDecodeError, a ValueError too, is handled above
            raise TraceError(
                Msg("summary JSON cannot be read: %(error)s", error=str(exc)[:80])
            ) from None
    else:
        obj = data
    if not isinstance(obj, dict):
        raise TraceError(Msg("summary must be an object of key: value pairs"))
    meta: Dict[str, str] = {"source": "typed summary"}
    diag: Dict[str, object] = {}
    flat = dict(obj)
    for group, subs in SUMMARY_GROUPS.items():
        g = flat.pop(group, None)
        if g is not None:
            if not isinstance(g, dict):
                raise TraceError(Msg("summary field '%(field)s' must be an object", field=group))
            for k in g:
                if k not in subs:
                    raise TraceError(
                        Msg("summary field '%(field)s' is unknown", field=f"{group}.{k}")
                    )
            for k, v in g.items():
                flat[f"{group.rsplit('_', 1)[0]}_{k}"] = v
    for key, raw in flat.items():
        if key == "plane":
            meta["plane"] = str(raw)
            continue
        if key == "centre":
            meta["centre"] = ",".join(str(v) for v in raw) if isinstance(raw, list) else str(raw)
            continue
        value = _num(raw, key)
        if key in ("radius_mm", "feed_mm_min"):
            meta[key] = f"{value:g}"
            continue
        if key in SUMMARY_NUMBER_KEYS:
            diag[key] = value
            continue
        for group, subs in SUMMARY_GROUPS.items():
            prefix = group.rsplit("_", 1)[0] + "_"
            if key.startswith(prefix) and key[len(prefix) :] in subs:
                diag.setdefault(group, {})[key[len(prefix) :]] = value
                break
        else:
            raise TraceError(Msg("summary field '%(field)s' is unknown", field=key))
    meta["plane"] = meta_plane(meta)
    meta_centre(meta)
    if not diag:
        raise TraceError(Msg("summary has no diagnostic values"))
    if "backlash_um" in diag:
        for k, v in diag["backlash_um"].items():
            if v < 0:
                raise TraceError(
                    Msg("summary field '%(field)s' must be at least 0", field=f"backlash_um.{k}")
                )
    return Summary(meta=meta, diagnostics=diag)


def _num(raw, key) -> float:
    if isinstance(raw, bool):
        raise TraceError(Msg("summary field '%(field)s' must be a number", field=key))
    try:
        v = float(raw)
    except (TypeError, ValueError, OverflowError):  # OverflowError: a JSON int >= 1e309
        raise TraceError(
            Msg(
                "summary field '%(field)s': %(value)s is not a number",
                field=key,
                value=repr(str(raw)[:30]),
            )
        ) from None
    if not math.isfinite(v):
        raise TraceError(Msg("summary field '%(field)s' must be finite", field=key))
    return v


def load_any(data: bytes, filename: str = ""):
    """Pick the reader from the content: XML -> .b5r, CSV header -> trace, else summary."""
    if len(data) > MAX_TRACE_BYTES:
        # before any copy: decoding, stripping and lower-casing would each copy it
        raise TraceError(Msg("file is larger than %(mb)s MB", mb=MAX_TRACE_BYTES // (1024 * 1024)))
    stripped = data.lstrip()
    if stripped.startswith(b"<") or filename.lower().endswith(".b5r"):
        return parse_b5r(data)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise TraceError(Msg("file is not UTF-8 text (nor .b5r XML)")) from None
    if (
        NATIVE_HEADER in text.replace(" ", "").lower()
        or ANGLE_HEADER in text.replace(" ", "").lower()
    ):
        return parse_csv_trace(text)
    return parse_summary(text)
