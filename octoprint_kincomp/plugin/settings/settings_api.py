"""KinComp's own status and settings endpoints.

* ``GET /status``: everything the UI shows at once: the settings, the parameter hash, which
  engine runs, the queue's compensation state, what the firmware compensates itself (and
  conflicts), the firmware equivalents of the parameters, demo mode, the bed limits (mm)
  and axis max feeds (mm/min) of the printer profile, the printer's motion limits
  (``motion_limits``: stated, read, combined with the profile; :mod:`.limits_capture`),
  the background jobs, the printer profile whose calibration is in force (``profile``:
  id, name, calibrated, known ids; ``service/settings/printer_profiles.py``), and what is wrong
  with the stored settings, if anything (``settings_problem``, its ``settings_problem_field``;
  compensation is off then, ``settings`` shows the invalid value as its default).
* ``POST /settings``: a partial settings document, merged into the stored one and validated
  whole (400 naming the field, nothing stored), saved and applied in one step under the
  store's lock (:meth:`SettingsStore.update`; 507 if the disk is full, nothing changed);
  ``"apply_now": true`` applies it mid-print. ``check``
  (set by the plugin) adds what needs OctoPrint's state (the sensor port must not be the
  printer's own). ``"expected_profile": "<id>"`` (the settings page sends the printer
  profile it was loaded for) makes the save conditional: 409 with ``profile_changed``
  (``expected``, ``current``) and nothing stored when another profile's set is in force
  now (a page opened for printer A and saved after a switch to B must not write A's values
  into B's set). Without it the save goes to the profile in force (scripts, the API).
"""

from __future__ import annotations

import flask
from flask_babel import gettext

from ...core.params import Params
from ...core.version import VERSION
from ...engines.select import engine
from ...firmware.export import equivalents
from ...service.calibration.demo_mode import DemoMode
from ...service.files.jobs import JobQueue
from ...service.printing.firmware_watch import FirmwareWatcher
from ...service.printing.queue import QueueCompensator
from ...service.settings.schema import SettingsError
from .. import http
from .limits_capture import status as limits_status
from .settings_store import ProfileChanged, SettingsStore


class SettingsApi:
    def __init__(
        self,
        store: SettingsStore,
        queue: QueueCompensator,
        watch: FirmwareWatcher,
        demo: DemoMode,
        jobs: JobQueue,
    ):
        self._store = store
        self._queue = queue
        self._watch = watch
        self._demo = demo
        self._jobs = jobs
        self.check = None  # check(settings): raises SettingsError; None: nothing more

    @http.route("/status", "GET", needs=(http.STATUS,))
    def status(self):
        store = self._store
        s = store.editable()
        params = Params.from_dict(s["params"])
        return flask.jsonify(
            version=VERSION,
            settings=s,
            profile=store.profile_status(s),
            params_hash=params.hash(),
            engine=engine(),
            compensation=self._queue.status(),
            firmware={
                "skew": self._watch.skew,
                "backlash": self._watch.backlash,
                "conflicts": self._watch.conflicts(params),
                # the state a test printed now runs with (firmware/compensation.py)
                "state": self._watch.state().to_dict(),
            },
            equivalents=http.with_i18n(equivalents(params)),
            demo=self._demo.ballbar is not None,
            limits=store.limits(),
            max_feeds=store.max_feeds(),
            motion_limits=limits_status(s, store.max_feeds()),
            jobs=[j.to_dict() for j in self._jobs.jobs.values()],
            settings_problem=(http.tr(store.problem) if store.problem is not None else None),
            settings_problem_field=(store.problem.field if store.problem is not None else None),
        )

    @http.route("/settings", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def save(self):
        data = http.json_object()
        if data is None:
            return http.error(gettext("Expected a JSON object"), 400)
        try:
            immediately = http.flag(data, "apply_now")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        data.pop("apply_now", None)
        try:
            expected = http.expected_profile(data)
        except http.BadRequest as exc:
            return http.error(str(exc), 400)

        def vet(stored, new):
            if self.check is not None:
                self.check(new)
            refused = http.update_source_refused(stored, new)
            if refused is not None:
                raise http.Refused(refused)

        try:
            new, _ = self._store.update(
                data, immediately=immediately or None, vet=vet, expected_profile=expected
            )
        except ProfileChanged as exc:
            return http.profile_changed(exc, self._store.profile_names())
        except SettingsError as exc:
            return http.error(http.tr(exc), 400)
        except http.Refused as exc:
            return exc.response
        return flask.jsonify(
            settings=new,
            params_hash=Params.from_dict(new["params"]).hash(),
            compensation=self._queue.status(),
        )
