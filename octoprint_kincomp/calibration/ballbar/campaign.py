"""A calibration campaign: the set of ballbar tests that calibrates the whole volume in one round,
and the checks that a set of traces really is one complete campaign.

Planning (:func:`plan_campaign`): on the machine volume ``x0,x1,y0,y1,z0,z1`` (mm), XY with
``radius_xy`` (default 100 mm) about the middle of the bed, ``xy_height`` above ``z0``;
XZ and YZ with ``radius_vertical`` (default 50 mm) about the middle of the bed, at the lowest
height where the arc (with its overshoot and feed-in) stays ``margin_mm`` above ``z0``;
optionally XY again at a second height (how squareness changes with Z) and at a second feed
(whether the servo lag is proportional to speed, which servo pre-compensation assumes). Every
program pauses (``M0``) to mount and unmount the bar and carries the campaign id, its step
name and the names of all steps in its metadata, so traces tell which campaign they belong to.
:func:`write_campaign` writes the programs and ``campaign.json`` (the manifest).

Checks (:func:`check_traces`, before any fit): every file is a trace, all come from one
printer, one parameter set (``params_hash``) and one campaign, no planned test is missing, no
test is there twice (the same plane at the same height and feed), and each trace's metadata
describes the program it claims to come from (the program is regenerated from the metadata
and its hash compared). Each failure raises :class:`CampaignError` naming the file.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple, Union

from ...core.messages import Msg, joined
from ...firmware.motion_limits import (
    LimitsError,
    MotionLimits,
    circle_feed,
    describe,
    require_known,
)
from ...firmware.planner import settings_from_limits
from .formats import AngleTrace, NativeTrace, TraceError, meta_float, meta_plane
from .program import (
    DEFAULT_FEED,
    ProgramError,
    TestSpec,
    body_hash,
    check_bounds,
    generate,
    pause_for,
    run_angles,
)

MANIFEST_NAME = "campaign.json"
MANIFEST_VERSION = 1


class CampaignError(TraceError):
    """A set of traces is not one complete, consistent campaign; names the file at fault."""


@dataclass
class Step:
    name: str  # "xy", "xz", "yz", "xy-z<height>", "xy-f<feed>"
    spec: TestSpec
    file: str
    feed_notes: List[str] = field(default_factory=list)  # how its feed was chosen


def test_words(name: str) -> Union[Msg, str]:
    """A campaign test's plan name (``xy``, ``xy-z110``, ``xy-f3700``: a key in files and
    metadata) in the user's words: its plane, and what sets an extra XY test apart."""
    plane, _, variant = name.partition("-")
    if variant.startswith("f"):
        return Msg("%(plane)s at %(feed)s mm/min", plane=plane.upper(), feed=variant[1:])
    if variant.startswith("z"):
        return Msg("%(plane)s at Z %(z)s mm", plane=plane.upper(), z=variant[1:])
    return name.upper()  # (a plane's name, the same in every language)


def _centre_height(spec: TestSpec, z0: float, margin: float) -> float:
    """Lowest pivot height (mm) that keeps a vertical test ``margin`` above ``z0``."""
    low = 0.0
    for d in spec.directions:
        a0, sweep = run_angles(spec, d)
        for k in range(361):
            ang = math.radians(a0 + sweep * k / 360.0)
            low = min(low, (spec.radius_mm + spec.feed_in_mm) * math.sin(ang))
    return math.ceil(z0 + margin - low)


