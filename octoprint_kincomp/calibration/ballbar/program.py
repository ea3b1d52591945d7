"""ISO 230-4 circular test programs for a ballbar, as fine G1 polylines.

Conventions: the plane's axes (A, B) are XY -> (X, Y), XZ -> (X, Z), YZ -> (Y, Z); angles run
from +A towards +B (degrees); ``ccw`` means the angle increases. The pivot (centre ball) sits at
``centre``; the nozzle carries the tool cup and moves on the circle of ``radius_mm``.

Per direction the program runs: start at radius ``R + feed_in_mm`` on the start angle, dwell
(sync marker), radial feed-in to ``R``, overshoot arc, capture arc (360 deg in XY; 220 deg in
vertical planes, from -20 to 200 deg by default), overshoot arc, radial feed-out to
``R + feed_in_mm``, dwell. The clockwise run retraces the same arc backwards from where the
counter-clockwise run ended, so the bar stays mounted. Arcs are G1 chords (chord error <=
``chord_error_um``) with a point on every quadrant: firmware segments G2/G3 differently and some
cannot do G18/G19 at all.

With ``mount_pause`` the program waits for the user to mount the bar before the first run and
to unmount it after the last, with the pause the firmware has (``pause_command``, see
:data:`PAUSES`): ``M0`` (Marlin, and any firmware through OctoPrint, which pauses its job at
it), Klipper's ``PAUSE`` (``M0`` is unknown to Klipper: printed from its own SD card the program
would run on without the bar), RepRapFirmware's blocking message box ``M291 S2`` (its ``M0``
ends the print). The header records the planner settings the program was planned with
(``motion``, :meth:`..firmware.planner.MotionSettings.metadata`): a trace captured for it
carries them, and the analysis plans the program as that firmware does.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import re
from dataclasses import asdict, dataclass
from typing import Dict, List, Optional, Sequence, Tuple

from ...core.messages import Msg, joined
from ...firmware.planner import MotionSettings, pauses

PLANES = {"XY": (0, 1), "XZ": (0, 2), "YZ": (1, 2)}
# Run markers that survive comment stripping (OctoPrint sends no comments); M117 just shows
# them on the printer's display.
RUN_MARKER = "Ballbar run"
END_MARKER = "Ballbar test done"
AXIS = "XYZ"
DEFAULT_FEED = 1850.0
DEFAULT_RADIUS = 100.0
# The mount and unmount pause of each pause command; the M0 lines as they always were (a
# program's hash covers its body: stored campaigns' programs must stay the same)
PAUSES = {
    "M0": (
        "M0 Mount the ballbar now ; pause: continue when it is mounted",
        "M0 Unmount the ballbar now ; pause",
    ),
    "PAUSE": (
        "PAUSE ; Klipper: mount the ballbar now, then RESUME",
        "PAUSE ; Klipper: unmount the ballbar now, then RESUME",
    ),
    "M291": (
        'M291 P"Mount the ballbar now, then press OK" R"KinComp" S2 ; wait for the user',
        'M291 P"Unmount the ballbar now, then press OK" R"KinComp" S2 ; wait for the user',
    ),
}
# the pause command of each firmware (firmware/motion_limits.FIRMWARES); M0 for any other
FIRMWARE_PAUSE = {"marlin": "M0", "klipper": "PAUSE", "reprapfirmware": "M291"}


_M0_M1 = re.compile(r"\s*M0*[01](?!\d)", re.IGNORECASE)


def is_pause(line: str) -> bool:
    """Whether ``line`` (a program line as written or as sent, comments stripped) is one of
    the pauses a test program may write (:data:`PAUSES`: ``M0``/``M1``, ``PAUSE``,
    ``M291 S2``; ``M226`` too)."""
    return _M0_M1.match(line) is not None or pauses(line)


def pause_for(firmware: Optional[str]) -> str:
    """The pause command (a key of :data:`PAUSES`) a program for ``firmware`` (``marlin``,
    ``klipper``, ``reprapfirmware``; None: not known) writes: M0 unless the firmware has
    another (Klipper: PAUSE; RepRapFirmware: M291 S2, never its M0, which ends the print)."""
    return FIRMWARE_PAUSE.get(firmware or "", "M0")


class ProgramError(ValueError):
    """The requested test cannot be run (does not fit the machine, bad values)."""


@dataclass
class TestSpec:
    """One ballbar test. Lengths in mm, feed in mm/min, angles in degrees."""

    __test__ = False  # not a pytest class despite its name

    plane: str = "XY"
    centre: Tuple[float, float, float] = (110.0, 110.0, 10.0)
    radius_mm: float = DEFAULT_RADIUS
    feed_mm_min: float = DEFAULT_FEED
    feed_in_mm: float = 1.0
    overshoot_deg: float = 20.0
    capture_deg: Optional[float] = None  # default: 360 (XY) or 220 (vertical planes)
    start_deg: Optional[float] = None  # capture start; default 0 (XY) or -20 (vertical)
    dwell_s: float = 1.0
    chord_error_um: float = 0.5
    lift_mm: float = 10.0
    travel_feed_mm_min: float = 3000.0
    directions: Tuple[str, ...] = ("ccw", "cw")
    mount_pause: bool = False
    pause_command: str = "M0"  # a key of PAUSES (the firmware's pause, see pause_for)
    motion: Optional[Dict[str, str]] = None  # planner settings planned with (metadata keys)
    requested_feed_mm_min: Optional[float] = None  # before capping (for the record)
    params_hash: Optional[str] = None  # of the parameters active when it runs (read back)
    printer: Optional[str] = None  # printer name (campaign checks: one printer)
    campaign: Optional[str] = None  # campaign id, this test's name and all tests' names
    campaign_step: Optional[str] = None
    campaign_tests: Optional[str] = None

    def __post_init__(self):
        self.plane = str(self.plane).upper()
        if self.plane not in PLANES:
            raise ProgramError(
                Msg(
                    "plane must be one of %(choices)s, got %(plane)s",
                    choices=", ".join(PLANES),
                    plane=repr(self.plane),
                )
            )
        self.centre = tuple(float(v) for v in self.centre)
        if len(self.centre) != 3 or not all(math.isfinite(v) for v in self.centre):
            raise ProgramError(Msg("centre needs three finite coordinates X,Y,Z (mm)"))
        for name, lo, hi in (
            ("radius_mm", 5.0, 1000.0),
            ("feed_mm_min", 10.0, 60000.0),
            ("feed_in_mm", 0.1, 5.0),
            ("overshoot_deg", 0.0, 180.0),
            ("dwell_s", 0.0, 60.0),
            ("chord_error_um", 0.01, 50.0),
            ("lift_mm", 0.0, 100.0),
        ):
            v = float(getattr(self, name))
            if not (lo <= v <= hi) or not math.isfinite(v):
                raise ProgramError(
                    Msg(
                        "%(name)s must be within %(lo)s..%(hi)s, got %(value)s",
                        name=name,
                        lo=f"{lo:g}",
                        hi=f"{hi:g}",
                        value=f"{v:g}",
                    )
                )
            setattr(self, name, v)
        if self.capture_deg is None:
            self.capture_deg = 360.0 if self.plane == "XY" else 220.0
        if self.start_deg is None:
            self.start_deg = 0.0 if self.plane == "XY" else -20.0
        if not (10.0 <= float(self.capture_deg) <= 360.0):
            raise ProgramError(Msg("capture_deg must be within 10..360"))
        if self.pause_command not in PAUSES:
            raise ProgramError(
                Msg(
                    "pause_command must be one of %(choices)s, got %(value)s",
                    choices=", ".join(PAUSES),
                    value=repr(self.pause_command),
                )
            )
        if self.motion is not None:
            self.motion = {str(k): str(v) for k, v in dict(self.motion).items()}
            try:
                MotionSettings.from_metadata(self.motion)
            except ValueError:  # ParamsError too
                raise ProgramError(Msg("the program's planner settings are not valid")) from None
        self.directions = tuple(self.directions)
        if (
            not self.directions
            or len(set(self.directions)) != len(self.directions)
            or any(d not in ("ccw", "cw") for d in self.directions)
        ):
            raise ProgramError(Msg("directions are 'ccw' and/or 'cw'"))

    @property
    def axes(self) -> Tuple[int, int]:
        return PLANES[self.plane]

    def point(self, angle_deg: float, radius: float) -> Tuple[float, float, float]:
        a, b = self.axes
        p = list(self.centre)
        t = math.radians(angle_deg)
        p[a] += radius * math.cos(t)
        p[b] += radius * math.sin(t)
        return (p[0], p[1], p[2])

    def metadata(self) -> Dict[str, str]:
        """The trace metadata this program implies (see formats.py); every value the program
        body depends on, so that the program can be regenerated from a trace."""
        out = {
            "plane": self.plane,
            "radius_mm": f"{self.radius_mm:.10g}",
            "feed_mm_min": f"{self.feed_mm_min:.10g}",
            "centre": ",".join(f"{v:.10g}" for v in self.centre),
            "feed_in_mm": f"{self.feed_in_mm:g}",
            "overshoot_deg": f"{self.overshoot_deg:g}",
            "capture_deg": f"{self.capture_deg:g}",
            "start_deg": f"{self.start_deg:g}",
            "dwell_s": f"{self.dwell_s:g}",
            "directions": ",".join(self.directions),
            "chord_error_um": f"{self.chord_error_um:g}",
            "lift_mm": f"{self.lift_mm:g}",
            "travel_feed_mm_min": f"{self.travel_feed_mm_min:g}",
            "mount_pause": "true" if self.mount_pause else "false",
        }
        if self.mount_pause and self.pause_command != "M0":
            out["mount_pause_command"] = self.pause_command
        if self.motion:
            out.update(self.motion)
        if self.printer:
            out["printer"] = self.printer
        if self.campaign:
            out["campaign"] = self.campaign
            out["campaign_step"] = self.campaign_step or ""
            out["campaign_tests"] = self.campaign_tests or ""
        return out


def cap_feed(feed: float, plane: str, max_feed_mm_min: Optional[Dict[str, float]]) -> float:
    """Feed capped at the slowest max feed of the plane's two axes (mm/min)."""
    if not max_feed_mm_min:
        return feed
    a, b = PLANES[plane.upper()]
    caps = [max_feed_mm_min.get(AXIS[k].lower()) or max_feed_mm_min.get(AXIS[k]) for k in (a, b)]
    caps = [float(c) for c in caps if c]
    return min([feed] + caps)


