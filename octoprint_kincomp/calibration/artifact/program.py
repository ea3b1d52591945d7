"""The printed calibration artifact: a G-code program KinComp writes itself (no slicer).

The artifact is a set of thin printed walls ("fins") in pairs. Each pair is one *feature*: two
parallel walls whose centre planes are ``L`` mm apart along the unit direction ``n``. A caliper
measures each feature twice: **outside** (the outer jaws on the outer faces; the reading is
``L`` plus one wall thickness) and **inside** (the inner jaws on the facing faces; ``L`` minus
one wall thickness), so the printed line width cancels in the analysis
(:mod:`.fit`).

* **XY part** (flat, 5 mm tall walls spread over the bed): two spans along X, two along Y and
  five diagonals each way at 45 deg (``A``: towards +X+Y, ``B``: towards +X-Y). The diagonals
  carry the XY squareness (a positive ``xy`` makes the ``A`` diagonals long, the ``B`` ones
  short), the X and Y spans the X-Y scale mismatch.
* **XZ and YZ towers** (in lanes at the back and at the right of the bed): two walls leaning at
  45 deg, the measuring direction ``n`` at 45 deg in the plane, one tower per sign of the
  diagonal. Their readings carry ``xz`` (``yz``) and, against the X (Y) spans, the scale
  mismatch with Z.

The measurement contract is the program's header, one comment per measurement::

    ; kincomp measure: id=<ID> kind=<outside|inside> from=<X>,<Y>,<Z> to=<X>,<Y>,<Z> hint=<text>

``from``/``to`` are the nominal points (mm, machine frame) on the centre planes of the two walls
the jaws touch; ``to - from`` is ``L * n``. Read it back with :func:`read_measurements`.

The program heats (bed, then nozzle), homes, prints layer by layer with relative extrusion,
retracts and lifts on travel, and ends like a slicer's file (heaters and fan off, head lifted,
motors off). All lengths mm, temperatures deg C, feeds mm/min.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple, Union

from ...core.messages import Msg

Vec = Tuple[float, float, float]
PLANES = ("XY", "XZ", "YZ")
KINDS = ("outside", "inside")
MODES = ("full", "quick")  # the whole artifact, or its few measurements (12 readings)
HEADER = "; kincomp artifact program"
MEASURE_PREFIX = "; kincomp measure:"
FILAMENT_MM = 1.75
_FILAMENT_AREA = math.pi * (FILAMENT_MM / 2) ** 2  # mm^2

_MEASURE_RE = re.compile(
    r"^;\s*kincomp measure:\s*id=(?P<id>[A-Za-z0-9_.-]+)\s+kind=(?P<kind>\S+)\s+"
    r"from=(?P<from>\S+)\s+to=(?P<to>\S+)(?:\s+hint=(?P<hint>.*))?$"
)


class ArtifactProgramError(ValueError):
    """The artifact cannot be made as asked (does not fit, bad values) or a program's
    measurement header is malformed."""


@dataclass(frozen=True)
class ArtifactSpec:
    """What the user chooses. ``volume`` = (X0, X1, Y0, Y1, Z0, Z1), mm, machine frame."""

    volume: Tuple[float, float, float, float, float, float] = (0.0, 220.0, 0.0, 220.0, 0.0, 250.0)
    planes: Tuple[str, ...] = PLANES
    nozzle_mm: float = 0.4
    hotend_c: float = 210.0
    bed_c: float = 60.0
    first_layer_mm: float = 0.2
    layer_mm: Optional[float] = None  # default: min(0.2, nozzle / 2)
    line_width_mm: Optional[float] = None  # default: 1.125 * nozzle
    max_span_mm: float = 150.0  # the caliper's range: an outside reading must fit in it
    tower_span_mm: float = 100.0  # longest span of the XZ/YZ towers (sets their height)
    margin_mm: float = 10.0  # kept free along the bed's edges
    fin_length_mm: float = 10.0  # length of each wall across the measuring direction
    xy_height_mm: float = 5.0  # height of the XY walls
    print_feed: float = 2400.0
    first_layer_feed: float = 1200.0
    travel_feed: float = 6000.0
    z_feed: float = 600.0
    # "full": 2 spans along X and Y, 5 diagonals each way, two towers per vertical plane,
    # measured three times each; "quick": one diagonal each way and the four towers,
    # measured once each (12 readings in all)
    mode: str = "full"

    @property
    def repeats(self) -> int:
        """How often the program asks for each measurement to be read."""
        return 1 if self.mode == "quick" else 3

    @property
    def layer(self) -> float:
        return self.layer_mm if self.layer_mm else min(0.2, self.nozzle_mm / 2)

    @property
    def width(self) -> float:
        return self.line_width_mm if self.line_width_mm else round(1.125 * self.nozzle_mm, 3)


@dataclass(frozen=True)
class Measurement:
    """One caliper measurement of the contract. Points in mm (machine frame)."""

    id: str
    kind: str  # "outside" (wall thickness adds) or "inside" (subtracts)
    start: Vec  # ``from``: centre plane of the first wall
    end: Vec  # ``to``: centre plane of the second wall
    hint: str = ""

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    @property
    def direction(self) -> Vec:
        n = self.length
        return tuple((b - a) / n for a, b in zip(self.start, self.end))

    @property
    def sign(self) -> int:
        return 1 if self.kind == "outside" else -1

    @property
    def family(self) -> str:
        """``vertical`` walls (horizontal measuring direction) or ``slanted`` (45 deg)."""
        return "vertical" if abs(self.direction[2]) < 1e-9 else "slanted"

    @property
    def plane(self) -> str:
        """The coordinate plane the measuring direction lies in (XY, XZ, YZ; X/Y/Z alone)."""
        axes = "".join(a for a, v in zip("XYZ", self.direction) if abs(v) > 1e-9)
        return axes


@dataclass
class Feature:
    """Two parallel walls ``length`` mm apart along ``n`` (from ``start``)."""

    name: str
    plane: str
    start: Vec
    n: Vec
    length: float
    hint: str
    tops: Tuple[float, float] = (5.0, 5.0)  # top height of the first and second wall, mm
    fins: List[Fin] = field(default_factory=list)

    @property
    def end(self) -> Vec:
        return tuple(s + self.length * c for s, c in zip(self.start, self.n))


@dataclass
class Fin:
    """A wall through ``point`` with normal ``n`` from the bed up to ``top`` (mm)."""

    point: Vec
    n: Vec
    top: float
    length: float

    def centre_at(self, z: float) -> Tuple[float, float]:
        """Centre of the wall's line at height ``z`` (a 45 deg wall moves with z)."""
        nx, ny, nz = self.n
        h = math.hypot(nx, ny)
        a = -nz * (z - self.point[2]) / h
        return self.point[0] + a * nx / h, self.point[1] + a * ny / h

    def segment(self, z: float, offset: float = 0.0):
        """The wall's line at height ``z`` (``offset`` mm along the horizontal normal)."""
        nx, ny, _ = self.n
        h = math.hypot(nx, ny)
        cx, cy = self.centre_at(z)
        cx += offset * nx / h
        cy += offset * ny / h
        tx, ty = -ny / h, nx / h
        half = self.length / 2
        return (cx - half * tx, cy - half * ty), (cx + half * tx, cy + half * ty)