def _tests_on(
    volume: Sequence[float],
    radius_xy: float,
    radius_vertical: float,
    feed: float,
    xy_height: float,
    second_height: Optional[float],
    second_feed: Optional[float],
    margin_mm: float,
) -> List[Tuple[str, dict]]:
    """(name, TestSpec fields) of the campaign's tests on ``volume`` (x0,x1,y0,y1,z0,z1 mm),
    centred on the bed: XY ``xy_height`` above the bed, XZ and YZ as low as their circle
    allows (``margin_mm`` above it), XY again at ``second_height`` and at ``second_feed``
    (mm/min) when given."""
    x0, x1, y0, y1, z0, z1 = (float(v) for v in volume)
    mx, my = round((x0 + x1) / 2, 1), round((y0 + y1) / 2, 1)

    def xy(z, f):
        return dict(plane="XY", centre=(mx, my, z), radius_mm=radius_xy, feed_mm_min=f)

    plan: List[Tuple[str, dict]] = [("xy", xy(z0 + xy_height, feed))]
    for plane in ("XZ", "YZ"):
        probe = TestSpec(plane=plane, centre=(mx, my, 0.0), radius_mm=radius_vertical)
        zc = _centre_height(probe, z0, margin_mm)
        spec = dict(plane=plane, centre=(mx, my, zc), radius_mm=radius_vertical, feed_mm_min=feed)
        plan.append((plane.lower(), spec))
    if second_height is not None:
        plan.append((f"xy-z{second_height:g}", xy(second_height, feed)))
    if second_feed is not None:
        plan.append((f"xy-f{second_feed:g}", xy(z0 + xy_height, second_feed)))
    return plan


def plan_campaign(
    volume: Sequence[float],
    radius_xy: float = 100.0,
    radius_vertical: float = 50.0,
    feed: float = DEFAULT_FEED,
    xy_height: float = 10.0,
    second_height: Optional[float] = None,
    second_feed: Optional[float] = None,
    max_feed: Optional[Dict[str, float]] = None,
    printer: Optional[str] = None,
    campaign_id: Optional[str] = None,
    margin_mm: float = 5.0,
    limits: Optional[MotionLimits] = None,
    require_limits: bool = False,
    firmware: Optional[str] = None,
) -> List[Step]:
    """The campaign's tests on ``volume`` (x0,x1,y0,y1,z0,z1 mm); raises ProgramError naming
    the test that does not fit or cannot run within the printer's motion ``limits`` (with
    ``max_feed``, axis max feeds in mm/min, the lower of each applies; see
    :func:`.limits.circle_feed`); ``require_limits``: refuse vertical tests whose Z max feed
    is not known; ``firmware`` (``marlin``, ``klipper``, ``reprapfirmware``; None: not known,
    else ``limits.firmware``): the pause the programs write and the planner their headers
    record (:func:`.program.pause_for`, ``planner.settings_from_limits``)."""
    if volume is None or len(volume) != 6:
        raise ProgramError(Msg("a campaign needs the machine volume X0,X1,Y0,Y1,Z0,Z1 (mm)"))
    cid = campaign_id or "c" + _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    plan = _tests_on(
        volume, radius_xy, radius_vertical, feed, xy_height, second_height, second_feed, margin_mm
    )
    names = ",".join(n for n, _ in plan)
    known = MotionLimits.from_feeds(max_feed, "max feed").combined(limits)
    firmware = firmware or (limits.firmware if limits is not None else None)
    settings = settings_from_limits(limits, firmware)
    motion = settings.metadata() if settings is not None else None
    steps = []
    for i, (name, kw) in enumerate(plan, 1):
        requested = kw["feed_mm_min"]
        try:
            choice = circle_feed(kw["plane"], kw["radius_mm"], requested, known)
            if require_limits:
                require_known(choice, kw["plane"])
            kw["feed_mm_min"] = choice.feed_mm_min
            spec = TestSpec(
                requested_feed_mm_min=requested,
                mount_pause=True,
                pause_command=pause_for(firmware),
                motion=motion,
                printer=printer,
                campaign=cid,
                campaign_step=name,
                campaign_tests=names,
                **kw,
            )
            check_bounds(spec, volume)
        except (ProgramError, LimitsError) as exc:
            raise ProgramError(
                Msg(
                    "campaign test %(name)s: %(error)s",
                    name=test_words(name),
                    error=exc.args[0] if exc.args else str(exc),
                )
            ) from None
        steps.append(Step(name, spec, f"ballbar_{i}_{name}.gcode", describe(choice)))
    if second_feed is not None and steps[-1].spec.feed_mm_min == steps[0].spec.feed_mm_min:
        raise ProgramError(
            Msg(
                "the second XY feed is capped to the first one (%(feed)s "
                "mm/min) by the axis limits: it cannot test speed dependence",
                feed=f"{steps[0].spec.feed_mm_min:g}",
            )
        )
    return steps


