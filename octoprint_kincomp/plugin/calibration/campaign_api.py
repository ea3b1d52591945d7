"""The campaign endpoints: one calibration round over the whole volume (XY, XZ and YZ;
optionally XY at a second height and at a second feed), planned on the printer profile's
volume, printed test by test with the same parameters in force, fitted jointly
(``calibration/ballbar/campaign_analysis.py``) and applied once.

* ``POST /campaign/plan``  plans a campaign (``radius_xy``, ``radius_vertical`` mm,
  ``feed`` mm/min, ``xy_height`` mm above the bed, ``second_height`` absolute Z of a second
  XY test in mm or null, ``second_feed`` mm/min or null, ``retest_of`` an earlier campaign
  whose options are the defaults and whose result is the "before"); ``"dry_run": true``
  only answers the plan (for the drawing), else it is stored.
* ``GET /campaigns``, ``GET /campaigns/<id>``  the campaigns of the printer profile in force
  (each is tagged with the profile it was planned on; the others stay stored, and one of
  them is not applied unless forced: 409), newest first; one campaign with
  its progress and, once analysed, the joint result and per test the comparison with the
  campaign it re-tests (the paper's Table 2 per plane).
* ``POST /campaigns/<id>/steps/<n>/program``  writes test n's program (n from 1) into
  OctoPrint's storage, ``"print": true`` prints it (it pauses (M0) to mount the bar and to
  unmount it); 409 when the printer's motion limits no longer allow its planned feed.
* ``POST /campaigns/<id>/steps/<n>/trace``  test n's measurement: a file (multipart field
  ``file``) or ``{"demo": true}`` for demo mode's SIMULATED trace of the printed commands
  (the measurement without the live path, ``demo.live`` off, and a fallback with it); it
  must be this test's trace (campaign, test, program and parameters in its metadata);
  analysed on its own and stored as a run of the campaign. While another printer profile is
  in force than the campaign's it is refused (409, nothing stored) unless ``force`` is true
  (JSON field, or form field / query ``force=true`` with a file): then the run carries the
  warning finding ``campaign.other_profile``. (A live sensor's capture of a test needs no
  request: that is also the demo's virtual bar with ``demo.live`` on.)
* ``POST /campaigns/<id>/analyze``  the joint fit over all tests, stored as a run (source
  ``campaign``): ONE parameter set; nothing applied. Refused (400 naming the file) for a
  missing or failed test or traces that are not one campaign.
* ``DELETE /campaigns/<id>``  deletes the campaign (its document; the runs of its tests and
  of its joint analysis stay in the history): 404 for an unknown id, 409 for a campaign of
  another printer profile than the one in force, and 409 while one of its tests is being
  measured (its program printing or paused, or a live capture armed for it).
* ``POST /campaigns/<id>/apply``  that parameter set into the settings (``enabled``,
  ``apply_now`` and ``force`` as for ``/apply``: an untrusted result, or another printer
  profile's campaign, applied anyway, the latter with the warning ``applied.other_profile``
  on its run). The joint result, as every run, carries ``findings`` and ``trusted``.

What is in force, when a campaign may go on (409 when the parameters in force or the printer profile
changed since it began) and how a trace becomes a test's measurement (also a live capture's, armed
when a test is printed) is ``service/calibration/campaign_measure.py``. Reading needs STATUS,
everything else PLUGIN_KINCOMP_ADMIN, printing also PRINT.
"""

from __future__ import annotations

import math
import os
from typing import Any, Callable, Dict, List, Optional, Tuple

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions

from ...calibration import findings as fnd
from ...calibration.ballbar.campaign import plan_campaign, test_words
from ...calibration.ballbar.program import ProgramError, TestSpec, generate
from ...core.messages import Msg, as_dict, joined
from ...firmware.motion_limits import LimitsError, circle_feed
from ...service.calibration.campaign_measure import (
    CampaignMeasurements,
    Refused,
    busy_test,
    campaign_keys,
    with_findings,
)
from ...service.calibration.campaign_store import (
    CampaignNotFound,
    CampaignStore,
    new_campaign,
    now,
    view,
)
from ...service.calibration.demo_mode import DemoMode
from ...service.calibration.printed_programs import trace_meta
from ...service.calibration.run_store import RunNotFound, RunStore
from ...service.settings.printer_profiles import other_profile
from .. import http
from ..settings.settings_store import SettingsStore
from .calibration_api import CalibrationApi, UploadRefused, safe_name