# ---------------------------------------------------------------------------------------
# layout


def _check_spec(spec: ArtifactSpec) -> None:
    x0, x1, y0, y1, z0, z1 = spec.volume
    if not (x1 > x0 and y1 > y0 and z1 > z0):
        raise ArtifactProgramError(
            Msg("the volume must be X0,X1,Y0,Y1,Z0,Z1 with each minimum below its maximum")
        )
    for name, v, lo, hi in (
        ("nozzle", spec.nozzle_mm, 0.1, 2.0),
        ("first layer", spec.first_layer_mm, 0.05, 1.0),
        ("layer height", spec.layer, 0.05, 1.0),
        ("line width", spec.width, 0.1, 3.0),
        ("nozzle temperature", spec.hotend_c, 150.0, 350.0),
        ("bed temperature", spec.bed_c, 0.0, 150.0),
        ("caliper range", spec.max_span_mm, 50.0, 1000.0),
        ("tower span", spec.tower_span_mm, 20.0, 1000.0),
    ):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
            raise ArtifactProgramError(
                Msg(
                    "%(name)s %(value)s is out of range (%(lo)s..%(hi)s)",
                    name=name,
                    value=f"{v:g}",
                    lo=f"{lo:g}",
                    hi=f"{hi:g}",
                )
            )
    if spec.mode not in MODES:
        raise ArtifactProgramError(
            Msg("mode must be full or quick (got %(mode)s)", mode=str(spec.mode))
        )
    bad = [p for p in spec.planes if p not in PLANES]
    if bad or not spec.planes:
        raise ArtifactProgramError(
            Msg(
                "planes must be among XY, XZ, YZ (got %(planes)s)",
                planes=",".join(spec.planes) or "none",
            )
        )