def write_campaign(
    steps: Sequence[Step], outdir: str, volume: Sequence[float], params_hash: str = "none"
) -> Dict[str, object]:
    """Write the programs and the manifest into ``outdir``; returns the manifest."""
    os.makedirs(outdir, exist_ok=True)
    manifest: Dict[str, object] = {
        "kincomp_campaign": MANIFEST_VERSION,
        "id": steps[0].spec.campaign,
        "created": _dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "volume_mm": [float(v) for v in volume],
        "params_hash": params_hash,
        "printer": steps[0].spec.printer,
        "steps": [],
        "how": "print the programs in this order with the same parameters in force; each "
        "pauses to mount the bar and to unmount it; then analyse all traces together: "
        "python -m octoprint_kincomp analyze T1 T2 ... --manifest campaign.json",
    }
    for step in steps:
        text = generate(step.spec, params_hash=params_hash, feed_notes=step.feed_notes)
        with open(os.path.join(outdir, step.file), "w", encoding="utf-8") as f:
            f.write(text)
        s = step.spec
        manifest["steps"].append(
            {
                "name": step.name,
                "file": step.file,
                "plane": s.plane,
                "centre": list(s.centre),
                "radius_mm": s.radius_mm,
                "feed_mm_min": s.feed_mm_min,
                "program_hash": body_hash(s),
            }
        )
    with open(os.path.join(outdir, MANIFEST_NAME), "w", encoding="utf-8") as f:
        json.dump(manifest, f, indent=2)
    return manifest


def load_manifest(path: str) -> Dict[str, object]:
    try:
        with open(path, encoding="utf-8") as f:
            m = json.load(f)
    except (OSError, ValueError) as exc:
        raise CampaignError(
            Msg(
                "%(file)s: cannot read the campaign manifest (%(error)s)",
                file=os.path.basename(path),
                error=str(exc),
            )
        ) from None
    if (
        not isinstance(m, dict)
        or m.get("kincomp_campaign") != MANIFEST_VERSION
        or not isinstance(m.get("steps"), list)
    ):
        raise CampaignError(
            Msg("%(file)s: not a KinComp campaign manifest", file=os.path.basename(path))
        )
    return m


# ---------------------------------------------------------------------------------------
# checks


def _key(meta: Dict[str, str]) -> Tuple[str, float, float]:
    """(plane, height of the plane, feed): what makes two tests of a plane different."""
    plane = meta_plane(meta)
    centre = [float(v) for v in meta.get("centre", "0,0,0").split(",")]
    off = {"XY": 2, "XZ": 1, "YZ": 0}[plane]
    return plane, round(centre[off], 1), round(meta_float(meta, "feed_mm_min", 0.0), 1)


def _known(v: Optional[str]) -> bool:
    return bool(v) and v.strip().lower() not in ("none", "-", "")


def _first_differing(items, key):
    """(file, value) of the first item and the first one that differs in metadata ``key``."""
    known = [(n, t.meta.get(key, "").strip()) for n, t in items if _known(t.meta.get(key))]
    for n, v in known[1:]:
        if v != known[0][1]:
            return known[0], (n, v)
    return None