def arc_angles(spec: TestSpec, start: float, sweep: float) -> List[float]:
    """Angles (deg) of the chord ends of an arc, excluding ``start``, quadrants included."""
    seg = 2.0 * math.degrees(math.acos(1.0 - spec.chord_error_um * 1e-3 / spec.radius_mm))
    # 0.8: merging a grid point into a nearby quadrant point lengthens a chord by up to 25 %
    n = max(1, int(math.ceil(abs(sweep) / (0.8 * seg) - 1e-9)))
    fr = {i / n for i in range(1, n + 1)}
    lo, hi = sorted((start, start + sweep))
    k = math.ceil(lo / 90.0)
    while k * 90.0 < hi:
        f = (k * 90.0 - start) / sweep
        if 0 < f < 1:
            fr = {x for x in fr if abs(x - f) > 0.25 / n}
            fr.add(f)
        k += 1
    fr.add(1.0)
    return [start + sweep * f for f in sorted(fr)]


def run_angles(spec: TestSpec, direction: str) -> Tuple[float, float]:
    """(feed-in angle, signed total sweep incl. overshoots) of one run, degrees."""
    cap0, cap = spec.start_deg, spec.capture_deg
    o = spec.overshoot_deg
    if direction == "ccw":
        return cap0 - o, cap + 2 * o
    return cap0 + cap + o, -(cap + 2 * o)


