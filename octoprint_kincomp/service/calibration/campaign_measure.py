"""A campaign's tests measured: what is in force, whether a campaign may go on, and a trace
taken as the measurement of one of its tests (no Flask: the live capture's worker thread
hands its runs here too).

"In force" are the parameters the printed programs are compensated with: the current ones
while compensation is on, none (zero) while it is off. A campaign keeps the hash of those it
began with and the OctoPrint printer profile it was planned on (its id, ``profile``, and its
name, ``printer``); when either changes it cannot go on (a joint fit of tests measured under
different parameters, or on another printer, would be wrong). The profile id decides
(:func:`.printer_profiles.other_profile`, a campaign from before profiles belonging to
``legacy_profile``); only when there is no id to compare (settings from before profiles) the
name does. A test's measurement taken while another profile is in force is refused unless
the request says ``force``: then its run carries the warning finding
``campaign.other_profile`` (and the campaign's joint result too); a profile renamed since
the plan (same id, other name) is said as an info finding.

A trace is a test's measurement when its metadata names the campaign and the test, its
program hash is the test's program, and the parameter hash (when the trace has one: a live
capture has none, it was taken while the campaign's parameters were in force) and the
printer (when the campaign has one) are the campaign's. It is analysed on its own with the
parameters in force and stored as a run of the campaign (``campaign``, ``campaign_step``);
a live capture's run is replaced by that run (its raw stream and capture data kept), so
that every trace stays one run. Refusals are :class:`Refused` with a translatable message
(``core.messages.Msg``) naming the file and the HTTP status a request answers with.
"""

from __future__ import annotations

import contextlib
from typing import Any, Callable, Dict, List, Optional

from ...calibration import findings as fnd
from ...calibration.ballbar.campaign import test_words
from ...calibration.ballbar.formats import AngleTrace, NativeTrace, TraceError
from ...calibration.ballbar.program import ProgramError
from ...core.messages import Msg, error_message
from ...core.params import Params
from ..notify import N_, Notifier
from ..printing.queue import QueueCompensator
from ..settings.printer_profiles import other_profile, profile_id
from .campaign_store import CampaignNotFound, CampaignStore, now
from .findings_view import verdict_of
from .printed_programs import trace_meta
from .run_store import RunStore


class Refused(Exception):
    """A campaign cannot take a request: ``message`` (a Msg) and the HTTP ``status``."""

    def __init__(self, message, status: int = 400):
        super().__init__(str(message))
        self.message = message
        self.status = status


