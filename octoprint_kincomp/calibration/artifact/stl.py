"""The artifact as a mesh (binary STL), for printing it with the user's own slicer profile.

The solids are the walls the G-code of :mod:`.program` prints, in the same machine
coordinates (mm, Z up): each wall one line wide (the program's line width) and
``fin_length_mm`` long, from the bed to its top, leaning 45 deg where it does (its horizontal
cross-section at height ``z`` is centred on :meth:`.program.Fin.centre_at`), and under each
wall the foot of the program's first two layers, three lines wide. The measuring contract
(the program's header: ids, nominal from/to) is the program's, unchanged: a part sliced from
this mesh is measured and analysed with the G-code program it came with. Moving the part on
the bed changes nothing (the analysis uses only the spans); rotating or scaling it does.

Binary STL: an 80-byte header, the facet count (uint32), then per facet its normal and three
vertices (float32, little-endian) and a zero uint16. Facets are wound counter-clockwise seen
from outside (right-hand normal outwards).
"""

from __future__ import annotations

import math
import struct
from typing import List, Sequence, Tuple

from .program import ArtifactSpec, Fin, layout, spec_of

Vec = Tuple[float, float, float]
Facet = Tuple[Vec, Vec, Vec]

# the six faces of a box whose corners are indexed (i, j, k) = bit 0, 1, 2 of the index
# (i along the wall's normal, j along the wall, k up), each as two facets wound outwards
_FACES = (
    (0, 2, 3, 1),  # k = 0 (bottom), seen from below
    (4, 5, 7, 6),  # k = 1 (top)
    (0, 1, 5, 4),  # j = 0
    (2, 6, 7, 3),  # j = 1
    (0, 4, 6, 2),  # i = 0
    (1, 3, 7, 5),  # i = 1
)


def _slab(fin: Fin, z_lo: float, z_hi: float, width: float) -> List[Facet]:
    """The solid of ``fin`` between heights ``z_lo`` and ``z_hi`` (mm), ``width`` mm thick
    along its horizontal normal: a box, sheared along that normal for a leaning wall."""
    nx, ny, _ = fin.n
    h = math.hypot(nx, ny)
    ux, uy = nx / h, ny / h  # horizontal normal
    tx, ty = -uy, ux  # along the wall
    corners = []
    for idx in range(8):
        i, j, k = idx & 1, (idx >> 1) & 1, (idx >> 2) & 1
        z = z_hi if k else z_lo
        cx, cy = fin.centre_at(z)
        a = (i - 0.5) * width
        b = (j - 0.5) * fin.length
        corners.append((cx + a * ux + b * tx, cy + a * uy + b * ty, z))
    out: List[Facet] = []
    for a, b, c, d in _FACES:
        out.append((corners[a], corners[b], corners[c]))
        out.append((corners[a], corners[c], corners[d]))
    return out


def solids(spec: ArtifactSpec) -> List[Facet]:
    """Every facet of the artifact of ``spec``: per wall its foot (three lines wide, the
    first two layers) and the wall (one line wide, the bed up to its top)."""
    z0 = spec.volume[4]
    foot_top = z0 + spec.first_layer_mm + spec.layer
    out: List[Facet] = []
    for feature in layout(spec):
        for fin in feature.fins:
            out += _slab(fin, z0, min(foot_top, fin.top), 3 * spec.width)
            out += _slab(fin, z0, fin.top, spec.width)
    return out


def _normal(f: Facet) -> Vec:
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = f
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    n = (uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx)
    length = math.sqrt(sum(c * c for c in n)) or 1.0
    return tuple(c / length for c in n)


def binary_stl(facets: Sequence[Facet], name: str = "KinComp artifact") -> bytes:
    """``facets`` as binary STL (mm)."""
    head = name.encode("ascii", "replace")[:80].ljust(80, b" ")
    parts = [head, struct.pack("<I", len(facets))]
    for f in facets:
        parts.append(struct.pack("<12fH", *_normal(f), *f[0], *f[1], *f[2], 0))
    return b"".join(parts)


def program_stl(text: str) -> bytes:
    """The STL of the artifact program ``text`` (its walls rebuilt from its header and
    checked against its measurement contract: :func:`.program.spec_of`)."""
    spec = spec_of(text)
    return binary_stl(solids(spec), f"KinComp artifact ({spec.mode}), mm, machine frame")