def check_bounds(spec: TestSpec, volume: Optional[Sequence[float]]) -> None:
    """Raise ProgramError when the test leaves ``volume`` (x0,x1,y0,y1,z0,z1 in mm)."""
    if volume is None:
        return
    vol = [float(v) for v in volume]
    pts = []
    for d in spec.directions:
        a0, sweep = run_angles(spec, d)
        n = max(8, int(abs(sweep)))
        for i in range(n + 1):
            pts.append(spec.point(a0 + sweep * i / n, spec.radius_mm + spec.feed_in_mm))
    lift = list(
        spec.point(run_angles(spec, spec.directions[0])[0], spec.radius_mm + spec.feed_in_mm)
    )
    lift[2] += spec.lift_mm
    pts.append(tuple(lift))
    problems = []
    for k, name in enumerate(AXIS):
        lo, hi = vol[2 * k], vol[2 * k + 1]
        vmin = min(p[k] for p in pts)
        vmax = max(p[k] for p in pts)
        if vmin < lo - 1e-9:
            problems.append(
                Msg(
                    "%(axis)s reaches %(value)s mm, below the limit %(limit)s mm",
                    axis=name,
                    value=f"{vmin:.2f}",
                    limit=f"{lo:g}",
                )
            )
        if vmax > hi + 1e-9:
            problems.append(
                Msg(
                    "%(axis)s reaches %(value)s mm, above the limit %(limit)s mm",
                    axis=name,
                    value=f"{vmax:.2f}",
                    limit=f"{hi:g}",
                )
            )
    if problems:
        raise ProgramError(
            Msg(
                "the %(radius)s mm circle about %(centre)s in %(plane)s does not fit the machine: "
                "%(problem)s. Move the centre or use a smaller radius.",
                radius=f"{spec.radius_mm:g}",
                centre=",".join(f"{v:g}" for v in spec.centre),
                plane=spec.plane,
                problem=joined(problems),
            )
        )


