"""The live ballbar sensor on the OctoPrint side (issue 15): which sensor is in use, its live
preview, arming a capture when the test program is printed from the Calibration tab,
stopping it after the program's end marker, and the endpoints. Readings are mm, positive =
bar longer; noise in um; times in s.

* ``GET /sensor/ports``: the serial ports (pyserial's list) and the printer's own port.
* ``GET /sensor/status``: the capture's state, the current reading, the noise, the bar check
  (data, steady, in range), the armed program and the last live run.
* ``GET /sensor/live?seconds=``: the same plus the moving chart ``{"t": [s before now],
  "mm": [...]}``.
* ``POST /sensor/open``, ``/sensor/close``: the live preview (the port stays open while it
  is wanted, or while a capture runs).
* ``POST /sensor/arm`` ``{"path"}`` (a ballbar program in OctoPrint's storage, to be printed
  by other means), ``POST /sensor/stop`` (end the running capture; what it has is kept).
* ``GET /runs/<id>/raw``: a live run's raw sensor stream.

The sensor in use is the demo's virtual ballbar in demo mode (``demo.live``), else the one
of the ``sensor`` settings when it is enabled; its port must not be the printer's own.

Threads: the routes, the queuing hook (end marker) and the print events only take a short lock
(opening or closing a port may wait up to a second, in request threads only); the capture reads its
port in its own thread and its listener only queues; this piece's worker thread pushes the state to
the UI (plugin messages ``sensor``, about twice a second while the port is open), ends the capture a
grace time after the program's end, and hands a finished capture to
``service/capture/capture_recorder.py`` (analysis, run history, message ``sensor_run``, sent once
the port is let go; its ``test_of`` names the campaign test the program is, also when the capture
failed).
"""

from __future__ import annotations

import functools
import math
import os
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

import flask
from flask_babel import gettext
from octoprint.filemanager import FileDestinations

from ...calibration.ballbar.program import END_MARKER, ProgramError, TestSpec, spec_from_program
from ...core.messages import Msg, as_dict
from ...sensor import Capture, CaptureResult, SensorConfig, SensorError, list_ports
from ...sensor.live import bar_check
from ...sensor.run_detection import program_seconds
from ...service.calibration.demo_mode import DemoMode
from ...service.calibration.run_store import RunNotFound, RunStore
from ...service.capture.capture_recorder import CaptureRecorder
from ...service.notify import N_, Notifier
from ...service.settings.schema import SettingsError
from .. import http

END_GRACE_S = 5.0  # after the end marker, the data's end must be seen within this (or 3 dwells)
STOP_WAIT_S = 5.0  # a stopped capture that gives no result by then is recorded as failed
MOUNT_WAIT_S = 1800.0  # a program with a mount pause: the bar may be mounted this long
CHART_S, CHART_POINTS = 10.0, 150  # the pushed moving chart
MAX_PROGRAM_HEAD = 65536  # bytes of a program read for its ``; ballbar`` lines


def sensor_config(s: Dict[str, Any]) -> SensorConfig:
    """The SensorConfig of the (validated) ``sensor`` settings."""
    return SensorConfig.from_dict({k: v for k, v in s.items() if k != "enabled"})


@dataclass
class Armed:
    """A capture armed for one printed program."""

    spec: TestSpec
    program_hash: str
    path: str
    source: str  # "sensor" or "demo"
    previous: Optional[CaptureResult]  # the capture's result before it was armed
    stop_at: Optional[float] = None  # time.monotonic() at which to stop it
    stopped_at: Optional[float] = None
    # demo: stop this long after the virtual bar's stream ends (its end may not be known
    # yet when the program's end is seen: it is then re-read until it is)
    after_stream_s: Optional[float] = None


