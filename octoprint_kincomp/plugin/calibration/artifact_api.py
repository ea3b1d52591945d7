"""The printed-artifact endpoints (issue 27): calibrate with calipers.

* ``POST /artifact/program``  {mode: full|quick, planes, nozzle, temps: [nozzle, bed],
  first_layer, caliper, print}: writes KinComp's artifact for the printer profile's volume
  into OctoPrint's storage (``kincomp/artifact_<date>.gcode``), optionally prints it; answers
  with its path and :func:`sheet` (the numbered measurements and the drawing).
* ``GET /artifact/sheet?path=``  the same sheet for a stored artifact program.
* ``GET /artifact/stl?path=``  the stored artifact program's walls as a binary STL, to slice
  with the user's own profile (measured and analysed with that program's sheet).
* ``GET /artifact/simulated?path=``  demo mode only: SIMULATED readings of the stored program,
  as demo mode's printer (its hidden errors, the compensation in force) would have printed it.
* ``POST /artifact/analyze``  {path, readings: {"<id>": [mm, ...]}, simulated}: fits the readings
  (``calibration/artifact/fit.py``) with the parameters in force as those of the print, and
  stores the result as a calibration run (source ``artifact``; the readings are kept as its
  measurement file). Applying it and the history are those of every run (``/apply``,
  ``/runs``).

Errors are JSON ``{"error": ...}`` in the user's language, 400 naming the field.
"""

from __future__ import annotations

import datetime as _dt
import json
from typing import Any, Dict

import flask
from flask_babel import gettext
from octoprint.access.permissions import Permissions

from ...calibration.artifact.diagonals import ArtifactError, analyse_diagonals
from ...calibration.artifact.drawing import legend, svg
from ...calibration.artifact.program import (
    MODES,
    PLANES,
    ArtifactProgramError,
    ArtifactSpec,
    generate,
    read_measurements,
    read_program_info,
)
from ...calibration.artifact.stl import program_stl
from ...core.params import ParamsError
from ...simulator.artifact import demo_readings
from .. import http
from .calibration_api import CalibrationApi

MAX_PROGRAM_BYTES = 8 * 1024 * 1024
MAX_READINGS = 20  # repeats per measurement
MAX_LENGTH_PAIRS = 100  # nominal/measured pairs per axis of a printed square
DEFAULT_VOLUME = (0.0, 220.0, 0.0, 220.0, 0.0, 250.0)


def sheet(text: str, volume=None) -> Dict[str, Any]:
    """What the measuring form shows of a program: its measurements (numbered), the drawing
    and the program's settings."""
    meas = read_measurements(text)
    info = read_program_info(text)
    if volume is None and info.get("volume"):
        try:
            volume = [float(v) for v in info["volume"].split(",")]
        except ValueError:
            volume = None
    return {"measurements": legend(meas), "svg": svg(meas, volume), "info": info}


def _mode(data: Dict[str, Any]) -> str:
    mode = data.get("mode", "full")
    if mode not in MODES:
        raise http.BadRequest(
            gettext("'%(key)s' must be one of %(choices)s", key="mode", choices=", ".join(MODES))
        )
    return mode


