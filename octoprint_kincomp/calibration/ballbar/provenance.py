"""Where a trace comes from (issue 34): its program, the firmware's compensation it ran with,
and what the user must confirm before its result can be applied.

* **Program identity** (:func:`program_findings`): a trace records its program's hash; the
  metadata must describe that program (regenerated from it, byte for byte). Another plane,
  radius or feed written into the metadata no longer matches: an error (a campaign refuses
  such a trace outright, ``campaign.check_traces``).
* **Confirmation** (:func:`needs_confirmation`): a trace captured while KinComp printed its
  program, or uploaded with the hash of a program KinComp printed, is tied to that program
  (``confirmed``). Any other trace is what its metadata says, and some of that the data
  cannot check: the plane always (an XZ and a YZ test of the same radius and feed move
  alike), and for an angle-domain trace also the radius and the feed (R50 at F925 and R100
  at F1850 have the same angular speed; a time series shows it in its ramps, an angle
  export does not). The result then says what to confirm (``needs_confirmation``) and the
  plugin's ``/apply`` refuses it until the request confirms those values.
* **Firmware compensation** (:func:`firmware_of`, :func:`firmware_findings`): the state
  recorded with the test (the trace's ``firmware_compensation`` key, else what the caller
  knows); a test measured with the firmware compensating is what the firmware left over,
  and the advice says which side to keep.

Units: um/m, um, ppm as in the diagnostics.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional

from ...core.messages import Msg, joined
from ...firmware.compensation import FirmwareCompensation
from ..findings import Finding, error, info
from .formats import TraceError
from .program import ProgramError, body_hash

META_KEY = "firmware_compensation"  # the trace's record of the firmware's compensation
CONFIRMABLE = ("plane", "radius_mm", "feed_mm_min", "sensor", "firmware_compensation")
# what the user confirms for the two keys that are no metadata: the analysis took the sensor
# as checked (its sign and gain) and the firmware as compensating nothing itself
ASSUMED = {"sensor": "checked", "firmware_compensation": "none"}


def program_mismatch(meta: Dict[str, str]) -> Optional[Dict[str, str]]:
    """``{"recorded", "described"}`` when the metadata describes another program than the
    hash it records (only for metadata that records everything its program depends on:
    traces written since the campaign format); None when they match or cannot be
    compared. Raises TraceError for metadata no program can have."""
    want = meta.get("program_hash", "").strip()
    if not want or want.lower() in ("none", "-") or "chord_error_um" not in meta:
        return None
    from .timing import spec_from_meta

    try:
        got = body_hash(spec_from_meta(meta))
    except ProgramError as exc:
        raise TraceError(str(exc)) from None
    return None if got == want else {"recorded": want, "described": got}


def program_findings(meta: Dict[str, str]) -> List[Finding]:
    """An error when the trace's metadata no longer describes the program it records."""
    bad = program_mismatch(meta)
    if bad is None:
        return []
    return [
        error(
            "program.mismatch",
            Msg(
                "The trace's metadata does not describe the program it was recorded with (the "
                "plane, radius, feed and angles it states are not those of the program it "
                "names): the metadata was edited (a plane key changed, say) or belongs to "
                "another test. The result is that of the test as labelled, not necessarily of "
                "the one that ran."
            ),
            Msg(
                "Upload the trace with the metadata it was recorded with, or the metadata of "
                "the program that was printed; do not apply this result."
            ),
            **bad,
        )
    ]


def needs_confirmation(
    meta: Dict[str, str],
    timed: bool,
    timing_ok: bool,
    confirmed: Optional[str],
    firmware_known: bool = True,
) -> Optional[Dict[str, object]]:
    """What the user must confirm before the result of a trace with ``meta`` is applied:
    ``{"confirm": [keys], "stated": {key: value}}`` (keys of :data:`CONFIRMABLE`); None
    when ``confirmed`` (how the trace is tied to its program) is given. ``timed``: a time
    series, whose timing (``timing_ok``: no timing or ramp error) confirms radius and feed
    and whose radial steps check the sensor; an angle trace also asks for the sensor
    (``"checked"``: its sign and gain were checked). ``firmware_known`` false (the trace
    records no firmware state and the caller gave none) asks for the firmware's
    compensation (``"none"``: it compensated nothing itself): an M425/M852 that matches the
    printer leaves no trace in the data."""
    if confirmed:
        return None
    keys = ["plane"] if timed and timing_ok else ["plane", "radius_mm", "feed_mm_min"]
    if not timed:
        keys.append("sensor")
    if not firmware_known:
        keys.append("firmware_compensation")
    stated: Dict[str, object] = {"plane": str(meta.get("plane", "")).strip().upper()}
    for key in ("radius_mm", "feed_mm_min"):
        stated[key] = _stated_number(meta.get(key))
    for key in ("sensor", "firmware_compensation"):
        if key in keys:
            stated[key] = ASSUMED[key]
    return {"confirm": keys, "stated": stated}


