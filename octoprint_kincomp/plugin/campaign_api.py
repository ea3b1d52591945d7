"""The campaign endpoints: one calibration round over the whole volume (XY, XZ and YZ;
optionally XY at a second height and at a second feed), planned on the printer profile's
volume, printed test by test with the same parameters in force, fitted jointly
(:mod:`..ballbar.campaign_analysis`) and applied once.

* ``POST /campaign/plan``  plans a campaign (``radius_xy``, ``radius_vertical`` mm,
  ``feed`` mm/min, ``xy_height`` mm above the bed, ``second_height`` absolute Z of a second
  XY test in mm or null, ``second_feed`` mm/min or null, ``retest_of`` an earlier campaign
  whose options are the defaults and whose result is the "before"); ``"dry_run": true``
  only answers the plan (for the drawing), else it is stored.
* ``GET /campaigns``, ``GET /campaigns/<id>``  the campaigns, newest first; one campaign with
  its progress and, once analysed, the joint result and per test the comparison with the
  campaign it re-tests (the paper's Table 2 per plane).
* ``POST /campaigns/<id>/steps/<n>/program``  writes test n's program (n from 1) into
  OctoPrint's storage, ``"print": true`` prints it (it pauses (M0) to mount the bar and to
  unmount it).
* ``POST /campaigns/<id>/steps/<n>/trace``  test n's measurement: a file (multipart field
  ``file``) or ``{"demo": true}`` for demo mode's SIMULATED trace; it must be this test's
  trace (campaign, test, program and parameters in its metadata); analysed on its own and
  stored as a run of the campaign.
* ``POST /campaigns/<id>/analyze``  the joint fit over all tests, stored as a run (source
  ``campaign``): ONE parameter set; nothing applied. Refused (400 naming the file) for a
  missing or failed test or traces that are not one campaign.
* ``POST /campaigns/<id>/apply``  that parameter set into the settings (``enabled``,
  ``apply_now`` as for ``/apply``).

"In force" are the parameters the printed programs are compensated with: the current ones
while compensation is on, none (zero) while it is off. A campaign keeps the hash of those it
began with; when they (or the printer profile) change, it cannot go on (409): a joint fit of
tests measured under different parameters would be wrong. Reading needs STATUS, everything
else PLUGIN_KINCOMP_ADMIN, printing also PRINT.
"""

from __future__ import annotations

import math
import os
from typing import Any, Dict, List, Optional, Tuple

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions

from ..ballbar.analysis import analyse
from ..ballbar.campaign import plan_campaign
from ..ballbar.campaign_analysis import analyse_campaign
from ..ballbar.formats import AngleTrace, NativeTrace, TraceError, load_any
from ..ballbar.program import ProgramError, TestSpec, generate
from ..core.messages import as_dict
from ..core.params import Params
from . import http
from .calibration_api import CalibrationApi, UploadRefused, safe_name
from .campaigns import CampaignNotFound, CampaignStore, new_campaign, now, view
from .demo_mode import DemoMode
from .queue import QueueCompensator
from .runs import RunNotFound, RunStore
from .settings_store import SettingsStore

# request field: (default, lowest, highest); None as default: optional (null: left out)
PLAN_FIELDS = {
    "radius_xy": (100.0, 5.0, 1000.0),  # mm
    "radius_vertical": (50.0, 5.0, 1000.0),  # mm
    "feed": (1850.0, 10.0, 60000.0),  # mm/min
    "xy_height": (10.0, 0.0, 10000.0),  # mm above the bed
    "second_height": (None, -10000.0, 10000.0),  # mm, absolute Z
    "second_feed": (None, 10.0, 60000.0),  # mm/min
}


def number(data: Dict[str, Any], key: str, default: Optional[float], lo: float,
           hi: float) -> Optional[float]:
    """The JSON number ``data[key]`` (``default`` when absent; None when null and
    optional); raises http.BadRequest naming ``key`` for anything else or out of range."""
    value = data.get(key, default)
    if value is None and default is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or not lo <= value <= hi:
        raise http.BadRequest(gettext("'%(key)s' must be a number from %(lo)s to %(hi)s",
                                      key=key, lo=f"{lo:g}", hi=f"{hi:g}"))
    return float(value)


