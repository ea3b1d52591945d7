"""The result document: the one shape every analysis returns, and the decision it stands for.

Every analysis (a ballbar test, a campaign's joint fit, a printed artifact, typed numbers)
returns :func:`result_document`:

* ``diagnostics``: what was measured (each analysis' own keys, units in their names);
* ``parameters``: the proposed params document (the parameters in force plus the residual);
* ``firmware``: the same parameters as each firmware's own compensation;
* ``findings``: what was checked and seen, worst first (English text), ``findings_i18n`` the
  same with translatable messages (:meth:`Finding.to_wire`);
* ``trusted``: False when any finding is an error (:func:`..findings.trusted`);
* ``verdict``: the decision the result is for (:func:`verdict`);
* ``notes``: free-text remarks for the record; ``plot`` / ``plots``: what the UI draws;
* ``needs_confirmation``: what the user must confirm before the proposal is applied
  (``{"confirm": ["plane", "radius_mm", "feed_mm_min"], "stated": {...}}``: a trace that is
  not tied to a program KinComp printed, ``ballbar/provenance.py``), or None. It does not
  change the verdict; the plugin's ``/apply`` refuses such a run until the request confirms
  the stated values.

The verdict is decided here only, from the findings: ``do_not_apply`` when a finding is an
error (the result cannot be trusted; applying it needs an explicit "apply anyway"),
``apply_with_care`` when one is a warning (it holds, but something deserves a look first),
else ``apply``; ``reason`` is the message of the worst finding behind it (None for
``apply``). A stored run gets its verdict from its stored findings the same way.
"""

from __future__ import annotations

from typing import Any, Dict, Iterable, List, Optional, Sequence

from ..core.messages import as_dict
from ..core.params import Params
from ..firmware.export import equivalents
from .findings import Finding, severity_of, trusted, worst_first

DECISIONS = ("apply", "apply_with_care", "do_not_apply")


def verdict(findings: Iterable[Any]) -> Dict[str, Any]:
    """``{"decision", "reason"}`` of a result with ``findings`` (:class:`Finding` objects
    or their dicts, any order): see the module docstring. ``reason`` is the worst finding's
    message as that finding holds it (a Msg, a text or its translatable dict)."""
    ordered = worst_first(findings, severity=severity_of)
    worst = ordered[0] if ordered else None
    sev = severity_of(worst) if worst is not None else "info"
    if sev == "error":
        decision = "do_not_apply"
    elif sev == "warning":
        decision = "apply_with_care"
    else:
        return {"decision": "apply", "reason": None}
    message = worst.message if isinstance(worst, Finding) else worst.get("message")
    return {"decision": decision, "reason": message}


def result_document(
    diagnostics: Dict[str, Any],
    params: Params,
    found: Sequence[Finding],
    notes: Optional[List[Any]] = None,
    plot: Any = None,
    plots: Any = None,
    needs_confirmation: Optional[Dict[str, Any]] = None,
) -> Dict[str, Any]:
    """The result of an analysis that measured ``diagnostics``, proposes ``params`` and
    found ``found`` (see the module docstring)."""
    ordered = worst_first(found)
    out = {
        "diagnostics": diagnostics,
        "parameters": params.to_dict(),
        "firmware": equivalents(params),
        "findings": [f.to_dict() for f in ordered],
        "findings_i18n": [f.to_wire() for f in ordered],
        "trusted": trusted(ordered),
        "verdict": _wire_verdict(ordered),
        "notes": list(notes or []),
        "plot": plot,
        "needs_confirmation": needs_confirmation,
    }
    if plots is not None:
        out["plots"] = plots
    return out


def _wire_verdict(ordered: Sequence[Finding]) -> Dict[str, Any]:
    v = verdict(ordered)
    if v["reason"] is not None:
        v["reason"] = as_dict(v["reason"])
    return v