def layout(spec: ArtifactSpec) -> List[Feature]:
    """The features for ``spec`` (raises :class:`ArtifactProgramError` when they do not fit)."""
    _check_spec(spec)
    x0, x1, y0, y1, z0, z1 = spec.volume
    m = spec.margin_mm
    bx0, bx1, by0, by1 = x0 + m, x1 - m, y0 + m, y1 - m
    lane = spec.fin_length_mm + 8.0  # lane pitch of the towers
    has_xz, has_yz = "XZ" in spec.planes, "YZ" in spec.planes
    # the XY part keeps clear of the tower lanes (two at the back for XZ, two at the right)
    rx1 = bx1 - (2 * lane if has_yz else 0.0)
    ry1 = by1 - (2 * lane if has_xz else 0.0)
    if "XY" in spec.planes:
        _xy_features(spec, bx0, rx1, by0, ry1, z0)  # a bed too small for it says so first
    towers: List[Feature] = []
    if has_xz:
        towers += _tower_features(
            spec, "XZ", (bx0, rx1), (by1 - lane / 2, by1 - 1.5 * lane), z0, z1
        )
    if has_yz:
        towers += _tower_features(
            spec, "YZ", (by0, ry1), (bx1 - lane / 2, bx1 - 1.5 * lane), z0, z1
        )
    # on small beds the diagonals' ends come near the axis spans' walls: shorten the
    # diagonals (2 mm at a time) until every wall keeps its clearance
    cut = 0.0
    while True:
        feats = (
            _xy_features(spec, bx0, rx1, by0, ry1, z0, cut) if "XY" in spec.planes else []
        ) + towers
        for f in feats:
            f.fins = [
                Fin(f.start, f.n, f.tops[0], spec.fin_length_mm),
                Fin(f.end, f.n, f.tops[1], spec.fin_length_mm),
            ]
        try:
            _check_clearance(feats, spec)
            return feats
        except ArtifactProgramError:
            diagonal = next((f for f in feats if f.name[0] in "AB"), None)
            if diagonal is None or diagonal.length - 2.0 < 60.0:
                raise
            cut += 2.0


def _seg_dist(p, q, a, b) -> float:
    """Shortest distance between 2D segments pq and ab (mm)."""

    def point_seg(c, s0, s1):
        dx, dy = s1[0] - s0[0], s1[1] - s0[1]
        L2 = dx * dx + dy * dy
        t = 0.0 if L2 == 0 else max(0.0, min(1.0, ((c[0] - s0[0]) * dx + (c[1] - s0[1]) * dy) / L2))
        return math.hypot(c[0] - s0[0] - t * dx, c[1] - s0[1] - t * dy)

    def cross(o, u, v):
        return (u[0] - o[0]) * (v[1] - o[1]) - (u[1] - o[1]) * (v[0] - o[0])

    if (cross(p, q, a) * cross(p, q, b) < 0) and (cross(a, b, p) * cross(a, b, q) < 0):
        return 0.0
    return min(point_seg(p, a, b), point_seg(q, a, b), point_seg(a, p, q), point_seg(b, p, q))


