"""Notices when the firmware compensates too (double compensation), from what it reports
(``M503`` lines, which KinComp asks a Marlin firmware for after its ``M115`` reply) and from
what is sent to it: skew (Marlin/Klipper ``M852``, RepRapFirmware ``M556``, Klipper
``SET_SKEW``, ``SKEW_PROFILE LOAD``), backlash (``M425``) and per-axis scale
(RepRapFirmware ``M579``). Case does not matter.

The state itself is ``firmware/compensation.py``'s :class:`FirmwareCompensation`; a test
records it (:meth:`FirmwareWatcher.state`), so that its result is what the firmware left over
and its proposal says so (the params' ``meta.firmware``). :meth:`FirmwareWatcher.advice` tells
the two cases apart that "turn one off" confuses: parameters measured with the firmware's
compensation on hold only what it left (both stay; turning the firmware's off brings its part
back), parameters measured with it off hold everything (the firmware's must go)."""

from __future__ import annotations

from typing import Dict, List, Optional

from ...core.messages import Msg
from ...firmware.compensation import KINDS, FirmwareCompensation

# commands (upper case) whose lines the watcher reads; callers pre-filter with these
HINTS = ("M852", "M425", "M556", "M579", "SET_SKEW", "SKEW_PROFILE", "M92 ", "M203")
KIND_NAMES = {"skew": Msg("skew"), "backlash": Msg("backlash"), "scale": Msg("axis scale")}


def _compensates(params, kind: str) -> bool:
    if kind == "skew":
        return any(v != 0.0 for v in params.squareness_um_per_m.values())
    if kind == "backlash":
        return bool(params.has_backlash)
    return any(v != 0.0 for v in params.scale_ppm.values())


def measured_on(params) -> Optional[FirmwareCompensation]:
    """The firmware's compensation the parameters were measured with (their proposal's
    ``meta.firmware``); None when they do not say (typed in, or older)."""
    meta = getattr(params, "meta", None) or {}
    fw = meta.get("firmware")
    return FirmwareCompensation.from_dict(fw) if isinstance(fw, dict) else None


class FirmwareWatcher:
    """Tracks whether the firmware applies skew, backlash or scale compensation itself."""

    def __init__(self):
        self._state = FirmwareCompensation()
        self._where: Dict[str, str] = {}

    def reset(self) -> None:
        self._state = FirmwareCompensation()
        self._where = {}

    @property
    def skew(self) -> Optional[str]:
        """Where skew compensation was seen, e.g. "M852 I0.001 (sent)"; None: off."""
        return self._shown("skew")

    @property
    def backlash(self) -> Optional[str]:
        return self._shown("backlash")

    @property
    def scale(self) -> Optional[str]:
        return self._shown("scale")

    def _shown(self, kind: str) -> Optional[str]:
        cmd = getattr(self._state, kind)
        return f"{cmd} ({self._where.get(kind, 'sent')})" if cmd else None

    def state(self) -> FirmwareCompensation:
        """A copy of the state now (what a test printed now runs with)."""
        s = self._state
        return FirmwareCompensation(s.known, s.skew, s.backlash, s.scale)

    @staticmethod
    def relevant(text: str) -> bool:
        """Cheap pre-filter: does ``text`` mention a command the watcher reads?"""
        up = text.upper()
        return any(h in up for h in HINTS)

    def _line(self, text: str, where: str, reported: bool = False) -> None:
        before = {k: getattr(self._state, k) for k in KINDS}
        self._state.read(text, reported)
        for k in KINDS:
            if getattr(self._state, k) != before[k]:
                self._where[k] = where

    def sent(self, cmd: str) -> None:
        """A command on its way to the printer."""
        self._line(cmd, "sent")

    def received(self, line: str) -> None:
        """A line from the printer (M503 prints the settings as commands after 'echo:')."""
        body = line.strip()
        if body.lower().startswith("echo:"):
            body = body[5:]
        self._line(body.strip(), "reported by the firmware", reported=True)

    def conflicts(self, params) -> Dict[str, str]:
        """What KinComp and the firmware would both compensate where that is not how the
        parameters were measured (:meth:`advice`'s ``double`` and ``unknown`` cases)."""
        return {
            a["kind"]: a["where"] for a in self.advice(params) if a["case"] in ("double", "unknown")
        }

    def advice(self, params) -> List[Dict[str, object]]:
        """Per kind where the firmware's compensation and KinComp's parameters do not fit
        together: ``{"kind", "case", "where", "message"}``. Cases: ``double`` (both
        compensate it, the parameters were measured with the firmware's off: they hold all of
        it, the firmware's must go), ``unknown`` (both compensate it; how the parameters were
        measured is not recorded), ``changed`` (measured on top of another firmware value),
        ``gone`` (measured on top of the firmware's, which is off now: its part is back).
        Parameters measured on top of the same firmware compensation fit: nothing is said."""
        base = measured_on(params)
        out = []
        for kind in KINDS:
            now = getattr(self._state, kind)
            ours = _compensates(params, kind)
            then = getattr(base, kind) if base is not None else None
            name = KIND_NAMES[kind]
            if now and ours:
                if base is None or not base.known:
                    case, msg = "unknown", _unknown(kind, name, self._state)
                elif then is None:
                    case, msg = "double", _double(kind, name, self._state)
                elif base.same_as(self._state, kind):
                    continue
                else:
                    case, msg = "changed", _changed(name, then)
            elif then and not now and self._state.known:
                case, msg = "gone", _gone(name, then)
            else:
                continue
            out.append(
                {"kind": kind, "case": case, "where": self._shown(kind) or then, "message": msg}
            )
        return out


def _double(kind: str, name: Msg, state: FirmwareCompensation) -> Msg:
    return Msg(
        "The firmware compensates %(kind)s too (%(where)s), and KinComp's parameters were "
        "measured with the firmware's %(kind)s compensation off: they hold all of it, so it "
        "is corrected twice. Turn the firmware's off (%(off)s), not KinComp's.",
        kind=name,
        where=getattr(state, kind),
        off=state.off_command(kind),
    )


def _unknown(kind: str, name: Msg, state: FirmwareCompensation) -> Msg:
    return Msg(
        "The firmware compensates %(kind)s too (%(where)s), and KinComp's parameters do not "
        "record whether it was on when they were measured. If it was, they hold only what it "
        "left: keep both (turning either off brings back its part). If it was off, turn the "
        "firmware's off (%(off)s). Re-test to be sure: a new result records it.",
        kind=name,
        where=getattr(state, kind),
        off=state.off_command(kind),
    )


def _changed(name: Msg, then: str) -> Msg:
    return Msg(
        "The firmware's %(kind)s compensation is not the one KinComp's parameters were "
        "measured on top of (%(then)s): their residual no longer fits it. Set it back, or "
        "re-test with it as it is now.",
        kind=name,
        then=then,
    )


def _gone(name: Msg, then: str) -> Msg:
    return Msg(
        "KinComp's parameters were measured with the firmware's %(kind)s compensation on "
        "(%(then)s) and hold only what it left; it is off now, so what it corrected is back. "
        "Turn it on again, or re-test without it.",
        kind=name,
        then=then,
    )
