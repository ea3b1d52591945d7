"""A result's findings as the API and the browser carry them (no OctoPrint import here).

An analysis returns ``findings`` (:class:`..ballbar.findings.Finding` objects or their
dicts; ``findings_i18n``, when given, is preferred: its messages keep their templates) and
``trusted``; one that does not yet (older analyses) has its free-text notes
turned into info findings. Stored with a run as ``findings`` (worst first, message and
advice as translatable ``{"text", "template", "params"}``) and ``trusted`` (False when any
finding is an error, or the analysis said so). Applying an untrusted run needs ``force``.
"""

from __future__ import annotations

from typing import Any, Dict, List, Tuple

from ...calibration.findings import SEVERITIES, Finding, from_notes, trusted, worst_first
from ...calibration.result import verdict
from ...core.messages import Msg, as_dict


def _text(value: Any) -> Dict[str, Any]:
    if isinstance(value, dict) and "text" in value:
        return dict(value)
    if value is None:
        return {"text": ""}
    return as_dict(value if isinstance(value, Msg) else str(value))


def _wire(item: Any) -> Dict[str, Any]:
    if isinstance(item, Finding):
        return item.to_wire()
    if isinstance(item, dict):
        severity = item.get("severity") if item.get("severity") in SEVERITIES else "warning"
        return {
            "code": str(item.get("code") or "finding"),
            "severity": severity,
            "message": _text(item.get("message")),
            "advice": _text(item.get("advice")),
            "evidence": dict(item.get("evidence") or {}),
        }
    return from_notes([item])[0].to_wire()


def findings_of(result: Dict[str, Any]) -> Tuple[List[Dict[str, Any]], bool]:
    """(findings for the wire, worst first; trusted) of an analysis ``result`` (its
    ``findings_i18n``, the translatable form, where the analysis gives it), or of a stored
    run (whose ``findings`` are in that form already)."""
    items = result.get("findings_i18n") or result.get("findings")
    if items is None:
        items = from_notes(result.get("notes") or [])
    wire = worst_first(_wire(f) for f in items)
    return wire, result.get("trusted") is not False and trusted(wire)


def verdict_of(run: Dict[str, Any]) -> Dict[str, Any]:
    """The decision a stored run (or an analysis result) stands for, from its findings
    (``calibration/result.py``: :func:`verdict`); its reason in the translatable form. A
    run its analysis says is not trusted is never to be applied, whatever its findings."""
    wire, ok = findings_of(run)
    out = verdict(wire)
    if not ok and out["decision"] != "do_not_apply":
        out = {"decision": "do_not_apply", "reason": out["reason"] or {"text": ""}}
    return out


def _msg(d: Any) -> Any:
    """A message from its wire form (``as_dict``), nested parameters too."""
    if not isinstance(d, dict):
        return d
    template = d.get("template")
    if not template:
        return d.get("text", "")
    return Msg(template, **{k: _msg(v) for k, v in (d.get("params") or {}).items()})


def refusal(run: Dict[str, Any]) -> Any:
    """Why applying ``run`` needs an explicit "apply anyway" (a core message naming its
    first error), or None when the run is trusted (runs stored before findings were are)."""
    if run.get("trusted", True) is not False:
        return None
    errors = [f for f in run.get("findings") or [] if f.get("severity") == "error"]
    reason = _msg(errors[0]["message"]) if errors else ""
    return Msg(
        "This result is not trusted (%(reason)s): read its findings first. To apply "
        'it anyway, confirm with "force": true.',
        reason=reason or "-",
    )