def _check_clearance(feats: Sequence[Feature], spec: ArtifactSpec, need: float = 3.0) -> None:
    """Walls of different features keep ``need`` mm apart at every height (a jaw must reach
    each wall; walls that touch would merge)."""
    fins = [(i, f) for i, ft in enumerate(feats) for f in ft.fins]
    z0 = spec.volume[4]
    for a in range(len(fins)):
        for b in range(a + 1, len(fins)):
            (ia, fa), (ib, fb) = fins[a], fins[b]
            top = min(fa.top, fb.top)
            for k in range(9):
                z = z0 + (top - z0) * k / 8
                d = _seg_dist(*fa.segment(z), *fb.segment(z))
                if d < need + spec.width * 3:
                    raise ArtifactProgramError(
                        Msg(
                            "walls of %(a)s and %(b)s come too close (%(d)s mm): the volume is too "
                            "small for this artifact",
                            a=feats[ia].name,
                            b=feats[ib].name,
                            d=f"{d:.1f}",
                        )
                    )


def _xy_features(spec: ArtifactSpec, ax0, ax1, ay0, ay1, z0, cut: float = 0.0) -> List[Feature]:
    """Spans along X and Y and 45 deg diagonals (``cut`` mm shorter than they could be),
    symmetric about the region's centre; the quick artifact has one diagonal each way (the
    centre ones) and no axis spans."""
    w = spec.width
    reach = spec.fin_length_mm / 2 + 2 * w  # a wall's half length plus its foot
    side = min(ax1 - ax0, ay1 - ay0) - 2 * reach
    span = min(spec.max_span_mm - 3.0, side)
    if span < 60.0:
        raise ArtifactProgramError(
            Msg(
                "the bed is too small for the XY part (%(side)s mm "
                "free; it needs at least 60 mm spans)",
                side=f"{side:.0f}",
            )
        )
    cx, cy = (ax0 + ax1) / 2, (ay0 + ay1) / 2
    zm = z0 + spec.xy_height_mm / 2  # the walls' mid height: where the jaws go
    half = span / 2
    off = min(12.0, span / 10)  # the two X (Y) spans lie this far either side of the centre
    pitch = spec.fin_length_mm + 3.5 + 3 * w  # walls side by side keep the clearance
    # five diagonals each way (quick: the centre one)
    shifts = tuple(k * pitch for k in ((0,) if spec.mode == "quick" else (-2, -1, 0, 1, 2)))
    r = 1 / math.sqrt(2)
    # diagonal: as long as the caliper takes and the shifted ends stay within the spans
    diag = min(spec.max_span_mm - 3.0, 2 * math.sqrt(2) * (half - max(shifts) * r)) - cut
    h = diag / (2 * math.sqrt(2))
    feats: List[Feature] = []
    top = (z0 + spec.xy_height_mm,) * 2
    for i, s in enumerate(() if spec.mode == "quick" else (-off, off), 1):
        feats.append(
            Feature(
                f"X{i}",
                "XY",
                (cx - half, cy + s, zm),
                (1.0, 0.0, 0.0),
                span,
                "walls across X, " + ("front" if i == 1 else "back"),
                top,
            )
        )
    for i, s in enumerate(() if spec.mode == "quick" else (-off, off), 1):
        feats.append(
            Feature(
                f"Y{i}",
                "XY",
                (cx + s, cy - half, zm),
                (0.0, 1.0, 0.0),
                span,
                "walls across Y, " + ("left" if i == 1 else "right"),
                top,
            )
        )
    for i, s in enumerate(shifts, 1):  # A: towards +X+Y, shifted along (-1, 1)
        start = (cx - h - s * r, cy - h + s * r, zm)
        feats.append(
            Feature(
                f"A{i}",
                "XY",
                start,
                (r, r, 0.0),
                diag,
                "diagonal walls front-left to back-right",
                top,
            )
        )
    for i, s in enumerate(shifts, 1):  # B: towards +X-Y, shifted along (1, 1)
        start = (cx - h + s * r, cy + h + s * r, zm)
        feats.append(
            Feature(
                f"B{i}",
                "XY",
                start,
                (r, -r, 0.0),
                diag,
                "diagonal walls back-left to front-right",
                top,
            )
        )
    return feats


