"""Deterministic generators of awkward G-code for equivalence and property tests."""

import random

NASTY_LINES = [
    "; comment only",
    "",
    "   ",
    "M104 S200",
    "M106 P1 S255 ; fan",
    "G4 P100",
    "G92 E0",
    "G92",
    "G92 X10 Y10",
    "G92.1",
    "M82",
    "M83",
    "G90",
    "G91",
    "G20",
    "G21",
    "G17",
    "G18",
    "G19",
    "G28",
    "G28 X",
    "G28 Z P0 T140",
    "G29",
    "G29.2 S0",
    "T0",
    "T1",
    "M117 Hello; world",
    "N10 G1 X5 Y5*33",
    "g1 x5 y5",
    "G01 X5 Y6",
    "G1X7Y8",
    "G1  X9 Y9",
    "G1 X9 Y9 ",
    "\tG1 X1 Y2",
    "G1 X1 X2",
    "G1 X1.2.3 Y2",
    "G1 X Y2",
    "G1 X1e3",
    "G1 E1.2.3",
    "G1 X10 Y10;no space comment",
    "G1 X1 ; c1 ; c2",
    "G1 F1500 X10 Y10 E1",
    "G1 X1 E2 Y3",
    "G1 F1800",
    "G1 E-0.8 F2400",
    "G1 Z.4",
    "G1 X+5 Y-.5",
    "G1 X5. Y.5",
    "G0 F9000 X1 Y2",
    "G2 X20 Y10 I5 J0 E1",
    "G3 X10 Y10 I-5 J0",
    "G2 X0 Y0 R-10",
    "G1 X123456789.123 Y1",
    "M48",
    "G38.2 Z-5",
    "*junk",
    "%",
    "SET_SKEW CLEAR=1",
]


def random_program(seed: int, n: int = 300, nasty: float = 0.3) -> list:
    """A program that mostly moves around a 200 mm bed, with awkward lines mixed in."""
    rng = random.Random(seed)
    lines = ["G28", "G90", "G92 E0", "G1 Z0.3 F1200"]
    x, y, z, e = 100.0, 100.0, 0.3, 0.0
    for _ in range(n):
        r = rng.random()
        if r < nasty:
            lines.append(rng.choice(NASTY_LINES))
            continue
        kind = rng.random()
        dec = rng.choice([3, 3, 3, 2, 4, 0])
        if kind < 0.6:
            x = min(210, max(-10, x + rng.uniform(-30, 30)))
            y = min(210, max(-10, y + rng.uniform(-30, 30)))
            e += rng.uniform(0, 1)
            parts = [f"G1 X{x:.{dec}f} Y{y:.{dec}f}", f"E{e:.5f}"]
            if rng.random() < 0.2:
                parts.append(f"F{rng.choice([1200, 1800, 3000])}")
            line = " ".join(parts)
        elif kind < 0.75:
            x = min(210, max(-10, x + rng.uniform(-30, 30)))
            line = f"G0 X{x:.3f}"
        elif kind < 0.85:
            y = min(210, max(-10, y + rng.uniform(-30, 30)))
            line = f"G1 Y{y:.3f} F{rng.choice([3000, 9000])}"
        elif kind < 0.92:
            z = round(z + 0.2, 2)
            line = f"G1 Z{z:.2f}"
        else:
            line = f"G1 X{x:.3f} Y{y:.3f} Z{z:.2f}"
        if rng.random() < 0.1:
            line += " ; note"
        lines.append(line)
    return lines