class ArtifactApi:
    def __init__(self, store, queue, calibration: CalibrationApi, files_api, demo=None):
        self._store = store
        self._queue = queue
        self._calibration = calibration
        self._files = files_api
        self._demo = demo  # demo mode (service/calibration/demo_mode.py): simulated readings

    @http.route("/artifact/program", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def program(self):
        data = http.json_object() or {}
        try:
            do_print = http.flag(data, "print")
            planes = data.get("planes", list(PLANES))
            if isinstance(planes, str):
                planes = [p.strip() for p in planes.split(",") if p.strip()]
            if (
                not isinstance(planes, list)
                or not planes
                or not all(isinstance(p, str) and p.upper() in PLANES for p in planes)
            ):
                raise http.BadRequest(
                    gettext("'%(key)s' must be a list of XY, XZ, YZ", key="planes")
                )
            temps = http.numbers(data, "temps", 2, (210.0, 60.0))
            spec = ArtifactSpec(
                volume=tuple(self._store.limits() or DEFAULT_VOLUME),
                planes=tuple(p.upper() for p in planes),
                nozzle_mm=http.number(data, "nozzle", 0.4),
                hotend_c=temps[0],
                bed_c=temps[1],
                first_layer_mm=http.number(data, "first_layer", 0.2),
                max_span_mm=http.number(data, "caliper", 150.0),
                mode=_mode(data),
            )
            text = generate(spec, date=_dt.datetime.now().strftime("%Y-%m-%d %H:%M"))
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        except ArtifactProgramError as exc:
            return http.error(http.tr(exc.args[0] if exc.args else exc), 400)
        if do_print:
            http.require(Permissions.PRINT)
            if not self._calibration.printer_ready():  # (before a file is written)
                return http.error(gettext("The printer is not ready to print"), 409)
        name = f"artifact_{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}.gcode"
        path = self._calibration.store_program(text, name)
        printing = False
        if do_print:
            if not self._calibration.printer_ready():
                return http.error(gettext("The printer is not ready to print"), 409)
            self._calibration.start_print(path)
            printing = True
        out = sheet(text, spec.volume)
        out.update(path=path, printing=printing, lines=text.count("\n"))
        return flask.jsonify(out)

    def _read(self, path: Any) -> str:
        disk = self._files.local_file(path)  # aborts 400/403/404 as for every stored file
        try:
            with open(disk, encoding="utf-8", errors="replace") as f:
                return f.read(MAX_PROGRAM_BYTES)
        except OSError as exc:
            http.abort(
                400, gettext("%(path)s cannot be read: %(error)s", path=path, error=exc.strerror)
            )

    # (it reads a stored file's content: as OctoPrint's download does)
    @http.route("/artifact/sheet", "GET", needs=(http.STATUS, http.FILES_DOWNLOAD))
    def sheet(self):
        path = flask.request.args.get("path", "")
        text = self._read(path)
        try:
            out = sheet(text)
        except ArtifactProgramError as exc:
            return self._program_error(path, exc)
        out["path"] = path
        return flask.jsonify(out)

    def _program_error(self, path: str, exc: ArtifactProgramError):
        return http.error(
            gettext(
                "%(path)s: %(reason)s",
                path=path,
                reason=http.tr(exc.args[0] if exc.args else exc),
            ),
            400,
        )

    # (it reads a stored file's content: as OctoPrint's download does)
    @http.route("/artifact/stl", "GET", needs=(http.STATUS, http.FILES_DOWNLOAD))
    def stl(self):
        """The stored artifact program's walls as a binary STL (a download)."""
        path = flask.request.args.get("path", "")
        text = self._read(path)
        try:
            data = program_stl(text)
        except ArtifactProgramError as exc:
            return self._program_error(path, exc)
        name = str(path).rsplit("/", 1)[-1].rsplit(".", 1)[0] + ".stl"
        resp = flask.make_response(data)
        resp.headers["Content-Type"] = "model/stl"
        resp.headers["Content-Disposition"] = f'attachment; filename="{name}"'
        return resp

    # (demo mode's printer is no secret, but the readings are of a stored file)
    @http.route("/artifact/simulated", "GET", needs=(http.STATUS, http.FILES_DOWNLOAD))
    def simulated(self):
        """Demo mode: SIMULATED readings {"<id>": [mm, ...]} of the stored artifact program,
        printed by demo mode's printer with its hidden errors and the compensation in force;
        409 when demo mode is off."""
        ballbar = getattr(self._demo, "ballbar", None)
        if ballbar is None:
            return http.error(
                gettext("Simulated readings are there in demo mode only (KinComp's settings)"),
                409,
            )
        path = flask.request.args.get("path", "")
        text = self._read(path)
        try:
            readings = demo_readings(text, ballbar.truth.errors, self._queue.in_force)
        except ArtifactProgramError as exc:
            return self._program_error(path, exc)
        return flask.jsonify(readings=readings, simulated=True, path=path)

    def _analyze_square(self, square: Any):
        """A printed square (Marlin's and Klipper's calibration object, measured with
        calipers): its result stored as a run like every artifact's."""
        try:
            result = self._square(square)
        except http.BadRequest as exc:
            return http.error(gettext("Invalid artifact measurements: %(e)s", e=str(exc)), 400)
        except (ArtifactError, ParamsError, ArithmeticError, ValueError) as exc:
            return http.error(gettext("Invalid artifact measurements: %(e)s", e=http.tr(exc)), 400)
        return self._calibration.store_run(result, "printed artifact", "artifact", None)

    def _square(self, a: Any) -> Dict[str, Any]:
        """The result of a printed square's measurements ({plane, ac, bd, ad, lengths},
        mm), each field checked (:class:`http.BadRequest` naming it)."""
        if not isinstance(a, dict):
            raise http.BadRequest(gettext("'%(key)s' must be an object", key="square"))
        plane = http.choice(a, "plane", tuple(PLANES), "XY")
        ac, bd, ad = (http.number(a, k, None, "square.") for k in ("ac", "bd", "ad"))
        lengths = a.get("lengths") or {}
        if not isinstance(lengths, dict) or set(lengths) - set("xyzXYZ"):
            raise http.BadRequest(
                gettext(
                    "'%(key)s' must map the axes x, y, z to lists of [nominal, measured] mm",
                    key="square.lengths",
                )
            )
        pairs = {}
        for axis, items in lengths.items():
            where = f"square.lengths.{axis}"
            if (
                not isinstance(items, list)
                or not 0 < len(items) <= MAX_LENGTH_PAIRS
                or not all(isinstance(p, list) and len(p) == 2 for p in items)
            ):
                raise http.BadRequest(
                    gettext(
                        "'%(key)s' must be a list of 1..%(n)s [nominal, measured] pairs (mm)",
                        key=where,
                        n=MAX_LENGTH_PAIRS,
                    )
                )
            pairs[axis] = [tuple(http.number({"v": v}, "v", None, where) for v in p) for p in items]
        result = analyse_diagonals(plane, ac, bd, ad, pairs, self._queue.in_force)
        http.check_json(result["diagnostics"])  # an overflow (1e308 mm) is no measurement
        return result

    @http.route("/artifact/analyze", "POST", needs=(http.PLUGIN_KINCOMP_ADMIN,))
    def analyze(self):
        data = http.json_object()
        if data is None:
            return http.error(gettext("Expected a JSON object"), 400)
        if "square" in data:
            return self._analyze_square(data["square"])
        path = data.get("path")
        text = self._read(path)
        try:
            simulated = http.flag(data, "simulated")
        except http.BadRequest as exc:
            return http.error(str(exc), 400)
        raw = data.get("readings")
        if not isinstance(raw, dict) or any(
            isinstance(v, list) and len(v) > MAX_READINGS for v in raw.values()
        ):
            return http.error(
                gettext(
                    "'%(key)s' must map each measurement to at most %(n)s readings in mm",
                    key="readings",
                    n=MAX_READINGS,
                ),
                400,
            )
        # empty fields are not measured
        raw = {
            k: [v for v in (vals if isinstance(vals, list) else [vals]) if v is not None]
            for k, vals in raw.items()
        }
        known = self._calibration.known_now()
        args = {"text": text, "readings": raw, "current": known["current"], "simulated": simulated}
        name = str(path).rsplit("/", 1)[-1]

        def store(result: Dict[str, Any]) -> str:
            readings = result.pop("readings")
            result["diagnostics"]["plane"] = "+".join(result["diagnostics"]["planes"])
            result["diagnostics"]["program"] = path
            extra = {"profile": known["profile"]}
            raw_file = json.dumps(readings, indent=1).encode()
            return self._calibration.record_run(result, name, "artifact", raw_file, None, extra)[
                "id"
            ]

        # (in the worker process, as every analysis; a failure answers 400 naming the file)
        return self._calibration.analysis(
            "analyse_artifact", args, store, self._calibration._runs.get, name
        )