def _tower_features(
    spec: ArtifactSpec,
    plane: str,
    along: Tuple[float, float],
    lanes: Tuple[float, float],
    z0: float,
    z1: float,
) -> List[Feature]:
    """One 45 deg tower per lane: the first leans one way, the second the other."""
    low = 8.0  # height of the first wall's measuring point above the bed (jaw clearance)
    above = 5.0  # each wall rises this far above its measuring point
    lo, hi = along
    room = hi - lo - 2 * spec.width
    r = 1 / math.sqrt(2)
    span = min(
        spec.tower_span_mm,
        spec.max_span_mm - 3.0,
        (room - low - above) / math.sqrt(2),
        (z1 - z0 - low - above - 1.0) / r,
    )
    if span < 30.0:
        raise ArtifactProgramError(
            Msg(
                "no room for the %(plane)s towers (span %(span)s mm; they need 30 mm)",
                plane=plane,
                span=f"{span:.0f}",
            )
        )
    k = 0 if plane == "XZ" else 1  # the horizontal axis of the plane
    feats = []
    for i, (sign, c) in enumerate(((1.0, lanes[0]), (-1.0, lanes[1])), 1):
        n = [0.0, 0.0, r]
        n[k] = sign * r
        # footprint along the axis: [start - above, start + low + sqrt2*span] (mirrored for -)
        a = lo + above if sign > 0 else hi - above
        start = [0.0, 0.0, z0 + low]
        start[k] = a
        start[1 - k] = c
        tops = (z0 + low + above, z0 + low + span * r + above)
        lean = ("-" if sign > 0 else "+") + "XYZ"[k]
        feats.append(
            Feature(
                f"{plane}{i}",
                plane,
                tuple(start),
                tuple(n),
                span,
                f"45 deg tower in {plane} leaning towards {lean}",
                tops,
            )
        )
    return feats


# ---------------------------------------------------------------------------------------
# measurements (the header contract)


def measurements(features: Sequence[Feature]) -> List[Measurement]:
    out = []
    for f in features:
        for kind in KINDS:
            if f.plane == "XY":
                hint = (
                    f"{f.hint}: outer jaws on the outer faces of both walls"
                    if kind == "outside"
                    else f"{f.hint}: inner jaws on the facing faces of both walls"
                )
            else:
                hint = (
                    f"{f.hint}: caliper along the 45 deg line, outer jaws on the low face of "
                    "the short wall and the top face of the tall wall"
                    if kind == "outside"
                    else f"{f.hint}: inner jaws between the two leaning walls, square to them"
                )
            out.append(
                Measurement(
                    f"{f.name}-{'out' if kind == 'outside' else 'in'}", kind, f.start, f.end, hint
                )
            )
    return out


# The header's hints (plain ASCII English: the measuring contract in the G-code) in the
# user's words and language for the web UI: each part KinComp writes, as a message.
_HINT_PARTS = {
    m.template.replace("°", " deg"): m  # (keyed by the header's ASCII: "45 deg")
    for m in (
        Msg("walls across X, front"),
        Msg("walls across X, back"),
        Msg("walls across Y, left"),
        Msg("walls across Y, right"),
        Msg("diagonal walls front-left to back-right"),
        Msg("diagonal walls back-left to front-right"),
        Msg("outer jaws on the outer faces of both walls"),
        Msg("inner jaws on the facing faces of both walls"),
        Msg(
            "caliper along the 45° line, outer jaws on the low face of the short wall and the "
            "top face of the tall wall"
        ),
        Msg("inner jaws between the two leaning walls, square to them"),
    )
}
_TOWER = re.compile(r"^45 deg tower in (XZ|YZ) leaning towards ([+-][XYZ])$")


def hint_words(hint: str) -> Union[Msg, str]:
    """A measurement's header hint as a message for the web UI (``where: how``, each part
    KinComp writes translated); a hint it does not know (a hand-edited header) as it is."""
    parts = []
    for part in hint.split(": ", 1):
        tower = _TOWER.match(part)
        if tower:
            parts.append(
                Msg(
                    "45° tower in %(plane)s leaning towards %(lean)s",
                    plane=tower.group(1),
                    lean=tower.group(2),
                )
            )
        elif part in _HINT_PARTS:
            parts.append(_HINT_PARTS[part])
        else:
            return hint
    if len(parts) == 1:
        return parts[0]
    return Msg("%(where)s: %(how)s", where=parts[0], how=parts[1])