def _fmt(v: float) -> str:
    t = f"{v:.4f}"
    return "0.0000" if t == "-0.0000" else t


def generate(
    spec: TestSpec,
    volume: Optional[Sequence[float]] = None,
    params_hash: str = "none",
    date: Optional[str] = None,
    feed_notes: Sequence[str] = (),
) -> str:
    """The G-code program (text) for ``spec``; raises ProgramError if it does not fit.
    ``feed_notes``: header comment lines saying how the feed was chosen (limits.describe).

    The program pins the speed factor to 100 % (``M220 S100``): the test's timing and the
    analysis assume the feeds as written."""
    check_bounds(spec, volume)
    date = date or _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    a, b = spec.axes
    la, lb = AXIS[a], AXIS[b]
    body: List[str] = []
    w = body.append
    r_out = spec.radius_mm + spec.feed_in_mm
    first_angle = run_angles(spec, spec.directions[0])[0]
    start = spec.point(first_angle, r_out)
    w("G21 ; mm")
    w("G90 ; absolute")
    w("M220 S100 ; speed factor 100 %: the test runs at the feeds as written")
    w("M400")
    w("G91")
    w(f"G1 Z{spec.lift_mm:g} F600 ; lift before travel")
    w("G90")
    w(
        f"G1 X{_fmt(start[0])} Y{_fmt(start[1])} F{spec.travel_feed_mm_min:g}"
        " ; travel to above the start point"
    )
    w(f"G1 Z{_fmt(start[2])} F600 ; to the test height")
    mount, unmount = PAUSES[spec.pause_command]
    if spec.mount_pause:
        w("M400")
        w(mount)
    feed = spec.feed_mm_min
    for d in spec.directions:
        a0, sweep = run_angles(spec, d)
        w(
            f"; --- run {d}: feed-in at {a0:g} deg, sweep {sweep:g} deg, capture "
            f"{spec.capture_deg:g} deg from {spec.start_deg:g} deg"
        )
        w(f"M117 {RUN_MARKER} {d}")
        p = spec.point(a0, r_out)
        w(f"G1 {la}{_fmt(p[a])} {lb}{_fmt(p[b])} F{feed:g}")
        w("M400")
        w(f"G4 P{int(round(spec.dwell_s * 1000))} ; sync marker")
        p = spec.point(a0, spec.radius_mm)
        w(f"G1 {la}{_fmt(p[a])} {lb}{_fmt(p[b])} ; radial feed-in")
        for ang in arc_angles(spec, a0, sweep):
            p = spec.point(ang, spec.radius_mm)
            w(f"G1 {la}{_fmt(p[a])} {lb}{_fmt(p[b])}")
        p = spec.point(a0 + sweep, r_out)
        w(f"G1 {la}{_fmt(p[a])} {lb}{_fmt(p[b])} ; radial feed-out")
        w("M400")
        w(f"G4 P{int(round(spec.dwell_s * 1000))} ; end marker")
    w("; --- end of test: unmount the ballbar before moving the printer")
    w(f"M117 {END_MARKER}")
    if spec.mount_pause:
        w(unmount)
        w("G91")
        w(f"G1 Z{spec.lift_mm:g} F600")
        w("G90")
    body_text = "\n".join(body) + "\n"
    prog_hash = hashlib.sha256(body_text.encode()).hexdigest()[:12]
    meta = spec.metadata()
    header = [
        f"; KinComp ballbar test (ISO 230-4 circular test) - {date}",
        f"; plane {spec.plane}, radius {spec.radius_mm:g} mm, feed {spec.feed_mm_min:g} mm/min, "
        f"directions {'+'.join(spec.directions)}, centre "
        f"{','.join(f'{v:g}' for v in spec.centre)}",
        f"; params hash {params_hash}",
    ]
    if feed_notes:
        header += [f"; {n}" for n in feed_notes]
    elif spec.requested_feed_mm_min and spec.requested_feed_mm_min != spec.feed_mm_min:
        header.append(
            f"; feed capped from {spec.requested_feed_mm_min:g} mm/min "
            "to the slowest axis' max feed"
        )
    header += [f"; ballbar {k}: {v}" for k, v in meta.items()]
    header.append(f"; ballbar params_hash: {params_hash}")
    header.append(f"; ballbar program_hash: {prog_hash}")
    return "\n".join(header) + "\n" + body_text


