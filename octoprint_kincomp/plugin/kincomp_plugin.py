"""KinComp's OctoPrint plugin class: a thin composition of the pieces of this package.

OctoPrint's mixin calls, hooks, events and routes arrive here and are handed on; the work
is done by the pieces, one room per page of the manual, in ``plugin/`` where they need
OctoPrint or Flask and in ``service/`` where they do not:

* settings     ``plugin/settings``: the stored settings (read, validated against
               ``service/settings/schema.py``, migrated, saved, applied to the queue), their
               endpoints and the motion limits read from the printer
* printing     ``service/printing``: the compensator as the queuing hook sees it, the
               firmware's own compensation, the speed factor; ``plugin/printing``: the
               connection and the print on it (begins, ends, pause after an error)
* files        ``plugin/files``: the files endpoints, the upload preprocessor and the jobs
               endpoints over ``service/files`` (background jobs in a low-priority worker)
* calibration  ``plugin/calibration``: tests, the history, campaigns and the artifact over
               ``service/calibration`` (the run and campaign stores, demo mode)
* capture      ``plugin/capture``: the live ballbar sensor (preview, arming, the end of a
               capture), stored as a run by ``service/capture``
* ``service/notify.py`` notifications, plugin messages and custom events; ``http`` request
  helpers and the permission KinComp adds
"""

from __future__ import annotations

import functools
import os
from typing import Any, Dict

import flask
import octoprint.plugin
from flask_babel import gettext
from octoprint.events import Events
from octoprint.util.comm import parse_position_line

from ..core.compensator import Options
from ..core.params import Params
from ..core.version import VERSION
from ..engines.select import engine
from ..service.calibration.campaign_measure import CampaignMeasurements
from ..service.calibration.campaign_store import CampaignStore
from ..service.calibration.demo_mode import DemoMode, lines_as_sent
from ..service.calibration.printed_programs import PrintedPrograms
from ..service.calibration.run_store import RunStore
from ..service.capture.capture_recorder import CaptureRecorder
from ..service.notify import CUSTOM_EVENTS, N_, Notifier
from ..service.printing.firmware_check import FirmwareCheck
from ..service.printing.firmware_watch import FirmwareWatcher
from ..service.printing.queue import FILE_TAG, HOME_QUERY, QueueCompensator
from ..service.printing.speed_factor import held_back
from ..service.request_gate import RequestGate
from ..service.settings.schema import SETTINGS_VERSION, defaults, form_fields
from ..service.settings.software_update import check_config
from . import http
from .calibration.artifact_api import ArtifactApi
from .calibration.calibration_api import MAX_TRACE_UPLOAD, CalibrationApi
from .calibration.campaign_api import CampaignApi
from .capture.sensor_api import SensorApi
from .files.files_api import FilesApi
from .printing.print_state import PRINT_EVENTS, PrintState
from .settings.limits_capture import LimitsCapture
from .settings.settings_api import SettingsApi
from .settings.settings_store import SettingsStore