class CampaignApi:
    def __init__(self, store: SettingsStore, queue: QueueCompensator, runs: RunStore,
                 campaigns: CampaignStore, calibration: CalibrationApi, demo: DemoMode,
                 profiles):
        self._store = store
        self._queue = queue
        self._runs = runs
        self._campaigns = campaigns
        self._calibration = calibration
        self._demo = demo
        self._profiles = profiles

    # ~~ what is in force ----------------------------------------------------------------------
    def in_force(self) -> Params:
        """The parameters the programs are compensated with (none while compensation is
        off)."""
        return self._queue.params if self._queue.enabled else Params()

    def printer(self) -> Optional[str]:
        """The printer profile's name (the traces' ``printer``)."""
        try:
            profile = self._profiles.get_current_or_default() or {}
        except Exception:  # noqa: BLE001 - no profile: no name
            return None
        name = profile.get("name") or profile.get("id")
        return str(name) if name else None

    def _unchanged(self, doc: Dict[str, Any]):
        """None if the campaign may go on, else the 409 answer saying what changed."""
        force = self.in_force().hash()
        if force != doc["params_hash"]:
            return http.error(gettext(
                "The parameters in force changed since campaign %(id)s began (%(then)s, now "
                "%(now)s): all tests of a campaign must be measured with the same parameters. "
                "Start a new campaign.", id=doc["id"], then=doc["params_hash"], now=force), 409)
        printer = self.printer()
        if doc.get("printer") and printer != doc["printer"]:
            return http.error(gettext(
                "The printer profile changed since campaign %(id)s began (%(then)s, now "
                "%(now)s): a campaign is measured on one printer. Start a new campaign.",
                id=doc["id"], then=doc["printer"], now=printer or "-"), 409)
        return None

    # ~~ planning --------------------------------------------------------------------------------
    def plan(self):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = http.json_object()
        if data is None:
            return http.error(gettext("Expected a JSON object"), 400)
        before = None
        try:
            dry_run = http.flag(data, "dry_run")
            if data.get("retest_of") is not None:
                before = self._campaigns.get(str(data["retest_of"]))
                data = dict(before.get("options") or {}, **{k: v for k, v in data.items()
                                                           if k in PLAN_FIELDS})
            options = {k: number(data, k, *v) for k, v in PLAN_FIELDS.items()}
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except CampaignNotFound:
            return http.error(gettext("'retest_of': no such campaign"), 400)
        volume = self._store.limits()
        if volume is None:
            return http.error(gettext("The printer profile has no build volume"), 409)
        cid = self._campaigns.new_id()
        try:
            steps = plan_campaign(
                volume, radius_xy=options["radius_xy"],
                radius_vertical=options["radius_vertical"], feed=options["feed"],
                xy_height=options["xy_height"], second_height=options["second_height"],
                second_feed=options["second_feed"], max_feed=self._store.max_feeds(),
                printer=self.printer(), campaign_id=cid)
        except (ProgramError, ValueError) as exc:
            return http.error(http.tr(exc), 400)
        doc = new_campaign(cid, steps, volume, self.printer(), self.in_force().hash(), options,
                           before["id"] if before else None)
        if dry_run:
            return flask.jsonify(self._view(doc, stored=False))
        self._campaigns.save(doc)
        return flask.jsonify(self._view(doc))

    # ~~ reading -------------------------------------------------------------------------------
    def list(self):
        http.require(Permissions.STATUS)
        return flask.jsonify(campaigns=[self._view(d, analysis=False)
                                        for d in self._campaigns.list()])

    def get(self, cid: str):
        http.require(Permissions.STATUS)
        try:
            return flask.jsonify(self._view(self._campaigns.get(cid)))
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)

    # ~~ one test --------------------------------------------------------------------------------
    def _step(self, cid: str, n: int):
        """(campaign, its test n) for a request that goes on with it, or (None, the answer
        refusing it)."""
        try:
            doc = self._campaigns.get(cid)
        except CampaignNotFound:
            return None, http.error(gettext("No such campaign"), 404)
        if not 1 <= n <= len(doc["steps"]):
            return None, http.error(gettext("Campaign %(id)s has no test %(n)s", id=cid, n=n),
                                    404)
        if doc.get("result"):
            return None, http.error(gettext(
                "Campaign %(id)s is analysed and closed: to measure again, start a re-test "
                "campaign.", id=cid), 409)
        return doc, self._unchanged(doc)

    def program(self, cid: str, n: int):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        try:
            do_print = http.flag(http.json_object() or {}, "print")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        if do_print:
            http.require(Permissions.PRINT)
        doc, refused = self._step(cid, n)
        if refused is not None:
            return refused
        step = doc["steps"][n - 1]
        try:
            text = generate(TestSpec(**step["spec"]), volume=self._store.limits(),
                            params_hash=doc["params_hash"])
        except (ProgramError, TypeError, ValueError) as exc:
            return http.error(http.tr(exc), 400)
        path, prog_hash = self._calibration.write_program(
            text, f"{cid}_{n}_{safe_name(step['name'])}.gcode")
        step["path"] = path
        step["program_hash"] = prog_hash
        printing = do_print and self._calibration.print_program(path)
        if printing:
            step["printed"] = now()
        self._campaigns.save(doc)
        if do_print and not printing:
            return http.error(gettext("The printer is not ready to print"), 409)
        return flask.jsonify(campaign=self._view(doc), path=path, printing=printing,
                             program_hash=prog_hash)

    def trace(self, cid: str, n: int):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        body = http.json_object()
        try:
            demo = http.flag(body or {}, "demo")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        doc, refused = self._step(cid, n)
        if refused is not None:
            return refused
        step = doc["steps"][n - 1]
        if body is not None and not demo:
            return http.error(gettext("Give the trace file (multipart field 'file') or "
                                      "\"demo\": true"), 400)
        if demo:
            simulated = self._demo.last_trace()
            if simulated is None or simulated.meta.get("campaign") != cid or \
                    simulated.meta.get("campaign_step") != step["name"]:
                return http.error(gettext("No simulated trace of test %(n)s (%(name)s) yet: "
                                          "print its program in demo mode first", n=n,
                                          name=step["name"]), 404)
            data = simulated.to_text().encode()
            filename = f"test{n}_{step['name']}_simulated.csv"
        else:
            try:
                data, filename = self._calibration.read_upload()
            except UploadRefused as exc:
                return http.error(exc.message, exc.status)
        name = safe_name(os.path.basename(str(filename)))
        current = self.in_force()
        try:
            trace = load_any(data, name)
            wrong = self._not_this_test(trace, doc, step)
            if wrong is not None:
                return http.error(gettext("%(name)s: %(reason)s", name=name, reason=wrong),
                                  400)
            result = analyse(trace, current=current)
        except (TraceError, ProgramError, ValueError, ArithmeticError) as exc:
            return http.error(gettext("%(name)s: %(reason)s", name=name,
                                      reason=http.tr(exc)), 400)
        run = self._calibration.record_run(
            result, name, trace.kind, data, result.get("plot"),
            self._campaign_keys(cid, step["name"], current))
        step["run"] = run["id"]
        step["measured"] = now()
        self._campaigns.save(doc)
        return flask.jsonify(campaign=self._view(doc), run=self._runs.get(run["id"]))

    @staticmethod
    def _not_this_test(trace, doc: Dict[str, Any], step: Dict[str, Any]) -> Optional[str]:
        """Why ``trace`` is not the measurement of ``step`` of campaign ``doc`` (None: it
        is)."""
        if not isinstance(trace, (NativeTrace, AngleTrace)):
            return gettext("a campaign test needs a measured trace (native or angle CSV) "
                           "written with the test's program, not a summary")
        meta = trace.meta
        got = (meta.get("campaign") or "").strip()
        if got != doc["id"]:
            return gettext("it belongs to campaign %(other)s, not to %(id)s",
                           other=got or "-", id=doc["id"])
        got = (meta.get("campaign_step") or "").strip()
        if got != step["name"]:
            return gettext("it is the trace of test %(other)s, not of test %(n)s (%(name)s)",
                           other=got or "-", n=step["n"], name=step["name"])
        got = (meta.get("program_hash") or "").strip()
        if got != step["program_hash"]:
            return gettext("its program (program_hash %(got)s) is not test %(n)s's program "
                           "(%(want)s): the metadata does not match the program",
                           got=got or "-", n=step["n"], want=step["program_hash"])
        got = (meta.get("params_hash") or "").strip()
        if got != doc["params_hash"]:
            return gettext("it was measured with parameters %(got)s, but the campaign runs "
                           "with %(want)s", got=got or "-", want=doc["params_hash"])
        got = (meta.get("printer") or "").strip()
        if doc.get("printer") and got != doc["printer"]:
            return gettext("it comes from printer %(got)s, but the campaign is for "
                           "%(want)s", got=got or "-", want=doc["printer"])
        return None

    @staticmethod
    def _campaign_keys(cid: str, step: Optional[str], current: Params) -> Dict[str, Any]:
        return {"campaign": cid, "campaign_step": step, "params_before": current.to_dict(),
                "params_before_hash": current.hash()}

    # ~~ the joint analysis and applying it ----------------------------------------------------
    def analyze(self, cid: str):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        try:
            doc = self._campaigns.get(cid)
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)
        refused = self._unchanged(doc)
        if refused is not None:
            return refused
        current = self.in_force()
        try:
            items = self._traces(doc)
            result = analyse_campaign(items, current=current)
        except _Missing as exc:
            return http.error(str(exc), 400)
        except (TraceError, ProgramError, ValueError, ArithmeticError) as exc:
            return http.error(http.tr(exc), 400)
        camp = result["diagnostics"]["campaign"]
        for key in ("scale_rule", "servo_rule"):
            camp[key + "_i18n"] = as_dict(camp[key])
        camp["servo_precomp"]["reason_i18n"] = as_dict(camp["servo_precomp"]["reason"])
        extra = self._campaign_keys(cid, None, current)
        extra.update(plots=result["plots"], campaign_steps=[s["name"] for s in doc["steps"]],
                     step_runs=[s["run"] for s in doc["steps"]])
        run = self._calibration.record_run(result, f"campaign {cid}", "campaign", None, None,
                                           extra)
        doc["result"] = run["id"]
        doc["analysed"] = now()
        self._campaigns.save(doc)
        return flask.jsonify(self._view(doc))

    def _traces(self, doc: Dict[str, Any]) -> List[Tuple[str, object]]:
        """[(file name, trace)] of the campaign's tests, in order; _Missing names the first
        test without a measurement."""
        items = []
        for step in doc["steps"]:
            path = None
            try:
                run = self._runs.get(step.get("run") or "")
                path = self._runs.trace_path(run["id"])
            except RunNotFound:
                run = None
            if run is None or path is None:
                raise _Missing(gettext(
                    "The campaign is incomplete: test %(n)s (%(name)s, %(file)s) has no "
                    "measurement; nothing is analysed from a partial campaign", n=step["n"],
                    name=step["name"], file=os.path.basename(step.get("path") or "-")))
            with open(path, "rb") as f:
                items.append((run["filename"], load_any(f.read(), run["filename"])))
        return items

    def apply(self, cid: str):
        http.require(Permissions.PLUGIN_KINCOMP_ADMIN)
        data = http.json_object() or {}
        try:
            apply_now = http.flag(data, "apply_now")
            doc = self._campaigns.get(cid)
            run = self._runs.get(doc.get("result") or "")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except CampaignNotFound:
            return http.error(gettext("No such campaign"), 404)
        except RunNotFound:
            return http.error(gettext("Campaign %(id)s has no joint analysis to apply: "
                                      "analyse it first", id=cid), 409)
        resp = self._calibration.apply_params(
            run["proposed"], apply_now, run,
            {"enabled": data["enabled"]} if "enabled" in data else None)
        if resp.status_code == 200:
            doc["applied"] = now()
            self._campaigns.save(doc)
        return resp

    def _view(self, doc: Dict[str, Any], stored: bool = True,
              analysis: bool = True) -> Dict[str, Any]:
        return view(doc, self._runs, self._campaigns, self.in_force().hash(), stored, analysis)


class _Missing(Exception):
    """A test of the campaign has no measurement."""