class CampaignMeasurements:
    def __init__(
        self,
        queue: QueueCompensator,
        runs: RunStore,
        campaigns: CampaignStore,
        calibration,
        notifier: Notifier,
        profiles,
        store,
    ):
        self._queue = queue
        self._runs = runs
        self._campaigns = campaigns
        self._calibration = calibration  # CalibrationApi: record_run
        self._notifier = notifier
        self._profiles = profiles
        self._store = store  # SettingsStore: the printer profile in force (current())

    # ~~ what is in force ----------------------------------------------------------------------
    def in_force(self) -> Params:
        """The parameters the programs are compensated with (none while compensation is
        off)."""
        return self._queue.in_force

    def _current_profile(self) -> Dict[str, Any]:
        """OctoPrint's current printer profile (or its default); {} when it cannot say."""
        try:
            profile = self._profiles.get_current_or_default() or {}
        except Exception:
            return {}
        return profile if isinstance(profile, dict) else {}

    def printer(self) -> Optional[str]:
        """The printer profile's name (the traces' ``printer``)."""
        profile = self._current_profile()
        name = profile.get("name") or profile.get("id")
        return str(name) if name else None

    def check_unchanged(self, doc: Dict[str, Any], force: bool = False) -> None:
        """Raises Refused (409) when the parameters in force changed since the campaign
        began, or when another printer profile is in force (unless ``force``: a test's
        measurement taken anyway, see :meth:`other_printer`)."""
        in_force = self.in_force().hash()
        if in_force != doc["params_hash"]:
            raise Refused(
                Msg(
                    "The parameters in force changed since this campaign began: all tests of a "
                    "campaign must be measured with the same parameters. Start a new campaign.",
                ),
                409,
            )
        wrong = self.other_printer(doc)
        if wrong is not None and not force:
            raise Refused(wrong, 409)

    def other_printer(self, doc: Dict[str, Any]) -> Optional[Msg]:
        """Why the printer in force is not campaign ``doc``'s (None: it is). Decided by the
        printer profile id in force against the one the campaign was planned on; by the
        profile's name only when either has no id (from before profiles)."""
        s = self._store.current()
        owner = doc.get("profile") or s.get("legacy_profile") or ""
        printer = self.printer()
        if other_profile(doc.get("profile"), s):
            names = self._store.profile_names() or {}
            if printer and profile_id(self._current_profile()) == s["profile"]:
                names.setdefault(s["profile"], printer)
            then = doc.get("printer") or names.get(owner) or owner
            now = names.get(s["profile"]) or s["profile"]
            if then == now:  # two profiles of one name: told apart by their ids
                then, now = f"{then} ({owner})", f"{now} ({s['profile']})"
            return Msg(
                "This campaign was planned for printer profile %(then)s, but printer profile "
                "%(now)s is in force: a campaign is measured on the printer it was planned "
                "for. Connect that printer, or start a new campaign.",
                then=then,
                now=now,
            )
        if (not owner or not s.get("profile")) and doc.get("printer") and printer != doc["printer"]:
            return Msg(
                "The printer profile changed since this campaign began (%(then)s, now "
                "%(now)s): a campaign is measured on one printer. Start a new campaign.",
                then=doc["printer"],
                now=printer or "-",
            )
        return None

    def profile_findings(self, doc: Dict[str, Any]) -> List[fnd.Finding]:
        """What a test's measurement says of its printer: a warning when it was taken while
        another profile is in force (the request said ``force``), an info when the
        campaign's profile was renamed since the plan."""
        wrong = self.other_printer(doc)
        if wrong is not None:
            s = self._store.current()
            return [
                fnd.warning(
                    "campaign.other_profile",
                    Msg("Measured while another printer profile was in force: %(why)s", why=wrong),
                    Msg(
                        "Taken anyway (force). Make sure this measurement comes from the "
                        "campaign's printer; if not, measure the test again on it."
                    ),
                    campaign_profile=doc.get("profile") or s.get("legacy_profile") or None,
                    profile_in_force=s.get("profile") or None,
                    campaign_printer=doc.get("printer"),
                    printer_in_force=self.printer(),
                )
            ]
        printer = self.printer()
        if doc.get("printer") and printer and printer != doc["printer"]:
            return [
                fnd.info(
                    "campaign.profile_renamed",
                    Msg(
                        "The printer profile of this campaign is named %(now)s now "
                        "(%(then)s when the campaign was planned); it is the same profile.",
                        now=printer,
                        then=doc["printer"],
                    ),
                    campaign_printer=doc["printer"],
                    printer_in_force=printer,
                )
            ]
        return []

    def open_step(self, cid: str, n: int, force: bool = False):
        """(campaign, its test n) when the campaign can still measure it; else Refused
        (``force``: also while another printer profile is in force)."""
        try:
            doc = self._campaigns.get(cid)
        except CampaignNotFound:
            raise Refused(Msg("No such campaign"), 404) from None
        if not 1 <= n <= len(doc["steps"]):
            raise Refused(Msg("This campaign has no test %(n)s", n=n), 404)
        if doc.get("result"):
            raise Refused(
                Msg(
                    "This campaign is analysed and closed: to measure again, "
                    "start a re-test campaign.",
                ),
                409,
            )
        self.check_unchanged(doc, force)
        return doc, doc["steps"][n - 1]

    # ~~ a trace as a test's measurement --------------------------------------------------------
    def measure(
        self,
        doc: Dict[str, Any],
        step: Dict[str, Any],
        data: bytes,
        name: str,
        extra: Optional[Dict[str, Any]] = None,
        force: bool = False,
        analyse: Optional[Callable[[str, Dict[str, Any]], Dict[str, Any]]] = None,
        claimed: bool = False,
    ) -> Dict[str, Any]:
        """The trace ``data`` (file ``name``) as ``step``'s measurement: checked, analysed
        (``analyse(task, args)``: in the worker process, ``service/calibration/
        measurement.py``), stored as a run of the campaign (``extra``: more fields) and
        linked to the test under the campaign's lock; returns the run (``doc`` is updated
        to the stored document). Refused (400) naming the file when it is not this test's
        trace or its analysis fails; (409) while another printer profile is in force,
        unless ``force`` (then the run carries the warning finding and belongs to the
        campaign's profile, as the campaign does), and while the same test is measured
        already (``claimed``: the caller registered this measurement with
        ``CampaignStore.claim`` when the request came in); (404) when the campaign was
        deleted meanwhile (nothing is stored)."""
        self.check_unchanged(doc, force)
        said = self.profile_findings(doc)
        known = self._calibration.known_now()
        current = self.in_force()
        with contextlib.ExitStack() as stack:
            if not claimed and not stack.enter_context(
                self._campaigns.working(doc["id"], step["name"])
            ):
                raise busy_test(doc, step)
            args = dict(data=data, name=name, current=current.to_dict(), known=known["known"])
            args.update(campaign=doc, step=step)
            args["origin"] = self._calibration.origin_for(trace_meta(data))
            try:
                result = (analyse or _in_process)("analyse", args)
            except (TraceError, ProgramError, ValueError, ArithmeticError) as exc:
                raise Refused(
                    Msg("%(name)s: %(reason)s", name=name, reason=error_message(exc))
                ) from None
            kind = result.pop("kind", None) or "upload"
            result = with_findings(result, said)
            fields = campaign_keys(doc["id"], step["name"], current)
            fields["profile"] = doc.get("profile") or known["profile"]
            forced = any(f.code == "campaign.other_profile" for f in said)  # taken anyway
            if forced:
                fields["profile"] = doc.get("profile") or self._store.current().get(
                    "legacy_profile"
                )
            fields.update(extra or {})

            def link(fresh: Dict[str, Any]) -> Dict[str, Any]:
                if fresh.get("result"):
                    raise Refused(Msg("This campaign was analysed meanwhile"), 409)
                run = self._calibration.record_run(
                    result, name, kind, data, result.get("plot"), fields
                )
                mine = fresh["steps"][step["n"] - 1]
                mine.pop("other_profile", None)
                if forced:
                    mine["other_profile"] = self._store.current().get("profile")
                mine["run"], mine["measured"] = run["id"], now()
                doc.clear()
                doc.update(fresh)
                return run

            try:
                return self._campaigns.change(doc["id"], link)
            except CampaignNotFound:
                raise Refused(
                    Msg(
                        "This campaign was deleted while its test was analysed: nothing was "
                        "stored.",
                    ),
                    404,
                ) from None

    def take_capture(self, run: Dict[str, Any]) -> Dict[str, Any]:
        """CaptureRecorder.on_recorded (the sensor's worker thread): a live capture stored as
        ``run``. When its trace is a campaign's test, it becomes that test's measurement and
        the run that replaces it is returned; else ``run`` as it was (a refusal is
        notified)."""
        path = self._runs.trace_path(run.get("id") or "")
        if run.get("status", "ok") != "ok" or path is None:
            return run
        with open(path, "rb") as f:
            data = f.read()
        name = str(run.get("filename") or "live.csv")
        cid, step_name = _campaign_of(data)
        if not cid:
            return run
        try:
            doc = self._campaigns.get(cid)
            step = next((s for s in doc["steps"] if s["name"] == step_name), None)
            if step is None:
                raise Refused(
                    Msg(
                        "%(name)s: campaign %(id)s has no test %(test)s",
                        name=name,
                        id=cid,
                        test=step_name or "-",
                    )
                )
            doc, step = self.open_step(cid, step["n"])
            new = self.measure(
                doc,
                step,
                data,
                name,
                {"source": run.get("source"), "status": "ok", "capture": run.get("capture")},
                analyse=self._calibration.analyse_in_worker,
            )
        except CampaignNotFound:
            return run
        except Refused as exc:
            self._notifier.notify(
                "error",
                N_(
                    "The live capture was not taken as a test of "
                    "its campaign: %(reason)s. It is kept in the "
                    "history as a single run."
                ),
                reason=exc.message,
            )
            return run
        raw = self._runs.raw_path(run["id"])
        if raw is not None:
            with open(raw, "rb") as f:
                self._runs.save_raw(new["id"], f.read())
        self._runs.delete(run["id"])
        return new