def _pt(p: Sequence[float]) -> str:
    return ",".join(f"{v:.4f}" for v in p)


def measure_line(m: Measurement) -> str:
    return (
        f"{MEASURE_PREFIX} id={m.id} kind={m.kind} from={_pt(m.start)} to={_pt(m.end)} "
        f"hint={m.hint}"
    )


def read_measurements(text: str) -> List[Measurement]:
    """The measurement contract of a program (its ``; kincomp measure:`` lines)."""
    out: List[Measurement] = []
    seen = set()
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.lstrip().lower().startswith(MEASURE_PREFIX):
            continue
        mt = _MEASURE_RE.match(line.strip())
        if not mt:
            raise ArtifactProgramError(
                Msg(
                    "line %(line)s: malformed measurement (expected "
                    "id=, kind=, from=X,Y,Z, to=X,Y,Z, hint=)",
                    line=lineno,
                )
            )
        try:
            start = tuple(float(v) for v in mt["from"].split(","))
            end = tuple(float(v) for v in mt["to"].split(","))
        except ValueError:
            start = end = ()
        if len(start) != 3 or len(end) != 3 or not all(map(math.isfinite, start + end)):
            raise ArtifactProgramError(
                Msg("line %(line)s: from= and to= need three numbers each (mm)", line=lineno)
            )
        if mt["kind"] not in KINDS:
            raise ArtifactProgramError(
                Msg(
                    "line %(line)s: kind must be outside or inside, not %(kind)s",
                    line=lineno,
                    kind=mt["kind"],
                )
            )
        if math.dist(start, end) < 1.0:
            raise ArtifactProgramError(
                Msg("line %(line)s: from and to are less than 1 mm apart", line=lineno)
            )
        if mt["id"] in seen:
            raise ArtifactProgramError(
                Msg("line %(line)s: measurement id %(id)s appears twice", line=lineno, id=mt["id"])
            )
        seen.add(mt["id"])
        out.append(Measurement(mt["id"], mt["kind"], start, end, (mt["hint"] or "").strip()))
    if not out:
        raise ArtifactProgramError(
            Msg(
                "the program has no '; kincomp measure:' lines: it is "
                "not a KinComp artifact program"
            )
        )
    return out


def read_program_info(text: str) -> Dict[str, str]:
    """``; kincomp artifact <key>: <value>`` lines of the header (nozzle, line width ...)."""
    info = {}
    for line in text.splitlines():
        if line.startswith("; kincomp artifact ") and ":" in line:
            key, _, value = line[len("; kincomp artifact ") :].partition(":")
            info[key.strip()] = value.strip()
    return info


# ---------------------------------------------------------------------------------------
# G-code


def _f(v: float) -> str:
    t = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if t in ("-0", "") else t


def generate(spec: ArtifactSpec, date: str = "") -> str:
    """The artifact's G-code: header (contract), start, layers, end."""
    feats = layout(spec)
    fins = [f for ft in feats for f in ft.fins]
    top = max(f.top for f in fins)
    out = _header(spec, date) + [measure_line(m) for m in measurements(feats)]
    out += _start(spec)
    pos = _prime_line(spec, out)
    _layers(spec, fins, top, pos, out)
    out += _end(spec, park_z=min(spec.volume[5], top + 10.0))
    _check_inside(out, spec)
    return "\n".join(out) + "\n"


def _header(spec: ArtifactSpec, date: str) -> List[str]:
    """The program's header: the measuring contract the analysis reads back."""
    return [
        f"{HEADER} (KinComp printed calibration artifact{', ' + date if date else ''})",
        f"; kincomp artifact planes: {','.join(p for p in PLANES if p in spec.planes)}",
        f"; kincomp artifact volume: {','.join(_f(v) for v in spec.volume)}",
        f"; kincomp artifact nozzle_mm: {_f(spec.nozzle_mm)}",
        f"; kincomp artifact line_width_mm: {_f(spec.width)}",
        f"; kincomp artifact layer_mm: {_f(spec.layer)}",
        f"; kincomp artifact first_layer_mm: {_f(spec.first_layer_mm)}",
        f"; kincomp artifact temperatures_c: {_f(spec.hotend_c)},{_f(spec.bed_c)}",
        f"; kincomp artifact max_span_mm: {_f(spec.max_span_mm)}",
        f"; kincomp artifact tower_span_mm: {_f(spec.tower_span_mm)}",
        f"; kincomp artifact mode: {spec.mode}",
        f"; kincomp artifact repeats: {spec.repeats}",
        "; Print with compensation as it will be used (or off); tell the analysis which "
        "parameters were active.",
        "; Measure every span below with calipers ("
        + ("once each" if spec.repeats == 1 else f"repeat each {spec.repeats} times")
        + "), mm, 0.01 mm resolution.",
    ]