def _stated_number(text) -> Optional[float]:
    """A metadata number as the trace states it; None when it states none (or no number)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


NAMES = {
    "plane": Msg("the plane"),
    "radius_mm": Msg("the radius"),
    "feed_mm_min": Msg("the feed"),
    "sensor": Msg("the sensor's sign and gain (taken as right)"),
    "firmware_compensation": Msg(
        "whether the firmware compensated skew, backlash or scale itself (taken as not)"
    ),
}


def confirmation_finding(need: Dict[str, object]) -> Finding:
    """The info finding that goes with :func:`needs_confirmation`."""
    st = need["stated"]
    what = joined([NAMES[k] for k in need["confirm"]])
    return info(
        "program.unconfirmed",
        Msg(
            "KinComp cannot tie this trace to a program it printed (it was not captured while "
            "KinComp printed it, and the program it names is not one KinComp printed): it is what "
            "its metadata says, %(plane)s R%(radius)s F%(feed)s, and the data cannot check "
            "%(what)s. Confirm them before the result is applied.",
            plane=st.get("plane") or "?",
            radius=f"{st['radius_mm']:g}" if st.get("radius_mm") is not None else "?",
            feed=f"{st['feed_mm_min']:g}" if st.get("feed_mm_min") is not None else "?",
            what=what,
        ),
        _confirmation_advice(need["confirm"]),
        confirm=list(need["confirm"]),
        stated=dict(st),
    )


def _confirmation_advice(keys) -> Msg:
    """What to check for the keys to confirm."""
    if "firmware_compensation" in keys and "sensor" in keys:
        return Msg(
            "Check that the test was printed in that plane with that radius and feed (a trace "
            "of R50 at F925 labelled R100 F1850 halves every value), that the sensor reads a "
            "known step right (one that reads a 1 mm step as 1.03 mm reads every error that "
            "much too high), and that the firmware's own compensation was off (M503: M425, "
            "M852, M556, M579, SET_SKEW; one that was on makes every value here only what it "
            "left over)."
        )
    if "firmware_compensation" in keys:
        return Msg(
            "Check that the test was printed in that plane with that radius and feed, and that "
            "the firmware's own compensation was off (M503: M425, M852, M556, M579, SET_SKEW; "
            "one that was on makes every value here only what it left over)."
        )
    if "sensor" in keys:
        return Msg(
            "Check that the test was printed in that plane with that radius and feed (a trace "
            "of R50 at F925 labelled R100 F1850 halves every value), and that the sensor reads "
            "a known step right (one that reads a 1 mm step as 1.03 mm reads every error that "
            "much too high)."
        )
    return Msg(
        "Check that the test was printed in that plane with that radius and feed (a trace "
        "of R50 at F925 labelled R100 F1850 halves every value)."
    )


def firmware_of(
    meta: Dict[str, str], given: Optional[FirmwareCompensation]
) -> FirmwareCompensation:
    """The firmware's compensation the test ran with: the trace's record first, else
    ``given`` (the caller's knowledge), else unknown."""
    if META_KEY in meta:
        return FirmwareCompensation.from_text(meta[META_KEY])
    return given if given is not None else FirmwareCompensation()


KIND_NAMES = {"skew": Msg("skew"), "backlash": Msg("backlash"), "scale": Msg("axis scale")}


def firmware_findings(fw: FirmwareCompensation, plane: str) -> List[Finding]:
    """What the result is with the firmware's compensation as recorded: on top of it (an
    info that says which side to keep), or on an unknown state (an info)."""
    if fw.active:
        kinds = fw.kinds()
        return [
            info(
                "firmware.in_force",
                Msg(
                    "The firmware compensated %(kinds)s itself during this test (%(cmds)s): "
                    "the errors here are what it left over, and the proposal holds only those, "
                    "on top of the firmware's (its record says so: KinComp will not call the "
                    "two double compensation).",
                    kinds=joined([KIND_NAMES[k] for k in kinds]),
                    cmds=fw.text(),
                ),
                Msg(
                    "Keep the firmware's compensation as it is: turning it off brings back what "
                    "it corrected. To let KinComp do all of it instead, turn the firmware's off "
                    "(%(off)s) and test again.",
                    off="; ".join(fw.off_command(k) for k in kinds),
                ),
                firmware=fw.to_dict(),
            )
        ]
    if not fw.known:
        return [
            info(
                "firmware.unknown",
                Msg(
                    "Whether the firmware compensated skew, backlash or axis scale itself "
                    "during this test is not recorded: if it did (M852, M425, M556, M579, "
                    "SET_SKEW), the values here are only what it left over."
                ),
                Msg("Print the test from the plugin: it records the firmware's M503 settings."),
            )
        ]
    return []


def with_firmware(diag: Dict[str, object], fw: FirmwareCompensation, axes) -> Dict[str, object]:
    """The printer's own errors: the fitted residual plus what the firmware corrected (skew,
    backlash per side, scale mismatch; keys as the diagnostics'); {} when it corrected none
    or its values are not known."""
    out: Dict[str, object] = {}
    a, b = axes
    key = (a + b).lower()
    skew = fw.skew_um_per_m()
    if skew is not None and diag.get("squareness_um_per_m") is not None:
        out["squareness_um_per_m"] = float(diag["squareness_um_per_m"]) + skew.get(key, 0.0)
    scale = fw.scale_ppm()
    if scale is not None and diag.get("scale_mismatch_ppm") is not None:
        extra = scale.get(a.lower(), 0.0) - scale.get(b.lower(), 0.0)
        out["scale_mismatch_ppm"] = float(diag["scale_mismatch_ppm"]) + extra
    bl = fw.backlash_um()
    if bl is not None and isinstance(diag.get("backlash_um"), dict):
        sides = {}
        for side, v in diag["backlash_um"].items():
            axis = a if side.startswith("a") else b
            sides[side] = None if v is None else float(v) + bl.get(axis.lower(), 0.0)
        out["backlash_um"] = sides
    return out
