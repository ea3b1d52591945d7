"""The artifact seen from above, as SVG: every pair of walls, each measurement numbered.

Numbers follow the order of the program's header (1 = its first ``; kincomp measure:`` line);
the outside and inside measurement of a pair share its walls and are written ``n/m`` near one
of the pair's walls. The bed is drawn from the volume (mm; +Y up, as seen from above the bed).
Only numbers and the ids of the header (letters, digits, ``._-``) go into the SVG text.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

from ...core.messages import as_dict
from .program import Measurement, hint_words

WALL_MM = 10.0  # drawn length of a wall


def _pairs(measurements: Sequence[Measurement]) -> List[Tuple[Measurement, List[int]]]:
    """One entry per pair of walls: its measurement and the numbers measuring it."""
    out: Dict[Tuple, Tuple[Measurement, List[int]]] = {}
    for i, m in enumerate(measurements, 1):
        key = (tuple(round(v, 3) for v in m.start), tuple(round(v, 3) for v in m.end))
        out.setdefault(key, (m, []))[1].append(i)
    return list(out.values())


def svg(measurements: Sequence[Measurement], volume: Optional[Sequence[float]] = None) -> str:
    """The top view (SVG text) of an artifact's measurements on a bed of ``volume``."""
    if volume is None:
        xs = [p[0] for m in measurements for p in (m.start, m.end)]
        ys = [p[1] for m in measurements for p in (m.start, m.end)]
        volume = (min(xs) - 10, max(xs) + 10, min(ys) - 10, max(ys) + 10)
    x0, x1, y0, y1 = (float(v) for v in volume[:4])
    pad = 6.0
    w, h = x1 - x0, y1 - y0

    def X(x: float) -> float:
        return x - x0 + pad

    def Y(y: float) -> float:
        return y1 - y + pad

    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="kincomp-artifact-drawing" '
        f'viewBox="0 0 {w + 2 * pad:.1f} {h + 2 * pad:.1f}" font-family="sans-serif">',
        f'<rect x="{pad}" y="{pad}" width="{w:.1f}" height="{h:.1f}" fill="none" '
        'stroke="#999" stroke-width="0.8"/>',
        f'<text x="{pad + 2}" y="{pad + h - 2:.1f}" font-size="5" fill="#999">'
        f"X{x0:g}..{x1:g} Y{y0:g}..{y1:g} mm</text>",
    ]
    for m, numbers in _pairs(measurements):
        n = m.direction
        nh = math.hypot(n[0], n[1])
        ux, uy = n[0] / nh, n[1] / nh  # horizontal measuring direction
        tx, ty = -uy, ux  # along the walls
        slanted = m.family == "slanted"
        colour = "#b35900" if slanted else "#1f5fa8"
        parts.append(
            f'<line x1="{X(m.start[0]):.1f}" y1="{Y(m.start[1]):.1f}" '
            f'x2="{X(m.end[0]):.1f}" y2="{Y(m.end[1]):.1f}" stroke="{colour}" '
            'stroke-width="0.4" stroke-dasharray="2,1.5"/>'
        )
        for p in (m.start, m.end):
            a = (p[0] - tx * WALL_MM / 2, p[1] - ty * WALL_MM / 2)
            b = (p[0] + tx * WALL_MM / 2, p[1] + ty * WALL_MM / 2)
            parts.append(
                f'<line x1="{X(a[0]):.1f}" y1="{Y(a[1]):.1f}" x2="{X(b[0]):.1f}" '
                f'y2="{Y(b[1]):.1f}" stroke="{colour}" stroke-width="1.6"/>'
            )
        # spans along an axis are labelled at their second wall, the rest at their first: the
        # labels of the flat part then do not fall on each other
        if max(abs(ux), abs(uy)) > 0.99:
            lx, ly = m.end[0] - ux * 9 + tx * 6, m.end[1] - uy * 9 + ty * 6
        else:
            lx, ly = m.start[0] + ux * 9 + tx * 6, m.start[1] + uy * 9 + ty * 6
        label = "/".join(str(k) for k in numbers)
        parts.append(
            f'<text x="{X(lx):.1f}" y="{Y(ly):.1f}" font-size="5.5" fill="{colour}" '
            f'text-anchor="middle" dominant-baseline="middle">{label}</text>'
        )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def legend(measurements: Sequence[Measurement]) -> List[Dict[str, object]]:
    """The numbered list that goes with the drawing: number, id, kind, nominal mm, hint."""
    return [
        {
            "n": i,
            "id": m.id,
            "kind": m.kind,
            "nominal_mm": round(m.length, 3),
            "plane": m.plane,
            "hint": m.hint,
            "hint_i18n": as_dict(hint_words(m.hint)),  # (the web UI's, translated there)
        }
        for i, m in enumerate(measurements, 1)
    ]