def _start(spec: ArtifactSpec) -> List[str]:
    """Heat, home, absolute positions and relative E, the nozzle 2 mm over the bed."""
    z0 = spec.volume[4]
    return [
        "M140 S" + _f(spec.bed_c),
        "M104 S" + _f(spec.hotend_c * 0.75),
        "M190 S" + _f(spec.bed_c),
        "M104 S" + _f(spec.hotend_c),
        "G28",
        "M109 S" + _f(spec.hotend_c),
        "G90",
        "M83",
        "G92 E0",
        "M107",
        f"G1 Z{_f(z0 + 2)} F{_f(spec.z_feed)}",
    ]


def _prime_line(spec: ArtifactSpec, out: List[str]) -> Tuple[float, float]:
    """A prime line along the front edge appended to ``out``; returns where it ends (mm)."""
    x0, x1, y0, _, z0, _ = spec.volume
    h1 = spec.first_layer_mm
    px0 = x0 + spec.margin_mm / 2
    px1 = min(x1 - spec.margin_mm / 2, x0 + spec.margin_mm / 2 + 60)
    py = y0 + 3
    out.append(f"G1 X{_f(px0)} Y{_f(py)} F{_f(spec.travel_feed)}")
    out.append(f"G1 Z{_f(z0 + h1)} F{_f(spec.z_feed)}")
    e = (px1 - px0) * 1.5 * spec.width * h1 / _FILAMENT_AREA
    out.append(f"G1 X{_f(px1)} E{e:.5f} F{_f(spec.first_layer_feed)}")
    return (px1, py)


def _layers(spec: ArtifactSpec, fins, top: float, pos, out: List[str]) -> None:
    """Every layer of the walls up to ``top`` (mm) appended to ``out``, the head starting
    at ``pos``: the first two layers with a foot three lines wide."""
    z0, w, h1, h = spec.volume[4], spec.width, spec.first_layer_mm, spec.layer
    z = z0 + h1
    layer = 1
    while z <= top + 1e-9:
        lh = h1 if layer == 1 else h
        out.append(f";LAYER:{layer - 1}")
        if layer == 2:
            out.append("M106 S255")
        zmid = z - lh / 2
        offsets = (0.0, -w, w) if layer <= 2 else (0.0,)  # a foot, three lines wide
        lines = [f.segment(zmid, o) for f in fins if f.top >= z - 1e-9 for o in offsets]
        feed = spec.first_layer_feed if layer <= 1 else spec.print_feed
        pos = _print_lines(spec, lines, pos, z, lh, feed, out)
        layer += 1
        z = z0 + h1 + (layer - 1) * h


def _print_lines(spec: ArtifactSpec, lines, pos, z: float, lh: float, feed: float, out):
    """The wall ``lines`` [(a, b)] of one layer at height ``z`` (mm; layer height ``lh``)
    appended to ``out``: the nearest line next, printed from its nearer end, with a retract
    and a hop for a travel over 2 mm. Returns where the head ends."""
    z1 = spec.volume[5]
    while lines:
        best = min(
            range(len(lines)),
            key=lambda i: min(math.dist(pos, lines[i][0]), math.dist(pos, lines[i][1])),
        )
        a, b = lines.pop(best)
        if math.dist(pos, b) < math.dist(pos, a):
            a, b = b, a
        if math.dist(pos, a) > 2.0:
            out.append("G1 E-0.8 F2400")
            out.append(f"G1 Z{_f(min(z1, z + 0.4))} F{_f(spec.z_feed)}")
            out.append(f"G0 X{_f(a[0])} Y{_f(a[1])} F{_f(spec.travel_feed)}")
            out.append(f"G1 Z{_f(z)} F{_f(spec.z_feed)}")
            out.append("G1 E0.8 F2400")
        else:
            out.append(f"G1 X{_f(a[0])} Y{_f(a[1])} Z{_f(z)} F{_f(spec.travel_feed)}")
        e = math.dist(a, b) * spec.width * lh / _FILAMENT_AREA
        out.append(f"G1 X{_f(b[0])} Y{_f(b[1])} E{e:.5f} F{_f(feed)}")
        pos = b
    return pos