def spec_from_program(text: str) -> Tuple[TestSpec, str]:
    """Recover the TestSpec and program hash from a program's ``; ballbar key: value`` lines."""
    meta = {}
    for line in text.splitlines()[:60]:
        if line.startswith("; ballbar ") and ":" in line:
            k, v = line[len("; ballbar ") :].split(":", 1)
            meta[k.strip()] = v.strip()
    if "plane" not in meta:
        raise ProgramError(Msg("not a KinComp ballbar program (no '; ballbar plane:' line)"))
    try:
        spec = TestSpec(
            plane=meta["plane"],
            centre=tuple(float(v) for v in meta["centre"].split(",")),
            radius_mm=float(meta["radius_mm"]),
            feed_mm_min=float(meta["feed_mm_min"]),
            feed_in_mm=float(meta["feed_in_mm"]),
            overshoot_deg=float(meta["overshoot_deg"]),
            capture_deg=float(meta["capture_deg"]),
            start_deg=float(meta["start_deg"]),
            dwell_s=float(meta.get("dwell_s", 1.0)),
            directions=tuple(meta.get("directions", "ccw,cw").split(",")),
            chord_error_um=float(meta.get("chord_error_um", 0.5)),
            lift_mm=float(meta.get("lift_mm", 10.0)),
            travel_feed_mm_min=float(meta.get("travel_feed_mm_min", 3000.0)),
            mount_pause=meta.get("mount_pause", "false") == "true",
            pause_command=meta.get("mount_pause_command", "M0"),
            motion={k: meta[k] for k in MotionSettings.KEYS if k in meta} or None,
            params_hash=meta.get("params_hash") or None,
            printer=meta.get("printer") or None,
            campaign=meta.get("campaign") or None,
            campaign_step=meta.get("campaign_step") or None,
            campaign_tests=meta.get("campaign_tests") or None,
        )
    except KeyError as exc:  # a header cut short (only its plane line)
        raise ProgramError(
            Msg("not a complete KinComp ballbar program header (no '%(key)s')", key=exc.args[0])
        ) from None
    except (TypeError, ValueError, OverflowError):
        raise ProgramError(Msg("a KinComp ballbar program header with unreadable values")) from None
    return spec, meta.get("program_hash", "")


def body_hash(spec: TestSpec) -> str:
    """The program hash of the test ``spec`` describes (the body does not depend on the date,
    the params hash or the campaign)."""
    text = generate(spec, date="-")
    for line in text.splitlines()[:60]:
        if line.startswith("; ballbar program_hash:"):
            return line.split(":", 1)[1].strip()
    return ""  # pragma: no cover - generate always writes it


def spec_dict(spec: TestSpec) -> dict:
    d = asdict(spec)
    d["centre"] = list(spec.centre)
    d["directions"] = list(spec.directions)
    return d