# request field: (default, lowest, highest); None as default: optional (null: left out)
PLAN_FIELDS = {
    "radius_xy": (100.0, 5.0, 1000.0),  # mm
    "radius_vertical": (50.0, 5.0, 1000.0),  # mm
    "feed": (1850.0, 10.0, 60000.0),  # mm/min
    "xy_height": (10.0, 0.0, 10000.0),  # mm above the bed
    "second_height": (None, -10000.0, 10000.0),  # mm, absolute Z
    "second_feed": (None, 10.0, 60000.0),  # mm/min
}


def _form_flag(key: str) -> bool:
    """A flag of a multipart request (form field or query): "true" or "false", False when
    absent; anything else is refused (http.BadRequest naming ``key``)."""
    value = flask.request.values.get(key)
    if value is None or value == "false":
        return False
    if value == "true":
        return True
    raise http.BadRequest(gettext("'%(key)s' must be true or false", key=key))


def _forced_steps(doc: Dict[str, Any]) -> List[fnd.Finding]:
    """A warning for the joint result when tests of campaign ``doc`` were measured while
    another printer profile was in force (taken with ``force``)."""
    forced = [s for s in doc["steps"] if s.get("other_profile")]
    if not forced:
        return []
    return [
        fnd.warning(
            "campaign.other_profile",
            Msg(
                "Tests %(tests)s were measured while another printer profile was in force "
                "(%(other)s), not the campaign's (%(profile)s); they were taken anyway (force).",
                tests=", ".join(str(s["n"]) for s in forced),
                other=", ".join(sorted({str(s["other_profile"]) for s in forced})),
                profile=doc.get("profile") or "-",
            ),
            Msg(
                "Make sure these measurements come from the campaign's printer; if not, "
                "measure the tests again on it."
            ),
            tests=[s["n"] for s in forced],
        )
    ]


def number(
    data: Dict[str, Any], key: str, default: Optional[float], lo: float, hi: float
) -> Optional[float]:
    """The JSON number ``data[key]`` (``default`` when absent; None when null and
    optional); raises http.BadRequest naming ``key`` for anything else or out of range."""
    value = data.get(key, default)
    if value is None and default is None:
        return None
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not lo <= value <= hi
    ):
        raise http.BadRequest(
            gettext(
                "'%(key)s' must be a number from %(lo)s to %(hi)s",
                key=key,
                lo=f"{lo:g}",
                hi=f"{hi:g}",
            )
        )
    return float(value)


