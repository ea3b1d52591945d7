"""THE analysis of a measurement, whichever way it came in (no OctoPrint import): a trace,
.b5r or summary uploaded or typed, a campaign test's trace, a live capture, a campaign's
joint analysis and a printed artifact's readings. Every plugin caller hands over what the
plugin knows when the measurement starts (:func:`known_as_of`: the parameters in force, the
squareness the printer profile's history knows, the profile itself), so all of them analyse
alike: a vertical test always takes the known out-of-plane squareness
(``known_squareness.py``), and the run always belongs to the profile it was measured on,
whatever is switched meanwhile.

The functions here run in the worker process (``service/files/worker.py``, tasks
``analyse``, ``analyse_campaign``, ``analyse_artifact``): their arguments and results are
plain data (pickled), their refusals ValueErrors whose first argument is a translatable
message (``core.messages.Msg``).
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Tuple

from ...calibration.ballbar.analysis import analyse
from ...calibration.ballbar.formats import load_any
from ...core.params import Params
from .known_squareness import for_trace
from .printed_programs import origin_kwargs


class NotThisTest(ValueError):
    """The trace is not the measurement of the campaign test it was given for (its first
    argument says why)."""


def known_as_of(in_force: Params, known: Dict[str, Any], profile: Optional[str]) -> Dict[str, Any]:
    """What an analysis takes from the plugin, taken when the measurement starts: the
    parameters in force (``current``, a params document), the profile history's squareness
    (``known``, :func:`.known_squareness.known_squareness`) and the printer profile id the
    measurement belongs to (``profile``)."""
    return {"current": in_force.to_dict(), "known": known or {}, "profile": profile}


def analyse_measurement(
    data: bytes,
    name: str,
    current: Dict[str, Any],
    known: Optional[Dict[str, Any]] = None,
    campaign: Optional[Dict[str, Any]] = None,
    step: Optional[Dict[str, Any]] = None,
    origin: Optional[Dict[str, Any]] = None,
) -> Dict[str, Any]:
    """The file ``data`` (named ``name``) analysed against the parameters ``current`` with
    the known out-of-plane squareness that fits it; its ``kind`` added. With ``campaign``
    and ``step`` (the campaign's document and its test): NotThisTest when it is not that
    test's trace. ``origin``: what the test ran with (``printed_programs.origin_kwargs``:
    the firmware's compensation, whether the print is confirmed, how it was compensated)."""
    from .campaign_measure import not_this_test

    trace = load_any(data, name)
    if campaign is not None:
        wrong = not_this_test(trace, campaign, step)
        if wrong is not None:
            raise NotThisTest(wrong)
    values, sources = for_trace(known or {}, trace)
    result = analyse(
        trace,
        current=Params.from_dict(current),
        known_squareness_um_per_m=values,
        known_sources=sources,
        **origin_kwargs(origin),
    )
    result["kind"] = getattr(trace, "kind", None)
    return result


def analyse_joint(
    traces: Sequence[Tuple[str, bytes]],
    current: Dict[str, Any],
    origin: Optional[Dict[str, Any]] = None,
) -> Dict[str, Any]:
    """A campaign's joint analysis of its tests' traces ``[(file name, data)]``, in order,
    against the parameters ``current`` (the joint fit estimates the out-of-plane terms
    itself); ``origin``: what the first test ran with (as :func:`analyse_measurement`'s)."""
    from ...calibration.ballbar.campaign_analysis import analyse_campaign

    loaded: List[Tuple[str, Any]] = [(n, load_any(d, n)) for n, d in traces]
    how = origin_kwargs(origin)
    return analyse_campaign(
        loaded,
        current=Params.from_dict(current),
        sent=how["sent"],
        firmware=how["origin"].firmware,
    )


def analyse_artifact_readings(
    text: str, readings: Dict[str, Any], current: Dict[str, Any], simulated: bool = False
) -> Dict[str, Any]:
    """A printed artifact's caliper ``readings`` (as ``parse_readings`` takes them) against
    its program ``text`` and the parameters ``current``; the readings parsed are returned
    too (``readings``). ``simulated``: demo mode's readings (the result says SIMULATED)."""
    from ...calibration.artifact.fit import analyse_artifact, parse_readings
    from ...calibration.artifact.program import read_measurements, read_program_info

    measurements = read_measurements(text)
    parsed = parse_readings(readings)
    result = analyse_artifact(
        measurements,
        parsed,
        current=Params.from_dict(current),
        info=read_program_info(text),
        simulated=simulated,
    )
    result["readings"] = parsed
    return result
