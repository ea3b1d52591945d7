"""Proof that every written arc is where the program wants it (issue 13).

Programs with arcs (all planes, IJ and R forms, full circles, P turns, helices, G91, inches)
are compensated; the output is run through a firmware interpreter that cuts each written arc
into chords of 1e-6 mm sagitta, each point goes through the printer's true errors (the
forward model) and, with backlash, through its play (a play holds the carriage ``b(q)/2``
behind the drive; the compensation uses fraction 1); the printed path of each input arc is
then compared with the desired arc (the input's own arc, cut as finely) in both directions
(Hausdorff distance): every printed point lies within ``chord_tol_mm`` of the desired arc and
every desired point within ``chord_tol_mm`` of the printed path, plus the output resolution
(chord ends are rounded like every written coordinate; for arcs the fit reserves 1.5
resolutions of the tolerance for the rounded centre).

The right statement with backlash: each written arc piece moves every backlash axis one way
(reversals cut the arc, with a take-up there), so the play sits fully on one side along the
whole piece; the carriage follows the drive minus ``b(q)/2`` and lands on the desired arc.
Without play the same output is off by the take-up offset, which is what it is for.
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from octoprint_kincomp.core import arcs
from octoprint_kincomp.core.arcpath import strictly_between
from octoprint_kincomp.core.compensator import Options
from octoprint_kincomp.core.kinematics import KinematicModel
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.firmware.interpreter import FirmwareInterpreter, Home, Move
from octoprint_kincomp.simulator.play import Play
from tests.core.test_properties import cfg, geometry, program

pytestmark = pytest.mark.usefixtures("engine")
FINE = 1e-5  # sagitta of the chords the interpreters cut arcs into (mm)
# Arcs whose end radius differs from the start radius by more than this (plus 0.1 %) are
# spirals that firmware refuses (grbl, LinuxCNC); the random words of the property programs
# make such arcs, and for them the check (radial distance at the same angle) overstates the
# distance of a chord: they are not compared here.
SPIRAL_MM = 0.05
_BLOCK = 512  # points of the printed path whose nearest arc points are sought at once


def deviation(arc: arcs.Arc, path) -> float:
    """How far the printed ``path`` (points, mm) strays from the desired ``arc``: each point's
    distance to the arc (the nearest of the arc's points around the one at the same angle),
    the path's end against the arc's end, and the angle it covers against the sweep.
    Between two points the path is straight: it is checked at quarters of each segment too."""
    V = np.asarray(path, float)
    # the path is straight between its points: check those lines at quarters too
    P = np.empty((4 * len(V) - 3, 3))
    for i, q in enumerate((0.0, 0.25, 0.5, 0.75)):
        P[i:-1:4] = V[:-1] + (V[1:] - V[:-1]) * q
    P[-1] = V[-1]
    a = P[:, arc.ia] - arc.ca
    b = P[:, arc.ib] - arc.cb
    ang = np.unwrap(np.arctan2(b, a))
    ang += 2 * math.pi * round((arc.t0 - float(ang[0])) / (2 * math.pi))  # ang[0] ~ t0
    f = np.clip((ang - arc.t0) / arc.sweep, 0.0, 1.0)
    # the nearest point of the arc is near the one at the same angle: search around it
    # (twice, the second time 40 times finer), so a steep helix is not judged by its angle;
    # in blocks of points (the candidates of a block stay in the CPU's cache)
    width = min(0.5, 0.2 / (max(min(arc.r0, arc.r1), 1e-3) * abs(arc.sweep)))
    grid = np.linspace(-1.0, 1.0, 81)[None, :]
    d = np.empty(len(f))
    for lo in range(0, len(f), _BLOCK):
        fb, ab, bb = f[lo : lo + _BLOCK], a[lo : lo + _BLOCK, None], b[lo : lo + _BLOCK, None]
        lb = P[lo : lo + _BLOCK, arc.il][:, None]
        rows = np.arange(len(fb))
        w = width
        for _ in range(2):
            cand = np.clip(fb[:, None] + w * grid, 0.0, 1.0)
            t = arc.t0 + arc.sweep * cand
            r = arc.r0 + arc.dr * cand
            da = ab - r * np.cos(t)
            db = bb - r * np.sin(t)
            dl = lb - (arc.l0 + arc.dl * cand)
            d2 = da * da + db * db + dl * dl  # (the nearest by its square: no root each)
            best = np.argmin(d2, axis=1)
            fb = cand[rows, best]
            w /= 40.0
        d[lo : lo + _BLOCK] = np.sqrt(d2[rows, best])
    # (the first point is where the previous line left the head: after a partial G28 under
    # skew the drives' position, not the desired start; that is judged with that line)
    worst = float(d[1:].max()) if len(d) > 1 else 0.0
    worst = max(worst, float(np.linalg.norm(P[-1] - np.asarray(arc.end))))
    gap = (abs(arc.sweep) - (ang.max() - ang.min())) * max(arc.r0, arc.r1)
    return max(worst, gap)  # (gap: mm of arc the path never reached)


def printed_arcs(p: Params, lines, opts: Options, play: bool):
    """(input arc line, its output lines, deviation mm) for every arc the compensator
    rewrote, the output printed on a printer with the errors (and play) of ``p``."""
    comp = make_compensator(p, opts)
    want_fw = FirmwareInterpreter(arc_tol_mm=FINE)
    got_fw = FirmwareInterpreter(arc_tol_mm=FINE)
    model = KinematicModel(p)
    backlash = Play(p) if play else None
    pos = None  # the printed (actual) position
    results = []
    for line in lines:
        out = comp.process(line)
        outs = [line] if out is line else out
        want_fw.last_arc = None
        want = [ev for ev in want_fw.execute(line) if isinstance(ev, Move)]
        path = [pos] if pos is not None else []
        for o in outs:
            for ev in got_fw.execute(o):
                if isinstance(ev, Home):
                    pos = None  # (the head went home)
                    path = []
                    if backlash is not None:
                        backlash.reset(ev.axes)
                if not isinstance(ev, Move):
                    continue
                ends = []
                for drive in (ev.start, ev.end):
                    if backlash is not None:
                        drive = [backlash.carriage(k, drive[k]) for k in range(3)]
                    ends.append(model.forward(drive))
                if pos is None:
                    path.append(ends[0])
                pos = ends[1]
                path.append(pos)
        arc = want_fw.last_arc
        if (
            arc is not None
            and want
            and out is not line
            and len(path) > 1
            and abs(arc.dr) <= SPIRAL_MM + 1e-3 * arc.r0
        ):
            results.append((line, outs, deviation(arc, path)))
    return comp, results


def _resolution(opts: Options) -> float:
    return 10.0**-opts.decimals


@st.composite
def arc_program(draw):
    """Homed, then arcs of every kind (radii 0.5-80 mm, any sweep, helices, P turns) between
    straight moves, in G17/G18/G19, G90/G91, mm/inch."""
    lines = ["G28", "M83", "G1 X100 Y100 Z20 F3000"]
    inch = False
    for _ in range(draw(st.integers(1, 12))):
        op = draw(st.sampled_from(["arc"] * 6 + ["move", "plane", "g91", "inch"]))
        u = 25.4 if inch else 1.0
        if op == "arc":
            r = draw(st.floats(0.5, 80))
            a0 = draw(st.floats(0, 2 * math.pi))
            sweep = draw(
                st.sampled_from([draw(st.floats(0.01, 1.6)), draw(st.floats(0.01, 6.28)), 0.0])
            )
            ia = draw(st.booleans())
            words = []
            # the arc starts where the head is: centre at -r (cos a0, sin a0) from it
            oa, ob = -r * math.cos(a0), -r * math.sin(a0)
            cw = draw(st.booleans())
            a1 = a0 - sweep if cw else a0 + sweep
            da, db = oa + r * math.cos(a1), ob + r * math.sin(a1)
            plane = draw(st.sampled_from(["G17", "G18", "G19"]))
            ax, off = {"G17": ("XY", "IJ"), "G18": ("ZX", "KI"), "G19": ("YZ", "JK")}[plane]
            lines.append(plane)
            lines.append("G91")  # targets relative to the start, then back to G90
            words = [f"{ax[0]}{da / u:.4f}", f"{ax[1]}{db / u:.4f}"]
            if sweep == 0.0:
                words = []  # a full circle
            if ia and sweep != 0.0:
                r_word = r if sweep <= math.pi else -r
                words.append(f"R{r_word / u:.4f}")
            else:
                words += [f"{off[0]}{oa / u:.4f}", f"{off[1]}{ob / u:.4f}"]
            lin = "XYZ".replace(ax[0], "").replace(ax[1], "")
            if draw(st.integers(0, 3)) == 0:
                words.append(f"{lin}{draw(st.floats(-2, 2)) / u:.4f}")  # helix
            if draw(st.integers(0, 6)) == 0:
                words.append("P1")
            words.append(f"E{draw(st.floats(0.01, 2)):.5f}")
            lines.append(("G2 " if cw else "G3 ") + " ".join(words))
            lines.append("G90")
            lines.append("G17")
        elif op == "move":
            lines.append(
                "G1 X{:.3f} Y{:.3f} Z{:.3f}".format(
                    *(
                        v / u
                        for v in (
                            draw(st.floats(60, 140)),
                            draw(st.floats(60, 140)),
                            draw(st.floats(10, 30)),
                        )
                    )
                )
            )
        elif op == "inch":
            inch = not inch
            lines.append("G20" if inch else "G21")
    return lines


@st.composite
def play_backlash(draw):
    return {
        a: draw(st.floats(1.0, 80.0))
        if draw(st.booleans())
        else [
            {"at_mm": 10.0, "um": draw(st.floats(0, 80))},
            {"at_mm": 210.0, "um": draw(st.floats(0, 80))},
        ]
        for a in "xyz"
    }


@cfg(40)
@given(arc_program(), geometry(), st.sampled_from([0.01, 0.05, 0.002]), st.sampled_from([3, 6]))
def test_every_written_arc_prints_within_the_tolerance(lines, geo, tol, dec):
    p = Params.from_dict(geo)
    opts = Options(chord_tol_mm=tol, decimals=dec)
    _, results = printed_arcs(p, lines, opts, play=False)
    for line, outs, d in results:
        assert d <= tol + _resolution(opts) + FINE, (line, outs, d)


@cfg(40)
@given(arc_program(), geometry(), play_backlash(), st.sampled_from([0.01, 0.05]))
def test_with_play_every_written_arc_prints_within_the_tolerance(lines, geo, bl, tol):
    p = Params.from_dict(dict(geo, backlash=bl))
    opts = Options(chord_tol_mm=tol, decimals=6)
    _, results = printed_arcs(p, lines, opts, play=True)
    for line, outs, d in results:
        assert d <= tol + _resolution(opts) + FINE, (line, outs, d)


@cfg(25)
@given(program(partial_home=False), geometry(), st.sampled_from([0.01, 0.05]))
def test_arcs_of_the_property_programs_print_within_the_tolerance(lines, geo, tol):
    """(Full homing only: after a partial G28 under skew the drives are not at the command of
    the desired start, so the next move starts off by that much, arc or chord alike.)"""
    p = Params.from_dict(geo)
    opts = Options(chord_tol_mm=tol, decimals=6)
    _, results = printed_arcs(p, lines, opts, play=False)
    for line, outs, d in results:
        assert d <= tol + _resolution(opts) + FINE, (line, outs, d)


def test_slicer_arcs_are_kept_as_single_arcs():
    """A BambuStudio file at 200 um/m: every arc of at most 90 degrees stays one G2/G3
    (255 of its 3951 arcs sweep more and are written in pieces of at most 90 degrees)."""
    from tests.support import DATA

    p = Params.from_dict({"squareness_um_per_m": {"xy": 200.0}})
    with open(f"{DATA}/bambustudio-a1-hook.gcode") as f:
        lines = f.read().splitlines()
    comp = make_compensator(p)
    n_out = 0
    for line in lines:
        out = comp.process(line)
        n_out += 1 if out is line else len(out)
    rep = comp.report
    assert rep.arcs_linearised == 0
    assert rep.arcs_kept + rep.arcs_split == 3951 and rep.arcs_split <= 255
    assert n_out <= 1.05 * len(lines)
    assert 0 < rep.arc_max_deviation_um < 10.0


ANGLE = st.floats(0.0, 2 * math.pi)


@given(
    ANGLE,
    st.floats(0.01, 2 * math.pi - 0.01),
    st.floats(0.5, 300.0),
    st.floats(-0.2, 0.2),
    st.sampled_from([17, 18, 19]),
    st.booleans(),
    st.floats(0.0, 0.9),
    st.floats(0.05, 1.0),
)
def test_points_by_rotation_are_the_points_by_angle(a0, sweep, r, dr, plane, cw, fa, width):
    """Arc.points (the angle stepped by a rotation: two sine/cosine pairs for a piece's
    eighths) gives Arc.point's points within 1e-12 of the radius, and exactly its start and
    end points at fractions 0 and 1 (spirals too: end radius r + dr, dr up to 0.2 mm)."""
    ia, ib, il, _, _ = arcs.PLANES[plane]
    a1 = a0 - sweep if cw else a0 + sweep
    start, end = [0.0, 0.0, 0.0], [0.0, 0.0, 3.0]
    start[ia], start[ib] = 50 + r * math.cos(a0), 60 + r * math.sin(a0)
    end[ia], end[ib] = 50 + (r + dr) * math.cos(a1), 60 + (r + dr) * math.sin(a1)
    start[il] = 1.0
    arc = arcs.Arc(start, end, plane, 50.0, 60.0, cw)
    for fa_, fb_ in ((fa, min(1.0, fa + width)), (0.0, 1.0)):
        got = arc.points(fa_, fb_, 8)
        want = [arc.point(fa_ + (fb_ - fa_) * (j / 8)) for j in range(9)]
        assert max(math.dist(g, w) for g, w in zip(got, want)) < 1e-12 * (r + 1)
    assert got[0] == arc.start and got[-1] == arc.end


@given(ANGLE, ANGLE, ANGLE, st.booleans(), st.floats(0.1, 100.0))
def test_strictly_between_is_the_comparison_of_angles(a_s, a_v, a_e, clockwise, r):
    """The overshoot test's sign rule (no trigonometry) decides as angles would: the
    direction v lies strictly between the start s and the end e, turning as the arc turns,
    exactly when its angle from s in that sense is in (0, that of e)."""
    sa, sb = r * math.cos(a_s), r * math.sin(a_s)
    va, vb = math.cos(a_v), math.sin(a_v)
    ea, eb = 2 * r * math.cos(a_e), 2 * r * math.sin(a_e)

    def angle(x, y):
        ang = math.atan2(sa * y - sb * x, sa * x + sb * y)
        ang = -ang if clockwise else ang
        return ang + 2 * math.pi if ang < 0 else ang

    av, ae = angle(va, vb), angle(ea, eb)
    assume(min(abs(av - ae), av, ae, 2 * math.pi - av, 2 * math.pi - ae) > 1e-9)  # no tie
    assert strictly_between(va, vb, sa, sb, ea, eb, clockwise) == (0.0 < av < ae)


def test_strictly_between_at_its_edges():
    # counter-clockwise from +X: +Y lies within a half turn to -X, not within a quarter
    # turn short of it, nor at the start or end themselves; clockwise the other way round
    assert strictly_between(0.0, 1.0, 1.0, 0.0, -1.0, 0.0, False)
    assert not strictly_between(0.0, 1.0, 1.0, 0.0, 1.0, 1e-3, False)
    assert strictly_between(0.0, -1.0, 1.0, 0.0, -1.0, 0.0, True)
    assert not strictly_between(0.0, 1.0, 1.0, 0.0, -1.0, 0.0, True)
    assert not strictly_between(1.0, 0.0, 1.0, 0.0, -1.0, 0.0, False)  # the start itself
    assert not strictly_between(-1.0, 0.0, 1.0, 0.0, -1.0, 0.0, False)  # the end itself
    assert not strictly_between(0.0, 1.0, 1.0, 0.0, 2.0, 0.0, False)  # no turn at all
    # past a half turn: -Y lies inside a three-quarter turn counter-clockwise
    assert strictly_between(0.0, -1.0, 1.0, 0.0, 1.0, -1.0, False)


def test_the_check_can_fail():
    """The printed-path check sees an arc written without compensation (guards against a
    vacuous comparison)."""
    p = Params.from_dict({"squareness_um_per_m": {"xy": 3000.0}})
    lines = ["G28", "G1 X100 Y100 Z1", "G2 X120 Y100 I10 J0"]
    _, results = printed_arcs(p, lines, Options(decimals=6), play=False)
    assert results and results[0][2] < 0.01
    model = KinematicModel(p)
    fw = FirmwareInterpreter(arc_tol_mm=FINE)
    evs = [ev for line in lines for ev in fw.execute(line) if isinstance(ev, Move)]
    pts = [model.forward(evs[-1].start)] + [model.forward(ev.end) for ev in evs if ev.kind == "arc"]
    assert deviation(fw.last_arc, pts) > 0.05


def test_linearise_arcs_option_writes_chords():
    p = Params.from_dict({"squareness_um_per_m": {"xy": 500.0}})
    comp = make_compensator(p, Options(linearise_arcs=True))
    comp.process("M83")
    comp.process("G28")
    comp.process("G1 X100 Y100 Z1")
    out = comp.process("G2 X120 Y100 I10 J0 E1")
    assert all(o.startswith("G1 ") for o in out) and len(out) > 4
    assert comp.report.arcs_linearised == 1 and comp.report.arcs_kept == 0


def test_a_helical_half_circle_is_one_arc_when_it_fits():
    """Issue 28: a helix of 360 degrees (BambuStudio's lift) is written in two 180 degree
    pieces; each is one G2 when the fit is within the tolerance, as a planar half circle is
    (a half circle's end lies at +-180 degrees, where the angle's sign is a coin toss: the
    helix was halved into 90 degree lines at a deviation of 0.2 um)."""
    p = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}})
    lines = [
        "G28",
        "G90",
        "M83",
        "G1 X65 Y245 Z0.4",
        "G2 X66.72 Y246.72 I0.86 J0.86 E0.1",
        "G1 X65 Y245 Z0.4",
        "G2 X65 Y245 Z0.6 I-0.86 J-0.86 E0.1",
    ]
    opts = Options()
    comp, results = printed_arcs(p, lines, opts, play=False)
    (_, planar, d1), (_, helix, d2) = results
    assert len(planar) == 1 and planar[0].startswith("G2 ")
    assert len(helix) == 2 and all(o.startswith("G2 ") for o in helix), helix
    assert helix[-1].split()[1:4] == ["X64.755", "Y245", "Z0.6"]
    assert max(d1, d2) <= opts.chord_tol_mm + _resolution(opts) + FINE


@pytest.mark.parametrize("r", ["R4.9", "R-4.9", "R0.001"])
def test_an_r_below_half_the_chord_is_the_half_circle_marlin_prints(r):
    """Issue 28: Marlin prints an R arc whose R is below half its chord as the half circle
    over the chord (the centre's distance from the midpoint is 0 when r^2 < (chord/2)^2);
    it was refused as malformed and passed uncompensated, 65 um off under the paper's skew."""
    p = Params.from_dict(
        {"squareness_um_per_m": {"xy": -3638.6}, "scale_ppm": {"x": -451.7, "y": 287.0}}
    )
    lines = ["G28", "G90", "G1 X10 Y18", f"G2 X20 Y18 {r}"]
    opts = Options()
    comp, results = printed_arcs(p, lines, opts, play=False)
    assert comp.report.malformed == 0 and comp.report.untouched_unknown == 0
    ((line, outs, d),) = results
    assert d <= opts.chord_tol_mm + _resolution(opts) + FINE, (outs, d)
    # the half circle over the chord, clockwise: through (15, 23), above it
    arc = arcs.Arc(
        (10, 18, 0),
        (20, 18, 0),
        17,
        *arcs.centre_from_words((10, 18, 0), (20, 18, 0), 17, (None, None), float(r[1:]), True),
        True,
    )
    assert (arc.ca, arc.cb, arc.r0) == (15.0, 18.0, 5.0)
    assert arc.point(0.5) == pytest.approx((15.0, 23.0, 0.0))