class CampaignApi:
    # () -> the campaign id a live capture is armed for (None: none); set by the plugin
    armed_campaign: Optional[Callable[[], Optional[str]]] = None

    def __init__(
        self,
        store: SettingsStore,
        runs: RunStore,
        campaigns: CampaignStore,
        calibration: CalibrationApi,
        demo: DemoMode,
        measurements: CampaignMeasurements,
    ):
        self._store = store
        self._runs = runs
        self._campaigns = campaigns
        self._calibration = calibration
        self._demo = demo
        self.measure = measurements

    # ~~ planning --------------------------------------------------------------------------------
    @http.route("/campaign/plan", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def plan(self):
        data = http.json_object()
        if data is None:
            return http.error(gettext("Expected a JSON object"), 400)
        before = None
        try:
            dry_run = http.flag(data, "dry_run")
            if data.get("retest_of") is not None:
                before = self._campaigns.get(str(data["retest_of"]))
                data = dict(
                    before.get("options") or {},
                    **{k: v for k, v in data.items() if k in PLAN_FIELDS},
                )
            options = {k: number(data, k, *v) for k, v in PLAN_FIELDS.items()}
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except CampaignNotFound:
            return http.error(
                gettext("The campaign to re-test no longer exists: start a new campaign"), 400
            )
        volume = self._store.limits()
        if volume is None:
            return http.error(gettext("The printer profile has no build volume"), 409)
        cid = self._campaigns.new_id()
        printer = self.measure.printer()
        try:
            steps = plan_campaign(
                volume,
                radius_xy=options["radius_xy"],
                radius_vertical=options["radius_vertical"],
                feed=options["feed"],
                xy_height=options["xy_height"],
                second_height=options["second_height"],
                second_feed=options["second_feed"],
                limits=self._calibration.motion_limits(),
                printer=printer,
                campaign_id=cid,
                firmware=self._calibration.firmware(),
            )
        except (ProgramError, ValueError) as exc:
            return http.error(http.tr(exc), 400)
        doc = new_campaign(
            cid,
            steps,
            volume,
            printer,
            self.measure.in_force().hash(),
            options,
            before["id"] if before else None,
        )
        if dry_run:
            return flask.jsonify(self._view(doc, stored=False))
        self._campaigns.save(doc)
        return flask.jsonify(self._view(doc))

    # ~~ reading -------------------------------------------------------------------------------
    @http.route("/campaigns", "GET", needs=(http.STATUS,))
    def list(self):
        s = self._store.current()  # the campaigns of the printer profile in force
        docs = self._campaigns.documents(s["profile"] or None, s["legacy_profile"])
        return flask.jsonify(campaigns=[self._view(d, analysis=False) for d in docs])

    @http.route("/campaigns/<cid>", "GET", needs=(http.STATUS,))
    def get(self, cid: str):
        try:
            return flask.jsonify(self._view(self._campaigns.get(cid)))
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)

    # ~~ one test --------------------------------------------------------------------------------
    @http.route(
        "/campaigns/<cid>/steps/<int:n>/program", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,)
    )
    def program(self, cid: str, n: int):
        try:
            do_print = http.flag(http.json_object() or {}, "print")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        if do_print:
            http.require(Permissions.PRINT)
        try:
            doc, step = self.measure.open_step(cid, n)
            spec = TestSpec(**step["spec"])
            self._within_limits(spec, n)
            text = generate(spec, volume=self._store.limits(), params_hash=doc["params_hash"])
        except Refused as exc:
            return http.error(http.tr(exc.message), exc.status)
        except (ProgramError, TypeError, ValueError) as exc:
            return http.error(http.tr(exc), 400)
        path, prog_hash, stated = self._calibration.write_program(
            text, f"{cid}_{n}_{safe_name(step['name'])}.gcode"
        )
        step["path"] = path
        step["program_hash"] = prog_hash
        # the test as its program states it: a live capture's trace names campaign and test
        # and becomes its measurement by itself (CampaignMeasurements.take_capture). Demo
        # mode: its virtual bar is that live sensor (demo.live); without the live path the
        # demo's simulated trace of the printed commands is collected instead (trace route)
        demo = self._demo
        printing, capture = (
            self._calibration.print_program(
                path, stated, prog_hash, arm=demo.ballbar is None or demo.live
            )
            if do_print
            else (False, None)
        )
        if printing:
            step["printed"] = now()
        self._campaigns.save(doc)
        if do_print and not printing:
            return http.error(gettext("The printer is not ready to print"), 409)
        return flask.jsonify(
            campaign=self._view(doc),
            path=path,
            printing=printing,
            program_hash=prog_hash,
            capture=capture,
        )

    def _within_limits(self, spec: TestSpec, n: int) -> None:
        """Refused (409) when the printer's motion limits, as they are now, no longer allow
        test ``n``'s planned feed (they were read or changed after the plan)."""
        try:
            choice = circle_feed(
                spec.plane,
                spec.radius_mm,
                spec.feed_mm_min,
                self._calibration.motion_limits(),
                overshoot_deg=spec.overshoot_deg,
            )
        except LimitsError as exc:
            raise Refused(exc.args[0], 409) from None
        if choice.lowered:
            raise Refused(
                Msg(
                    "Test %(n)s was planned at %(feed)s mm/min, but the printer's motion limits "
                    "allow %(allowed)s mm/min now (%(why)s): plan the campaign again",
                    n=n,
                    feed=f"{spec.feed_mm_min:g}",
                    allowed=f"{choice.feed_mm_min:g}",
                    why=joined(choice.reasons),
                ),
                409,
            )

    @http.route("/campaigns/<cid>/steps/<int:n>/trace", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def trace(self, cid: str, n: int):
        body = http.json_object()
        try:
            demo = http.flag(body or {}, "demo")
            force = http.flag(body, "force") if body is not None else _form_flag("force")
            doc, step = self.measure.open_step(cid, n, force)
            if body is not None and not demo:
                raise Refused(Msg("Give the trace file (multipart field 'file') or \"demo\": true"))
            if demo:
                data, filename = self._simulated(cid, step)
            else:
                data, filename = self._calibration.read_upload()
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except UploadRefused as exc:
            return http.error(exc.message, exc.status)
        except Refused as exc:
            return http.error(http.tr(exc.message), exc.status)
        name = safe_name(os.path.basename(filename))
        if not self._campaigns.claim(cid, step["name"]):  # the same test twice at once
            return http.error(http.tr(busy_test(doc, step).message), 409)

        def run(job, progress) -> None:  # in the job thread, its analysis in the worker
            def analyse(task, args):
                return self._calibration._job_api.jobs.worker.call(job.id, task, args, progress)

            try:
                run = self.measure.measure(
                    doc, step, data, name, force=force, analyse=analyse, claimed=True
                )
                job.result = run["id"]
            finally:
                self._campaigns.release(cid, step["name"])

        try:
            job = self._calibration._job_api.submit("analyse", None, run)
        except BaseException:  # (429: the job never runs)
            self._campaigns.release(cid, step["name"])
            raise
        return self._answer(
            job, lambda run_id: dict(campaign=self._view(doc), run=self._runs.get(run_id)), name
        )

    def _answer(self, job, body, name: Optional[str]):
        """The answer to a campaign request whose work is ``job``: as an analysis's
        (CalibrationApi.answer_job), a refusal with its own status."""
        answer = self._calibration.answer_job(job, body, name)
        if job.state == "failed" and isinstance(job.exception, Refused):
            return http.error(http.tr(job.exception.message), job.exception.status)
        return answer

    def _simulated(self, cid: str, step: Dict[str, Any]) -> Tuple[bytes, str]:
        """Demo mode's SIMULATED trace of ``step`` (Refused, 404, when there is none)."""
        simulated = self._demo.last_trace()
        if (
            simulated is None
            or simulated.meta.get("campaign") != cid
            or simulated.meta.get("campaign_step") != step["name"]
        ):
            raise Refused(
                Msg(
                    "No simulated trace of test %(n)s (%(name)s) yet: print its "
                    "program in demo mode first",
                    n=step["n"],
                    name=test_words(step["name"]),
                ),
                404,
            )
        return simulated.to_text().encode(), f"test{step['n']}_{step['name']}_simulated.csv"

    # ~~ the joint analysis and applying it ----------------------------------------------------
    @http.route("/campaigns/<cid>/analyze", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def analyze(self, cid: str):
        """The joint analysis of campaign ``cid``'s tests, in the worker process (a job as
        every analysis: CalibrationApi.analysis); stored under the campaign's lock."""
        current = self.measure.in_force()
        try:
            doc = self._campaigns.get(cid)
            self.measure.check_unchanged(doc)
            traces = self._traces(doc)
            origin = self._calibration.origin_for(trace_meta(traces[0][1]))
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)
        except Refused as exc:
            return http.error(http.tr(exc.message), exc.status)
        args = {"traces": traces, "current": current.to_dict(), "origin": origin}
        if not self._campaigns.claim(cid, "joint"):  # the joint analysis twice at once
            return http.error(gettext("This campaign is being analysed already"), 409)

        def run(job, progress) -> None:
            try:
                worker = self._calibration._job_api.jobs.worker
                result = worker.call(job.id, "analyse_campaign", args, progress)
                job.result = self._store_joint(doc, result, current)
            finally:
                self._campaigns.release(cid, "joint")

        try:
            job = self._calibration._job_api.submit("analyse", None, run)
        except BaseException:  # (429: the job never runs)
            self._campaigns.release(cid, "joint")
            raise
        return self._answer(job, lambda _: self._view(doc), None)

    def _store_joint(self, doc: Dict[str, Any], result: Dict[str, Any], current) -> str:
        """The joint analysis ``result`` of campaign ``doc`` stored as its run, under the
        campaign's lock (Refused when it was deleted or analysed meanwhile: nothing is
        stored); ``doc`` becomes the stored document. Returns the run's id."""
        cid = doc["id"]
        result = with_findings(result, _forced_steps(doc))
        camp = result["diagnostics"]["campaign"]
        for key in ("scale_rule", "servo_rule"):
            camp[key + "_i18n"] = as_dict(camp[key])
        camp["servo_precomp"]["reason_i18n"] = as_dict(camp["servo_precomp"]["reason"])
        extra = campaign_keys(cid, None, current)
        extra.update(
            plots=result["plots"],
            campaign_steps=[s["name"] for s in doc["steps"]],
            step_runs=[s["run"] for s in doc["steps"]],
            profile=doc.get("profile") or self._store.current().get("legacy_profile"),
        )

        started = doc.get("result")  # the result this analysis began from (None: the first)

        def link(fresh: Dict[str, Any]) -> str:
            if fresh.get("result") != started:  # another analysis stored meanwhile
                raise Refused(Msg("This campaign was analysed meanwhile"), 409)
            name = f"campaign {cid}"
            run = self._calibration.record_run(result, name, "campaign", None, None, extra)
            fresh["result"], fresh["analysed"] = run["id"], now()
            doc.clear()
            doc.update(fresh)
            return run["id"]

        try:
            return self._campaigns.change(cid, link)
        except CampaignNotFound:
            raise Refused(
                Msg("This campaign was deleted during its analysis: nothing was stored."),
                404,
            ) from None

    def _traces(self, doc: Dict[str, Any]) -> List[Tuple[str, bytes]]:
        """[(file name, trace file's data)] of the campaign's tests, in order; Refused names
        the first test without a measurement."""
        items = []
        for step in doc["steps"]:
            path = None
            try:
                run = self._runs.get(step.get("run") or "")
                path = self._runs.trace_path(run["id"])
            except RunNotFound:
                run = None
            if run is None or path is None:
                raise Refused(
                    Msg(
                        "The campaign is incomplete: test %(n)s (%(name)s, %(file)s) has no "
                        "measurement; nothing is analysed from a partial campaign",
                        n=step["n"],
                        name=test_words(step["name"]),
                        file=os.path.basename(step.get("path") or "-"),
                    )
                )
            with open(path, "rb") as f:
                items.append((run["filename"], f.read()))
        return items

    # ~~ deleting ---------------------------------------------------------------------------------
    @http.route("/campaigns/<cid>", "DELETE", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def delete(self, cid: str):
        """Deletes campaign ``cid`` of the printer profile in force (the runs of its tests and
        of its joint analysis stay in the history)."""
        try:
            doc = self._campaigns.get(cid)
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)
        s = self._store.current()
        if other_profile(doc.get("profile"), s):
            return http.error(
                gettext(
                    "This campaign belongs to printer profile %(profile)s, not to the one in "
                    "force: connect that printer to delete it.",
                    profile=doc.get("profile") or s["legacy_profile"],
                ),
                409,
            )
        busy = self._measuring(doc)
        if busy is not None:
            return http.error(http.tr(busy), 409)
        self._campaigns.delete(cid)
        return flask.jsonify(deleted=cid)

    def _measuring(self, doc: Dict[str, Any]) -> Optional[Msg]:
        """Why campaign ``doc`` is being measured right now (None: it is not): one of its
        test programs is printing or paused, or a live capture is armed for it."""
        printing = self._calibration.job_path()
        for step in doc["steps"]:
            if step.get("path") and step["path"] == printing:
                return Msg(
                    "Test %(n)s (%(name)s) of this campaign is being printed and measured "
                    "now: cancel the print or let it finish before deleting the campaign.",
                    n=step["n"],
                    name=test_words(step["name"]),
                )
        if self.armed_campaign is not None and self.armed_campaign() == doc["id"]:
            return Msg(
                "A live capture is armed for a test of this campaign: let it finish or stop "
                "it before deleting the campaign.",
            )
        return None

    @http.route("/campaigns/<cid>/apply", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def apply(self, cid: str):
        data = http.json_object() or {}
        try:
            apply_now, force = http.flag(data, "apply_now"), http.flag(data, "force")
            expected = http.expected_profile(data)
            doc = self._campaigns.get(cid)
            run = self._runs.get(doc.get("result") or "")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)
        except RunNotFound:
            return http.error(
                gettext("This campaign has no joint analysis to apply: analyse it first"),
                409,
            )
        refused = (
            self._calibration.other_printers(doc, gettext("This campaign"), force)
            or self._calibration.other_printers(run, force=force)
            or self._calibration.untrusted(run, force)
        )
        if refused is not None:
            return refused
        resp = self._calibration.apply_params(
            run["proposed"],
            apply_now,
            run,
            {"enabled": data["enabled"]} if "enabled" in data else None,
            expected,
        )
        if resp.status_code == 200:
            doc["applied"] = now()
            self._campaigns.save(doc)
        return resp

    def _view(
        self, doc: Dict[str, Any], stored: bool = True, analysis: bool = True
    ) -> Dict[str, Any]:
        return view(
            doc, self._runs, self._campaigns, self.measure.in_force().hash(), stored, analysis
        )
