"""A calibration belongs to one printer: KinComp's per-profile sets (no OctoPrint import).

OctoPrint keeps one printer profile per machine. What KinComp measured or learnt of a
machine (``PER_PROFILE``: the parameters, the home position, the motion limits) is kept per
profile id in the settings' ``profiles``; the top-level keys hold the set in force, and
``profile`` names the profile it belongs to. The rules, each decided here:

* a save while profile P is in force also records the keys it changed in P's set
  (:func:`recorded`);
* when another profile P becomes current, P's set replaces the one in force; a profile
  without a set (no ``params``) has no calibration: its parameters are the defaults and
  compensation stays off until it gets one (:func:`switch`, :func:`calibrated`);
* the first time (``profile`` empty: settings from before profiles) the set in force is
  adopted by the current profile, and the runs recorded before belong to it
  (``legacy_profile``).
"""

from __future__ import annotations

import copy
from typing import Any, Dict, List, Optional

from ...core.params import Params
from .schema import PER_PROFILE, defaults

DEFAULT_ID = "_default"  # OctoPrint's own default profile id


def profile_id(profile: Optional[Dict[str, Any]]) -> str:
    """The id of an OctoPrint printer profile (``_default`` when it has none)."""
    pid = (profile or {}).get("id")
    return pid if isinstance(pid, str) and pid else DEFAULT_ID


def profile_name(profile: Optional[Dict[str, Any]]) -> str:
    name = (profile or {}).get("name")
    return name if isinstance(name, str) and name else profile_id(profile)


def calibrated(s: Dict[str, Any]) -> bool:
    """Whether the profile in force has a calibration (a parameter set of its own); a set
    not yet adopted by a profile (settings from before profiles) counts as one."""
    return not s["profile"] or "params" in s["profiles"].get(s["profile"], {})


def deleted(kept: Dict[str, Any], existing: Optional[Dict[str, str]]) -> List[str]:
    """The ids of the profiles KinComp keeps something of (``kept``: ids as keys) that
    OctoPrint no longer has (``existing``: its profiles' ids; None: unknown, so none).
    Their sets and runs stay stored: a profile made again with the same id gets them back."""
    if existing is None:
        return []
    return sorted(pid for pid in kept if pid and pid != DEFAULT_ID and pid not in existing)


def other_profile(owner: Optional[str], s: Dict[str, Any]) -> bool:
    """Whether something recorded for printer profile ``owner`` (a run, a campaign; empty:
    from before profiles, i.e. ``legacy_profile``'s) belongs to another printer than the
    one whose set is in force in ``s``: it must never be applied there."""
    mine = owner or s.get("legacy_profile") or ""
    return bool(s.get("profile")) and bool(mine) and mine != s["profile"]


def applied_elsewhere(
    owner: Optional[str], s: Dict[str, Any], names: Optional[Dict[str, str]] = None
) -> Dict[str, Any]:
    """The warning finding ``applied.other_profile`` (wire form) of a result recorded for
    printer profile ``owner`` that was applied anyway (``force``) while another profile's
    set is in force in ``s``; ``names``: the profiles' names by id, if known."""
    from ...calibration.findings import warning
    from ...core.messages import Msg

    mine = owner or s.get("legacy_profile") or ""
    names = names or {}
    return warning(
        "applied.other_profile",
        Msg(
            "Applied to printer profile %(current)s although it was measured on printer "
            "profile %(owner)s (applied anyway: force).",
            current=names.get(s["profile"]) or s["profile"],
            owner=names.get(mine) or mine,
        ),
        Msg(
            "Make sure both profiles are the same printer; if not, measure this printer and "
            "apply its own result."
        ),
        run_profile=mine or None,
        profile_in_force=s.get("profile") or None,
    ).to_wire()


def owners(s: Dict[str, Any], params_hash: str) -> List[str]:
    """The ids of the other printer profiles (not the one in force in ``s``) whose parameter
    set has the hash ``params_hash`` (a compensated file's marker: which printer it was
    compensated for)."""
    return sorted(
        pid
        for pid, entry in s["profiles"].items()
        if pid != s["profile"]
        and "params" in entry
        and Params.from_dict(entry["params"]).hash() == params_hash
    )


def recorded(stored: Dict[str, Any], new: Dict[str, Any]) -> Dict[str, Any]:
    """``new`` (validated settings) with the per-profile keys that differ from ``stored``,
    or that the profile in force already keeps, written into that profile's set."""
    pid = new["profile"]
    if not pid:
        return new
    out = copy.deepcopy(new)
    entry = out["profiles"].setdefault(pid, {})
    for key in PER_PROFILE:
        if key in entry or new[key] != stored[key]:
            entry[key] = copy.deepcopy(new[key])
    if not entry:
        del out["profiles"][pid]
    return out


def switch(s: Dict[str, Any], pid: str) -> Optional[Dict[str, Any]]:
    """The change that puts profile ``pid``'s set in force over the settings ``s``, or
    None when it already is. The set in force before stays recorded under its own profile
    (every save records it); settings from before profiles are adopted by ``pid``."""
    if s["profile"] == pid:
        return None
    profiles = copy.deepcopy(s["profiles"])
    if not s["profile"]:  # from before profiles: this is the printer they were made on
        profiles[pid] = {key: copy.deepcopy(s[key]) for key in PER_PROFILE}
        return {"profile": pid, "profiles": profiles, "legacy_profile": pid}
    entry = profiles.get(pid, {})
    base = defaults()
    data = {key: copy.deepcopy(entry.get(key, base[key])) for key in PER_PROFILE}
    data.update(profile=pid, profiles=profiles)
    return data
