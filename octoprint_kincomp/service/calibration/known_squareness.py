"""The printer's squareness as its run history knows it (no OctoPrint import), for the
out-of-plane motion of a vertical test analysed alone (:func:`.ballbar.analysis.analyse`'s
``known_squareness_um_per_m``; :data:`.ballbar.model.OUT_OF_PLANE`).

Per key (``xy``, ``xz``, ``yz``) the proposal of the newest trusted run of the printer
profile that measured that plane: a single test of the plane (any source: trace, live capture,
summary, printed artifact) or a campaign's joint analysis that included it. The proposal is
the printer's own squareness as the parameters state it (current + residual); the analysis
takes off what the parameters in force correct. Runs that failed, are untrusted or measured
nothing of the plane are skipped; a simulated run only informs a simulated trace and a
measured run only a measured one (demo mode's printer is not the real one). Values in um/m.
"""

from __future__ import annotations

import math
from typing import Any, Dict, Iterable, List, Tuple

KEYS = ("xy", "xz", "yz")


def _planes(run: Dict[str, Any]) -> List[str]:
    """The planes ``run`` measured (upper case)."""
    d = run.get("diagnostics") or {}
    camp = d.get("campaign")
    if isinstance(camp, dict):
        return [str(p).upper() for p in camp.get("planes") or ()]
    return [str(d["plane"]).upper()] if d.get("plane") else []


def _simulated(run: Dict[str, Any]) -> bool:
    d = run.get("diagnostics") or {}
    return bool(d.get("simulated") or run.get("simulated"))


def _source(run: Dict[str, Any], plane: str) -> str:
    what = "campaign" if run.get("source") == "campaign" else plane
    return f"run {run.get('id')} ({what}, {run.get('date') or '?'})"


def known_squareness(runs: Iterable[Dict[str, Any]]) -> Dict[str, Dict[str, Any]]:
    """From ``runs`` (one profile's documents, newest first): ``{"measured": {"values",
    "sources"}, "simulated": {...}}``, ``values`` um/m by key and ``sources`` the run each
    came from (its id, what it measured, its date)."""
    out = {k: {"values": {}, "sources": {}} for k in ("measured", "simulated")}
    for run in runs:
        if run.get("status", "ok") != "ok" or run.get("trusted") is False:
            continue
        sq = (run.get("proposed") or {}).get("squareness_um_per_m") or {}
        into = out["simulated" if _simulated(run) else "measured"]
        for plane in _planes(run):
            key = plane.lower()
            value = sq.get(key)
            if key not in KEYS or key in into["values"]:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            if not math.isfinite(value):
                continue
            into["values"][key] = float(value)
            into["sources"][key] = _source(run, plane)
    return out


def for_trace(known: Dict[str, Dict[str, Any]], trace) -> Tuple[Dict[str, float], Dict[str, str]]:
    """The values and sources of :func:`known_squareness` that fit ``trace`` (a simulated
    trace takes the simulated runs'); ({}, {}) when ``known`` is empty."""
    meta = getattr(trace, "meta", None) or {}
    simulated = str(meta.get("simulated", "")).lower() == "true"
    part = (known or {}).get("simulated" if simulated else "measured") or {}
    return dict(part.get("values") or {}), dict(part.get("sources") or {})