class SensorApi:
    def __init__(
        self,
        recorder: CaptureRecorder,
        runs: RunStore,
        demo: DemoMode,
        notifier: Notifier,
        printer,
        file_manager,
        logger,
        global_get: Callable[[List[str]], Any],
    ):
        self._recorder = recorder
        self._runs = runs
        self._demo = demo
        self._notifier = notifier
        self._printer = printer
        self._file_manager = file_manager
        self._logger = logger
        self._global_get = global_get
        # FilesApi.inside_uploads (set by the plugin): the disk path of a stored file, 403
        # for a link out of the uploads folder, as for every file a route reads
        self.inside_uploads: Optional[Callable[[str], str]] = None
        self._lock = threading.RLock()  # short: state only
        self._open_lock = threading.Lock()  # making, opening and closing captures
        self._settings: Dict[str, Any] = {"enabled": False, "port": ""}
        self._cap: Optional[Capture] = None
        self._source = ""
        self._armed: Optional[Armed] = None
        self.waiting = False  # a capture waits for its program's end (read by the hook)
        self._preview = False  # the user wants the live preview
        self._last_run: Optional[Dict[str, Any]] = None
        self._push_pending = False
        self._q: queue.Queue[Tuple[str, Optional[Capture]]] = queue.Queue()
        threading.Thread(target=self._loop, name="kincomp-sensor-ui", daemon=True).start()

    # ~~ which sensor ------------------------------------------------------------------------
    def configure(self, settings: Dict[str, Any]) -> None:
        """The settings were applied (any thread; returns at once)."""
        with self._lock:
            self._settings = dict(settings["sensor"])
        self._q.put(("configure", None))

    def _config(self, start: bool) -> Tuple[Optional[SensorConfig], str]:
        """(config, source) of the sensor in use: the demo's virtual bar (its port started
        if ``start``), the configured sensor, or (None, "")."""
        if self._demo.live:
            port = self._demo.sensor_port() if start else ""
            return SensorConfig(port=port or "", protocol="kincomp"), "demo"
        s = self._settings
        if s.get("enabled") and s.get("port"):
            return sensor_config(s), "sensor"
        return None, ""

    def printer_ports(self) -> List[str]:
        """The printer's port: its connection's and the one configured (not AUTO)."""
        ports = [self._global_get(["serial", "port"])]
        try:
            ports.append(self._printer.get_current_connection()[1])
        except Exception:
            pass
        return [p for p in ports if isinstance(p, str) and p and p.upper() != "AUTO"]

    def _printers(self, port: str) -> bool:
        def norm(p: str) -> str:
            return os.path.realpath(p) if p.startswith("/") else p.strip().lower()

        return norm(port) in {norm(p) for p in self.printer_ports()}

    def check_settings(self, s: Dict[str, Any]) -> None:
        """SettingsError when the sensor's port is the printer's own."""
        port = s["sensor"]["port"]
        if port and self._printers(port):
            raise SettingsError(
                "sensor.port",
                Msg("%(port)s is the printer's own port: choose the sensor's port", port=port),
            )

    def _capture(self) -> Capture:
        """The capture of the sensor in use (an outdated one closed and replaced); raises
        SensorError when no sensor is set or its port is the printer's."""
        cfg, source = self._config(start=True)
        if cfg is None or not cfg.port:
            raise SensorError(
                Msg("no live sensor is set: choose its port in KinComp's settings"), "port"
            )
        if self._printers(cfg.port):
            raise SensorError(
                Msg("%(port)s is the printer's own port: choose the sensor's port", port=cfg.port),
                "port",
            )
        cap = self._cap
        if cap is not None and cap.config == cfg:
            return cap
        if cap is not None:
            if self._armed is not None:
                raise SensorError(Msg("a capture is already running"))
            cap.close(wait_s=1.0)  # the port is locked until its thread has let go
        cap = Capture(cfg)
        cap.listener = functools.partial(self._listen, cap)
        with self._lock:
            self._cap, self._source = cap, source
        return cap

    # ~~ arming and ending ---------------------------------------------------------------------
    def program_printing(
        self, path: str, spec: TestSpec, program_hash: str
    ) -> Optional[Dict[str, Any]]:
        """CalibrationApi.on_print: the program at ``path`` is about to print: arm the
        capture (None when no sensor is in use). Never raises: a capture that cannot start
        is a message, the print goes on."""
        if self._config(start=False)[0] is None:
            return None
        try:
            self._arm(spec, program_hash, path)
        except SensorError as exc:
            self._notifier.notify(
                "error",
                N_("The live ballbar capture did not start: %(reason)s"),
                reason=exc.message,
            )
            return {
                "armed": False,
                "message": str(exc.message),
                "message_i18n": as_dict(exc.message),
            }
        return {"armed": True, "source": self._source, "port": self._cap.config.port}

    def armed_campaign(self) -> Optional[str]:
        """The campaign id of the test a capture is armed for now (None: none, or not a
        campaign's test)."""
        armed = self._armed
        return (armed.spec.campaign or None) if armed is not None else None

    def _arm(self, spec: TestSpec, program_hash: str, path: str) -> None:
        with self._open_lock:
            cap = self._capture()
            with self._lock:
                if self._armed is not None:
                    raise SensorError(Msg("a capture is already running"))
                previous = cap.result
                # a mount pause waits for the user: give them MOUNT_WAIT_S more to mount it
                cap.arm(
                    spec,
                    program_hash,
                    max_duration_s=3.0 * program_seconds(spec)
                    + (MOUNT_WAIT_S if spec.mount_pause else 300.0),
                )
                self._armed = Armed(spec, program_hash, path, self._source, previous)
                self.waiting = True
        self._request_push(cap)

    def command(self, cmd: str) -> None:
        """A command queued while a capture waits (M117 only): the program's end marker
        gives the data a grace time to show the end."""
        if END_MARKER in cmd:
            self._end_in(self._grace())

    def print_ended(self, done: bool) -> None:
        """The print ended: done gives the grace time, failed or cancelled stops now."""
        if self.waiting:
            self._end_in(self._grace() if done else 0.0)

    def _grace(self) -> float:
        armed = self._armed
        return max(END_GRACE_S, 3.0 * armed.spec.dwell_s) if armed else END_GRACE_S

    def _end_in(self, seconds: float) -> None:
        with self._lock:
            armed = self._armed
            if armed is None:
                return
            at = time.monotonic() + seconds
            if seconds and armed.source == "demo":
                armed.after_stream_s = seconds  # the virtual bar may still be playing
                at = max(at, self._stream_stop(armed, at))
            if armed.stop_at is None or at < armed.stop_at:
                armed.stop_at = at

    def _stream_stop(self, armed: Armed, at: float) -> float:
        """Demo: when to stop, after the virtual bar's stream (``at`` while it is not
        known: the caller asks again then)."""
        end = self._demo.stream_end()
        if end is None or armed.after_stream_s is None:
            return at
        if math.isinf(end):
            return at + armed.after_stream_s  # still simulating: look again then
        return end + armed.after_stream_s

    # ~~ the worker ------------------------------------------------------------------------------
    def _listen(self, cap: Capture, kind: str, status: Dict[str, Any]) -> None:
        """The capture's listener (its thread): queue, never wait."""
        if kind == "state" and status.get("state") in ("done", "failed"):
            self._q.put(("ended", cap))
        self._request_push(cap)

    def _request_push(self, cap: Optional[Capture]) -> None:
        if not self._push_pending:
            self._push_pending = True
            self._q.put(("push", cap))

    def _loop(self) -> None:
        while True:
            try:
                kind, cap = self._q.get(timeout=0.25)
            except queue.Empty:
                kind, cap = "", None
            try:
                if kind == "push":
                    self._push_pending = False
                    self._push(cap)
                elif kind == "ended":
                    self._ended(cap)
                elif kind == "configure":
                    self._reconfigure()
                self._watch()
            except Exception:
                self._logger.exception("KinComp: live sensor worker")

    def _push(self, cap: Optional[Capture]) -> None:
        if cap is not self._cap:
            return
        chart = cap.live(CHART_S, CHART_POINTS) if cap is not None else {}
        self._notifier.message(
            {
                "type": "sensor",
                "status": self._status(cap),
                "chart": {"t": chart.get("t", []), "mm": chart.get("mm", [])},
            }
        )

    def _watch(self) -> None:
        """Stop an armed capture when its time is up; record it once it has ended."""
        armed, cap = self._armed, self._cap
        if armed is None or cap is None:
            return
        result = cap.result  # None from when the capture took the arm request until its end
        if result is not None and result is not armed.previous:
            self._ended(cap)
            return
        now = time.monotonic()
        if armed.stop_at is not None and now >= armed.stop_at and armed.after_stream_s is not None:
            armed.stop_at = max(armed.stop_at, self._stream_stop(armed, armed.stop_at))
        if armed.stop_at is not None and now >= armed.stop_at:
            armed.stop_at, armed.stopped_at = None, now
            cap.stop()
        elif armed.stopped_at is not None and now - armed.stopped_at > STOP_WAIT_S:
            with self._lock:  # the stop came before the capture took the arm request
                self._armed, self.waiting = None, False
            self._recorded(
                self._recorder.record_missing(
                    armed, Msg("the capture did not start before it was stopped")
                ),
                cap,
                armed,
            )

    def _ended(self, cap: Optional[Capture]) -> None:
        with self._lock:
            armed = self._armed
            result = cap.result if cap is not None else None
            if armed is None or cap is not self._cap or result is None or result is armed.previous:
                return
            self._armed, self.waiting = None, False
        if not self._preview:  # first: reading the port would slow the analysis down
            self._release()
        self._recorded(self._recorder.record(result, armed, cap.config.port), cap, armed)

    def _recorded(self, run: Dict[str, Any], cap: Capture, armed: Armed) -> None:
        """Tell the UI: the run, and ``test_of`` the campaign's test the program is (also
        when the run is not that test's measurement: a failed capture, or one refused)."""
        self._last_run = {
            k: run.get(k)
            for k in (
                "id",
                "status",
                "message",
                "message_i18n",
                "simulated",
                "campaign",
                "campaign_step",
            )
        }
        spec = armed.spec
        self._last_run["test_of"] = (
            {"campaign": spec.campaign, "campaign_step": spec.campaign_step}
            if spec.campaign
            else None
        )
        if not self._preview:
            self._release()
        self._push(self._cap)
        self._reconfigure()
        # last: once told, the next test may be printed at once (a release after its arming
        # would close its capture)
        self._notifier.message({"type": "sensor_run", "run": self._last_run})

    def _reconfigure(self) -> None:
        """Close a capture whose sensor is no longer the one in use (not while armed)."""
        cap = self._cap
        if cap is None or self._armed is not None:
            return
        cfg, source = self._config(start=False)
        if cfg is None or source != self._source or (source == "sensor" and cfg != cap.config):
            self._preview = False  # another sensor: its live view is opened anew
            self._release()

    def _release(self) -> None:
        """Close the capture's port and stop the demo's virtual bar."""
        with self._open_lock:
            with self._lock:
                cap = self._cap
                if self._armed is None:  # else closing ends it, recorded as failed later
                    self._cap = None
            if cap is not None:
                cap.close(wait_s=1.0)
            if self._armed is None:
                self._demo.release_sensor()
        self._notifier.message(
            {"type": "sensor", "status": self._status(self._cap), "chart": {"t": [], "mm": []}}
        )

    # ~~ what the UI sees ------------------------------------------------------------------------
    def _status(self, cap: Optional[Capture]) -> Dict[str, Any]:
        cfg, source = self._config(start=False)
        if cap is not None:
            st = cap.status()
        else:
            st = {
                "state": "idle",
                "message": None,
                "port_open": False,
                "reading_mm": None,
                "noise_um": None,
                "last_data_age_s": None,
                "sensor": {},
                "diagnostics": {},
                "samples": 0,
                "runs_found": 0,
                "port": cfg.port if cfg else "",
                "protocol": cfg.protocol if cfg else "",
            }
        msg = st.get("message")
        armed = self._armed
        st.update(
            message=str(msg) if msg else None,
            message_i18n=as_dict(msg) if msg else None,
            check=bar_check(st),
            source=source,
            configured=cfg is not None,
            preview=self._preview,
            last_run=self._last_run,
            armed=None
            if armed is None
            else {
                "path": armed.path,
                "plane": armed.spec.plane,
                "radius_mm": armed.spec.radius_mm,
                "program_hash": armed.program_hash,
                "stopping": armed.stop_at is not None or armed.stopped_at is not None,
            },
        )
        return st

    # ~~ routes ------------------------------------------------------------------------------------
    @http.route("/sensor/status", "GET", needs=(http.STATUS,))
    def status(self):
        return flask.jsonify(self._status(self._cap))

    @http.route("/sensor/live", "GET", needs=(http.STATUS,))
    def live(self):
        try:
            seconds = min(60.0, max(1.0, float(flask.request.args.get("seconds", CHART_S))))
        except ValueError:
            return http.error(gettext("'seconds' must be a number"), 400)
        cap = self._cap
        chart = cap.live(seconds, 400) if cap is not None else {}
        return flask.jsonify(
            dict(self._status(cap), chart={"t": chart.get("t", []), "mm": chart.get("mm", [])})
        )

    @http.route("/sensor/ports", "GET", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def ports(self):
        return flask.jsonify(
            ports=list_ports(), printer_ports=self.printer_ports(), demo=self._demo.live
        )

    @http.route("/sensor/open", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def open(self):
        try:
            with self._open_lock:
                cap = self._capture()
                cap.open()
        except SensorError as exc:
            return http.error(http.tr(exc.message), 400)
        self._preview = True
        self._request_push(cap)
        return flask.jsonify(self._status(cap))

    @http.route("/sensor/close", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def close(self):
        self._preview = False
        self._release()
        return flask.jsonify(self._status(self._cap))

    @http.route("/sensor/arm", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def arm(self):
        """Arm for a program in OctoPrint's storage that the user prints by other means."""
        data = http.json_object() or {}
        path = data.get("path")
        if not isinstance(path, str) or not path:
            return http.error(
                gettext("Give 'path': a ballbar program in OctoPrint's local storage"), 400
            )
        try:
            exists = self._file_manager.file_exists(FileDestinations.LOCAL, path)
        except (ValueError, IndexError):  # OctoPrint's storage refuses the name (a lone
            exists = False  # "\\", ..) or trips over it ("./": IndexError in sanitize_path)
        if not exists:
            return http.error(gettext("No such file: %(path)s", path=path), 404)
        if self.inside_uploads is not None:
            disk = self.inside_uploads(path)  # a link out of the uploads folder: 403
        else:
            disk = self._file_manager.path_on_disk(FileDestinations.LOCAL, path)
        try:
            with open(disk, encoding="utf-8", errors="replace") as f:
                spec, program_hash = spec_from_program(f.read(MAX_PROGRAM_HEAD))
            self._arm(spec, program_hash, path)
        except (ProgramError, SensorError) as exc:
            return http.error(http.tr(getattr(exc, "message", exc)), 400)
        except OSError as exc:
            return http.error(
                gettext("%(path)s cannot be read: %(error)s", path=path, error=exc.strerror), 400
            )
        return flask.jsonify(self._status(self._cap))

    @http.route("/sensor/stop", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def stop(self):
        if self._armed is None:
            return http.error(gettext("No live capture is running"), 409)
        self._end_in(0.0)
        return flask.jsonify(self._status(self._cap))

    @http.route("/runs/<run_id>/raw", "GET", needs=(http.STATUS,))
    def raw(self, run_id: str):
        """A live run's raw sensor stream (``time_s,reading_mm,line``)."""
        try:
            self._runs.get(run_id)
            path = self._runs.raw_path(run_id)
        except RunNotFound:
            return http.error(gettext("No such calibration run"), 404)
        if path is None:
            return http.error(gettext("This run has no raw sensor stream"), 404)
        return flask.send_file(
            path, mimetype="text/csv", as_attachment=True, download_name=f"{run_id}_raw_stream.csv"
        )