def check_traces(
    items: Sequence[Tuple[str, object]],
    current_hash: Optional[str] = None,
    manifest: Optional[Dict[str, object]] = None,
) -> None:
    """Raise CampaignError unless ``items`` ([(file name, trace)]) form one campaign."""
    if len(items) < 2:
        raise CampaignError(Msg("a campaign needs at least two traces"))
    for name, tr in items:
        if not isinstance(tr, (NativeTrace, AngleTrace)):
            raise CampaignError(
                Msg(
                    "%(file)s: a campaign needs measured traces (native or "
                    "angle CSV), not a summary",
                    file=name,
                )
            )
    for key, what in (
        ("printer", Msg("printer")),
        ("params_hash", Msg("parameter set")),
        ("campaign", Msg("campaign")),
    ):
        diff = _first_differing(items, key)
        if diff:
            (f1, v1), (f2, v2) = diff
            raise CampaignError(
                Msg(
                    "%(file2)s comes from another %(what)s than %(file1)s (%(key)s %(value2)s, not "
                    "%(value1)s): a campaign must be measured on one printer with the same "
                    "parameters in force",
                    file1=f1,
                    file2=f2,
                    what=what,
                    key=key,
                    value1=v1,
                    value2=v2,
                )
            )
    if current_hash:
        for name, tr in items:
            h = tr.meta.get("params_hash", "")
            if _known(h) and h.strip() != current_hash:
                raise CampaignError(
                    Msg(
                        "%(file)s was measured with parameters %(hash)s, but the current "
                        "parameters are %(current)s: give the parameters that were in force",
                        file=name,
                        hash=h.strip(),
                        current=current_hash,
                    )
                )
    for name, tr in items:
        _check_program(name, tr.meta)
    seen: Dict[object, str] = {}
    for name, tr in items:
        key = tr.meta.get("campaign_step") or _key(tr.meta)
        if key in seen:
            plane, height, feed = _key(tr.meta)
            raise CampaignError(
                Msg(
                    "%(file1)s and %(file2)s are the same test (%(plane)s at %(height)s mm, "
                    "%(feed)s mm/min): keep one of them",
                    file1=seen[key],
                    file2=name,
                    plane=plane,
                    height=f"{height:g}",
                    feed=f"{feed:g}",
                )
            )
        seen[key] = name
    _check_complete(items, manifest)


def _check_program(name: str, meta: Dict[str, str]) -> None:
    """The metadata must describe the program its ``program_hash`` names (when it records
    everything the program depends on: traces written since the campaign format)."""
    from .provenance import program_mismatch

    try:
        bad = program_mismatch(meta)
    except (ProgramError, TraceError) as exc:
        raise CampaignError(Msg("%(file)s: %(error)s", file=name, error=str(exc))) from None
    if bad is not None:
        raise CampaignError(
            Msg(
                "%(file)s: its metadata does not match the test program it names: the file "
                "was edited or belongs to another test",
                file=name,
            )
        )


def _check_complete(items, manifest: Optional[Dict[str, object]]) -> None:
    present = {tr.meta.get("campaign_step", "") for _, tr in items}
    planned: List[str] = []
    if manifest is not None:
        steps = manifest.get("steps") or []
        planned = [str(s.get("name")) for s in steps if isinstance(s, dict)]
        by_hash = {
            str(s.get("program_hash")): str(s.get("name")) for s in steps if isinstance(s, dict)
        }
        for name, tr in items:
            h = tr.meta.get("program_hash", "").strip()
            if h not in by_hash:
                raise CampaignError(
                    Msg(
                        "%(file)s: it was not measured with one of this campaign's test "
                        "programs (another campaign's, or an earlier plan's)",
                        file=name,
                    )
                )
            present.add(by_hash[h])
    else:
        lists = {tr.meta.get("campaign_tests", "") for _, tr in items} - {""}
        if lists:
            planned = sorted(lists, key=len)[-1].split(",")
    missing = [p for p in planned if p and p not in present]
    if missing:
        raise CampaignError(
            Msg(
                "the campaign is incomplete: %(missing)s missing (planned: %(planned)s); nothing "
                "is proposed from a partial campaign",
                missing=joined([Msg("test %(name)s", name=test_words(m)) for m in missing]),
                planned=joined([test_words(m) for m in planned if m]),
            )
        )