class KinCompPlugin(
    octoprint.plugin.StartupPlugin,
    octoprint.plugin.ShutdownPlugin,
    octoprint.plugin.SettingsPlugin,
    octoprint.plugin.TemplatePlugin,
    octoprint.plugin.AssetPlugin,
    octoprint.plugin.BlueprintPlugin,
    octoprint.plugin.EventHandlerPlugin,
    octoprint.plugin.WizardPlugin,
):
    def __init__(self):
        super().__init__()
        self.watch = FirmwareWatcher()
        # the pieces, made in initialize() (OctoPrint injects what they use after __init__)
        self.notifier = self.queue = self.runs = self.store = self.demo = None
        self.firmware = self.prints = self.files = self.jobs = None
        self.settings_api = self.calibration = self.sensor = self.campaign = None
        self.limits = self.artifact = self.requests = None
        self._data_root = None

    # ~~ lifecycle ---------------------------------------------------------------------------
    def initialize(self):
        log, printer, files = self._logger, self._printer, self._file_manager
        self.notifier = notifier = Notifier(self._plugin_manager, self._event_bus, self._identifier)
        self.runs = RunStore(self.data_folder())
        # a run belongs to the printer profile in force when it is recorded
        self.runs.profile = lambda: self.store.current()["profile"]
        self.queue = queue = QueueCompensator(Params(), Options())
        # KinComp's requests rationed while a print runs (service/request_gate.py)
        self.requests = RequestGate(lambda: queue.printing)
        self.demo = DemoMode(notifier, log)
        self.firmware = FirmwareCheck(self.watch, queue, printer, notifier, log)
        self.store = SettingsStore(
            self._settings,
            self._identifier,
            self._printer_profile_manager,
            queue,
            notifier,
            log,
            on_applied=self._settings_applied,
        )
        self.files = FilesApi(self.store, queue, files, notifier, self.data_folder)
        self.jobs = self.files.jobs
        self.prints = PrintState(
            queue,
            self.watch,
            printer,
            files,
            notifier,
            log,
            on_begin=self._print_began,
            on_end=self._print_ended,
        )
        queue.on_error = self.prints.compensation_failed
        queue.on_untouched = self.prints.sent_as_written
        self.settings_api = SettingsApi(self.store, queue, self.watch, self.demo, self.jobs)
        self.limits = LimitsCapture(self.store, self._settings, printer, notifier, log)
        self.calibration = CalibrationApi(
            self.store, queue, self.runs, self.demo, notifier, printer, files, self.files.job_api
        )
        # what each test ran with: the firmware's compensation, the queue's compensator
        self.calibration.firmware_state = self.watch.state
        self.calibration.printed = PrintedPrograms(self.data_folder())
        self.calibration.firmware_name = lambda: self.limits.firmware
        self.demo.lines_as_sent = functools.partial(lines_as_sent, queue)
        recorder = CaptureRecorder(self.calibration, self.runs, queue, notifier)
        self.sensor = SensorApi(
            recorder, self.runs, self.demo, notifier, printer, files, log, self._settings.global_get
        )
        self.calibration.on_print = self.sensor.program_printing
        self.sensor.inside_uploads = self.files.inside_uploads  # one rule for files read
        self.settings_api.check = self.sensor.check_settings
        self.prints.compensated_for = self.store.compensated_for
        campaigns = CampaignStore(self.data_folder())
        campaigns.profile = self.runs.profile  # a campaign belongs to its printer too
        measurements = CampaignMeasurements(
            queue,
            self.runs,
            campaigns,
            self.calibration,
            notifier,
            self._printer_profile_manager,
            self.store,
        )
        recorder.on_recorded = measurements.take_capture  # a live capture of a campaign test
        self.campaign = CampaignApi(
            self.store, self.runs, campaigns, self.calibration, self.demo, measurements
        )
        self.campaign.armed_campaign = self.sensor.armed_campaign
        self.artifact = ArtifactApi(self.store, queue, self.calibration, self.files, self.demo)

    def data_folder(self) -> str:
        """The plugin's data folder (made if missing), absolute: OctoPrint's basedir may be
        relative (``./run.sh``), and it is resolved against the working directory once,
        here, not by each later reader against its own."""
        if self._data_root is None:
            self._data_root = os.path.abspath(self.get_plugin_data_folder())
        os.makedirs(self._data_root, exist_ok=True)
        return self._data_root

    def on_after_startup(self):
        self.store.apply(self.store.current(), immediately=True)
        self.store.follow_profile()  # settings from before profiles: adopted by this one
        self._logger.info(
            "KinComp %s ready (compensation %s, %s engine)",
            VERSION,
            "on" if self.queue.enabled else "off",
            engine(),
        )

    def on_shutdown(self):
        self.jobs.stop()  # the worker process ends; a file it was writing is removed

    def _settings_applied(self, s: Dict[str, Any]) -> None:
        self.demo.set_enabled(s["demo"]["enabled"], s["demo"]["live"])
        self.sensor.configure(s)
        self.firmware.check()

    def _print_began(self, payload: Dict[str, Any]) -> None:
        self.jobs.set_paused(True)  # file work must not starve the print
        if self.prints.test_program:  # what OctoPrint pauses at and blocks (its settings)
            get = self._settings.global_get
            self.prints.pausing_commands = frozenset(get(["serial", "pausingCommands"]) or ())
            self.prints.blocked_commands = frozenset(get(["serial", "blockedCommands"]) or ())
        self.demo.print_begins(payload)

    def _print_ended(self, done: bool) -> None:
        self.jobs.set_paused(False)
        self.demo.print_ends(done)
        self.sensor.print_ended(done)

    # ~~ settings ----------------------------------------------------------------------------
    def get_settings_defaults(self):
        return defaults()

    def get_settings_version(self):
        return SETTINGS_VERSION

    def on_settings_migrate(self, target, current):
        self.store.migrate(target, current)

    def on_settings_save(self, data):
        return self.store.dialog_save(data)

    # ~~ wizard, templates and assets --------------------------------------------------------
    def is_wizard_required(self):
        return True  # shown once (per wizard version): it introduces the calibration tab

    def get_wizard_version(self):
        return 1

    def is_template_autoescaped(self):
        return True

    def get_template_vars(self):
        # the settings page's plain fields, as declared (the template translates their texts)
        return {"settings_fields": form_fields()}

    def get_template_configs(self):
        return [
            {"type": "settings", "name": "KinComp", "custom_bindings": True},
            {"type": "tab", "name": gettext("KinComp calibration"), "custom_bindings": True},
            {"type": "wizard", "name": "KinComp", "custom_bindings": True},
            # one click to the tab from the top bar, however narrow the window
            {"type": "navbar", "custom_bindings": True},
        ]

    def get_assets(self):
        return {
            "js": [
                "js/kincomp_common.js",
                "js/kincomp_jobs.js",
                "js/kincomp_confirm_logic.js",
                "js/kincomp_settings_form.js",
                "js/kincomp_findings.js",
                "js/kincomp_result_logic.js",
                "js/kincomp_plot.js",
                "js/kincomp_sensor.js",
                "js/kincomp_campaign_draw.js",
                "js/kincomp_campaign.js",
                "js/kincomp_settings.js",
                "js/kincomp_limits.js",
                "js/kincomp_tab.js",
                "js/kincomp_artifact_logic.js",
                "js/kincomp_artifact.js",
                "js/kincomp_navbar.js",
            ],
            "css": ["css/kincomp.css", "css/kincomp_campaign.css"],
        }

    # ~~ hooks -------------------------------------------------------------------------------
    def queuing_hook(
        self, comm_instance, phase, cmd, cmd_type, gcode, subcode=None, tags=None, *args, **kwargs
    ):
        prints = self.prints
        if comm_instance is not prints.comm:
            if not prints.current(comm_instance):
                return None  # a retired connection's line: nothing of the print's changes
            # a new connection's profile decides the calibration before its first command
            self.store.follow_profile()
        if tags and FILE_TAG in tags and (not prints.file_lines_seen or "fileline:1" in tags):
            prints.file_line(tags)  # (a print's first line: the other lines change nothing)
        queue = self.queue
        if queue.halted:
            prints.follow_pause(comm_instance)
        if cmd[:1] in "MmSs":
            if FirmwareWatcher.relevant(cmd[:8]):
                self.firmware.sent(cmd)
            if self.sensor.waiting and cmd[:4] == "M117":
                self.sensor.command(cmd)  # the program's end marker ends the live capture
            if cmd[:4].upper() == "M220" and held_back(cmd, tags, self.calibration.test_printing()):
                self.notifier.notify(
                    "warning",
                    N_(
                        "A ballbar test is printing: the speed factor stays at 100 %% (%(command)s "
                        "was not sent). A test at another speed would not match its plan."
                    ),
                    command=cmd,
                )
                return (None,)
        result = queue.handle(cmd, tags)
        if self.demo.ballbar is not None:
            self.demo.record(cmd, result, tags)
        if prints.test_program and prints.program_pause(comm_instance, cmd, gcode, tags):
            return []  # paused here: OctoPrint would block it and warn (nothing is lost)
        return result

    def received_hook(self, comm_instance, line, *args, **kwargs):
        if comm_instance is not self.prints.comm:
            if not self.prints.current(comm_instance):
                return line  # a retired connection's late line is not the new one's
            self.store.follow_profile()
        self.firmware.received(line)
        self.limits.received(line)
        if self.queue.home_query_out:  # the firmware's answer to our M114 after G28
            position = parse_position_line(line)
            if position is not None:
                self.queue.home_reported(position)
        return line

    def sending_hook(
        self, comm_instance, phase, cmd, cmd_type, gcode, subcode=None, tags=None, *args, **kwargs
    ):
        # the "sending" phase runs before the write: in "sent" (after it) the firmware's
        # answer can already have been read on the monitor thread, and would be missed
        if cmd == HOME_QUERY and tags:
            self.queue.home_query_sent(tags)

    def preprocessor_hook(
        self,
        path,
        file_object,
        links=None,
        printer_profile=None,
        allow_overwrite=False,
        *args,
        **kwargs,
    ):
        return self.files.preprocess(path, file_object, printer_profile)

    def permissions_hook(self, *args, **kwargs):
        return http.permissions()

    def routes_hook(self, server_routes, *args, **kwargs):
        """KinComp's upload routes on its own Tornado handler (a full disk answers 507, its
        temporary files are its own: ``plugin/files/upload_handler.py``)."""
        from .files.upload_handler import routes

        return routes(self._settings.global_get)

    def bodysize_hook(self, current_max_body_sizes, *args, **kwargs):
        return [
            ("POST", r"/trace", MAX_TRACE_UPLOAD),
            ("POST", r"/campaigns/[^/]+/steps/[0-9]+/trace", MAX_TRACE_UPLOAD),
        ]

    def custom_events_hook(self, *args, **kwargs):
        return list(CUSTOM_EVENTS)

    def before_api_request_hook(self, plugin=None, *args, **kwargs):
        return [self.store.check_settings_request, self.ration_request]

    def ration_request(self):
        """KinComp's requests while a print runs (``service/request_gate.py``): one over its
        ration waits for its turn or is answered 429; None lets it through. (A before-request
        handler of every API blueprint, which OctoPrint adds after its login check: only
        KinComp's own are rationed.)"""
        if not flask.request.path.startswith(f"/plugin/{self._identifier}/"):
            return None
        return http.rationed(self.requests)

    def get_update_information(self, *args, **kwargs):
        """The software update plugin's check for new KinComp versions (software_update)."""
        return check_config(self.store.current()["software_update"], self._identifier)

    # ~~ events ------------------------------------------------------------------------------
    def on_event(self, event, payload):
        payload = payload or {}
        if event in PRINT_EVENTS:
            self.prints.on_event(event, payload)
        elif event == Events.FIRMWARE_DATA:
            self.firmware.query(payload)
            self.limits.firmware_data(payload)
        elif event in (
            Events.CONNECTED,
            Events.PRINTER_PROFILE_MODIFIED,
            Events.PRINTER_PROFILE_DELETED,
        ):
            # the calibration, bed volume (limits) and axis feeds belong to the printer
            # profile, which a connection may switch and the user may edit
            self.store.follow_profile()
        elif event == Events.TRANSFER_STARTED:
            self.prints.transfer_started()
        elif event == Events.PRINT_PAUSED:
            self.prints.paused()
        elif event == Events.PRINT_RESUMED:
            self.prints.resumed()
        elif event == Events.FILE_ADDED:
            self.files.file_added(payload)

    # ~~ API (each piece declares its own routes: http.route) ------------------------------
    def is_blueprint_protected(self):
        return True

    def is_blueprint_csrf_protected(self):
        return True

    def routed_pieces(self):
        """The pieces whose methods serve KinComp's routes."""
        return [
            self.settings_api,
            self.limits,
            self.calibration,
            self.artifact,
            self.campaign,
            self.sensor,
            self.files,
            self.files.job_api,
        ]

    def get_blueprint(self):
        if hasattr(self, "_blueprint"):
            return self._blueprint
        blueprint = super().get_blueprint()  # the error handlers declared below
        for piece in self.routed_pieces():
            http.register(blueprint, piece)
        return blueprint

    @octoprint.plugin.BlueprintPlugin.errorhandler(http.BadRequest)
    def bad_request_handler(self, exc):
        return http.bad_request(exc)

    @octoprint.plugin.BlueprintPlugin.errorhandler(OSError)
    def os_error_handler(self, exc):
        return http.os_error(exc)  # disk full: 507


def plugin_hooks(plugin: KinCompPlugin) -> Dict[str, Any]:
    return {
        # run last in queuing so other plugins' rewrites get compensated too
        "octoprint.comm.protocol.gcode.queuing": (plugin.queuing_hook, 10000),
        "octoprint.comm.protocol.gcode.received": plugin.received_hook,
        "octoprint.comm.protocol.gcode.sending": plugin.sending_hook,
        "octoprint.filemanager.preprocessor": (plugin.preprocessor_hook, 10000),
        "octoprint.access.permissions": plugin.permissions_hook,
        "octoprint.server.http.bodysize": plugin.bodysize_hook,
        "octoprint.server.http.routes": plugin.routes_hook,
        "octoprint.events.register_custom_events": plugin.custom_events_hook,
        "octoprint.server.api.before_request": plugin.before_api_request_hook,
        "octoprint.plugin.softwareupdate.check_config": plugin.get_update_information,
    }