def busy_test(doc: Dict[str, Any], step: Dict[str, Any]) -> Refused:
    """The refusal of a second measurement of a test while the first is under way."""
    return Refused(
        Msg(
            "Test %(n)s (%(name)s) of this campaign is being measured already: wait for "
            "that measurement.",
            n=step["n"],
            name=test_words(step["name"]),
        ),
        409,
    )


def _in_process(task: str, args: Dict[str, Any]) -> Dict[str, Any]:
    """The worker's task ``task`` run here (callers without a worker: tests)."""
    from ..files.worker import TASKS

    return TASKS[task](progress=lambda frac: None, **args)


def not_this_test(trace, doc: Dict[str, Any], step: Dict[str, Any]) -> Optional[Msg]:
    """Why ``trace`` is not the measurement of ``step`` of campaign ``doc`` (None: it is)."""
    if not isinstance(trace, (NativeTrace, AngleTrace)):
        return Msg(
            "a campaign test needs a measured trace (native or angle CSV) written "
            "with the test's program, not a summary"
        )
    meta = trace.meta
    got = (meta.get("campaign") or "").strip()
    if got != doc["id"]:
        if not got:
            return Msg("it was not measured with a campaign's test program")
        return Msg(
            "it belongs to another campaign, not to this one (each campaign, a re-test too, "
            "has test programs of its own: measure this campaign's)"
        )
    got = (meta.get("campaign_step") or "").strip()
    if got != step["name"]:
        return Msg(
            "it is the trace of test %(other)s, not of test %(n)s (%(name)s)",
            other=test_words(got) if got else "-",
            n=step["n"],
            name=test_words(step["name"]),
        )
    got = (meta.get("program_hash") or "").strip()
    if got != step["program_hash"]:
        return Msg(
            "its program is not test %(n)s's program: the metadata was edited or belongs to "
            "another test",
            n=step["n"],
        )
    got = (meta.get("params_hash") or "").strip()
    if got and got != doc["params_hash"]:
        return Msg(
            "it was measured with other parameters than the campaign runs with (the "
            "parameters were changed after the campaign was planned: plan it again)",
        )
    got = (meta.get("printer") or "").strip()
    if doc.get("printer") and got != doc["printer"]:
        return Msg(
            "it comes from printer %(got)s, but the campaign is for %(want)s",
            got=got or "-",
            want=doc["printer"],
        )
    return None