def _end(spec: ArtifactSpec, park_z: float) -> List[str]:
    """Retract, lift to ``park_z`` (mm), heaters and fan off, park at the back left."""
    x0, _, _, y1, _, _ = spec.volume
    return [
        "G1 E-1 F2400",
        f"G1 Z{_f(park_z)} F{_f(spec.z_feed)}",
        "M104 S0",
        "M140 S0",
        "M107",
        f"G0 X{_f(x0 + spec.margin_mm / 2)} Y{_f(y1 - spec.margin_mm / 2)} F{_f(spec.travel_feed)}",
        "M84",
        "; kincomp artifact end",
    ]


def _check_inside(lines: Sequence[str], spec: ArtifactSpec) -> None:
    x0, x1, y0, y1, z0, z1 = spec.volume
    for line in lines:
        if not line.startswith(("G0 ", "G1 ")):
            continue
        for word in line.split()[1:]:
            k = "XYZ".find(word[0])
            if k < 0:
                continue
            v = float(word[1:])
            lo, hi = (x0, x1) if k == 0 else (y0, y1) if k == 1 else (z0, z1)
            if not lo - 1e-9 <= v <= hi + 1e-9:
                raise ArtifactProgramError(
                    Msg(
                        "the artifact does not fit the volume (%(axis)s %(value)s)",
                        axis="XYZ"[k],
                        value=_f(v),
                    )
                )


# ---------------------------------------------------------------------------------------
# a program's own spec (its header)


def spec_of(text: str) -> ArtifactSpec:
    """The :class:`ArtifactSpec` a program was written for, read back from its header
    (``; kincomp artifact <key>: <value>``; a program written before a key existed has its
    default), checked against the program's measurement contract: the layout of that spec
    must give exactly the program's measurements (ids, from/to within 0.1 um), else
    :class:`ArtifactProgramError` (the walls could not be told from the header)."""
    info = read_program_info(text)
    contract = read_measurements(text)

    def num(key: str, default: float) -> float:
        try:
            return float(info[key])
        except (KeyError, ValueError):
            return default

    try:
        volume = tuple(float(v) for v in info["volume"].split(","))
        hotend, bed = (float(v) for v in info.get("temperatures_c", "210,60").split(","))
    except (KeyError, ValueError):
        volume, hotend, bed = (), 0.0, 0.0
    if len(volume) != 6:
        raise ArtifactProgramError(
            Msg("the program's header has no volume: it cannot be told where its walls are")
        )
    spec = ArtifactSpec(
        volume=volume,
        planes=tuple(p for p in info.get("planes", ",".join(PLANES)).split(",") if p),
        nozzle_mm=num("nozzle_mm", 0.4),
        hotend_c=hotend,
        bed_c=bed,
        first_layer_mm=num("first_layer_mm", 0.2),
        layer_mm=num("layer_mm", 0.0) or None,
        line_width_mm=num("line_width_mm", 0.0) or None,
        max_span_mm=num("max_span_mm", 150.0),
        tower_span_mm=num("tower_span_mm", 100.0),
        mode=info.get("mode", "full"),
    )
    made = measurements(layout(spec))
    same = [m.id for m in made] == [m.id for m in contract] and all(
        math.dist(a.start, b.start) < 1e-4 and math.dist(a.end, b.end) < 1e-4
        for a, b in zip(made, contract)
    )
    if not same:
        raise ArtifactProgramError(
            Msg(
                "the program's walls cannot be rebuilt from its header (written by another "
                "version of KinComp?): write the artifact again"
            )
        )
    return spec
