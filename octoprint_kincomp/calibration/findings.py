"""Findings: what an analysis checked and what it saw, in one shape for every result.

Every analysis (single test, campaign, live capture, uploaded trace, printed artifact) returns
``findings``: a list of :class:`Finding` as dicts ``{"code", "severity", "message", "advice",
"evidence"}``, worst first, and ``trusted``: False when any finding is an error. ``message``
and ``advice`` are :class:`~octoprint_kincomp.core.messages.Msg` (English, translatable by the
OctoPrint layer); ``evidence`` holds the numbers the finding rests on (JSON values only, each
key naming its unit, e.g. ``"rms_um"``, ``"sync_mismatch_ms"``).

Severities: ``info`` (said for the record: what was assumed or not checked), ``warning`` (the
result holds but something deserves a look), ``error`` (the result cannot be trusted: applying
it needs an explicit "apply anyway").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Iterable, List, Optional, Union

from ..core.messages import Msg, as_dict

SEVERITIES = ("info", "warning", "error")
_RANK = {s: i for i, s in enumerate(SEVERITIES)}


@dataclass(frozen=True)
class Finding:
    """One check's outcome. ``code`` is a stable machine name (``motion.feed_capped``)."""

    code: str
    severity: str
    message: Union[str, Msg]
    advice: Union[str, Msg] = ""
    evidence: Dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.severity not in _RANK:
            raise ValueError("severity must be one of %s, not %r" % (SEVERITIES, self.severity))

    def to_dict(self) -> Dict[str, Any]:
        """JSON form (message and advice as the English text)."""
        return {
            "code": self.code,
            "severity": self.severity,
            "message": str(self.message),
            "advice": str(self.advice),
            "evidence": dict(self.evidence),
        }

    def to_wire(self) -> Dict[str, Any]:
        """JSON form for the browser: message and advice as :func:`as_dict` (translatable)."""
        out = self.to_dict()
        out["message"] = as_dict(self.message)
        out["advice"] = as_dict(self.advice)
        return out


def info(
    code: str, message: Union[str, Msg], advice: Union[str, Msg] = "", **evidence: Any
) -> Finding:
    return Finding(code, "info", message, advice, evidence)


def warning(
    code: str, message: Union[str, Msg], advice: Union[str, Msg] = "", **evidence: Any
) -> Finding:
    return Finding(code, "warning", message, advice, evidence)


def error(
    code: str, message: Union[str, Msg], advice: Union[str, Msg] = "", **evidence: Any
) -> Finding:
    return Finding(code, "error", message, advice, evidence)


def severity_of(finding: Any) -> Optional[str]:
    """The severity of a :class:`Finding` or of its dict form."""
    if isinstance(finding, Finding):
        return finding.severity
    return finding.get("severity") if isinstance(finding, dict) else None


def worst_first(
    findings: Iterable[Any], severity: Optional[Callable[[Any], Any]] = None
) -> List[Any]:
    """Errors, then warnings, then infos; the order within a severity is kept. ``findings``:
    Finding objects or their dicts (an unknown severity ranks as an info). This is the one
    severity order: the API hands findings on in it, and the web UI shows them as given."""
    sev = severity or severity_of
    return sorted(findings, key=lambda f: -_RANK.get(sev(f), 0))


def trusted(findings: Iterable[Any]) -> bool:
    """Whether a result with ``findings`` (Finding objects or their dicts) can be trusted:
    the one rule, False when any finding is an error."""
    return not any(severity_of(f) == "error" for f in findings)


def from_notes(notes: Iterable[Union[str, Msg]], code: str = "note") -> List[Finding]:
    """Today's free-text notes as info findings (one each)."""
    return [info(code, n) for n in notes]