def with_findings(result: Dict[str, Any], found: List[fnd.Finding]) -> Dict[str, Any]:
    """An analysis ``result`` with the findings ``found`` added (both forms, worst first;
    an error among them makes it untrusted, and the verdict follows)."""
    if not found:
        return result
    out = dict(result)
    for key, form in (("findings", fnd.Finding.to_dict), ("findings_i18n", fnd.Finding.to_wire)):
        if key in result or key == "findings":
            out[key] = fnd.worst_first(list(result.get(key) or []) + [form(f) for f in found])
    out["trusted"] = result.get("trusted") is not False and fnd.trusted(found)
    out["verdict"] = verdict_of(out)
    return out


def campaign_keys(cid: str, step: Optional[str], current: Params) -> Dict[str, Any]:
    """A campaign run's fields: its campaign, its test (None: the joint analysis) and the
    parameters in force."""
    return {
        "campaign": cid,
        "campaign_step": step,
        "params_before": current.to_dict(),
        "params_before_hash": current.hash(),
    }


def _campaign_of(data: bytes):
    """(campaign id, test name) a trace's header names ("" when none): its ``# key: value``
    lines before the first row."""
    meta = {}
    for line in data[:65536].decode("utf-8", "replace").splitlines():
        if not line.startswith("#"):
            break
        key, _, value = line[1:].partition(":")
        meta[key.strip()] = value.strip()
    return meta.get("campaign", ""), meta.get("campaign_step", "")
