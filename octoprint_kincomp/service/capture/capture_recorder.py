"""A finished live capture into the run history (called in the sensor worker thread, never in
the capture's listener or OctoPrint's comm thread; no request context needed).

* Done: the native trace (its metadata now also saying the firmware's compensation and how
  the queue compensated the program: what the test ran with) is analysed exactly as an
  uploaded file of it would be (its text is
  read back, so that the stored trace, an upload of it and an offline re-run of the stored
  raw stream all give the same result) with the parameters in force and, for a vertical test,
  the squareness the profile's history knows (``service/calibration/known_squareness.py``; offline:
  ``analyze --out-of-plane``), and stored as a run of source ``live`` (trace, raw stream, the
  sensor's and the capture's metadata under ``capture``). Nothing is applied.
* Failed (unplugged, no data, garbage, flood, stopped, the runs not found ...): a run with
  ``status: failed``, the message (English and as a translatable template) and the partial
  raw stream for inspection; the UI is told.

Readings are mm, positive = bar longer; times s; ``armed_at``/``ended_at`` ISO dates.
"""

from __future__ import annotations

import datetime as _dt
from typing import Any, Callable, Dict, Optional

from ...calibration.ballbar.formats import TraceError
from ...core.messages import as_dict, error_message
from ...sensor import CaptureResult
from ..calibration.run_store import RunStore
from ..notify import N_, Notifier
from ..printing.queue import QueueCompensator

SOURCE = "live"


def _record_origin(meta: Dict[str, str], origin: Dict[str, Any]) -> None:
    """The stored trace says what its test ran with (the firmware's compensation, how the
    queue compensated the program), so that an upload or an offline run of it reads the same."""
    from ...firmware.compensation import FirmwareCompensation

    if origin.get("firmware") is not None:
        meta.setdefault(
            "firmware_compensation", FirmwareCompensation.from_dict(origin["firmware"]).text()
        )
    for k, v in (origin.get("sent") or {}).items():
        meta.setdefault(k, str(v))


def _iso(wall: float) -> Optional[str]:
    return _dt.datetime.fromtimestamp(wall).isoformat(timespec="seconds") if wall else None


class CaptureRecorder:
    def __init__(self, calibration, runs: RunStore, queue: QueueCompensator, notifier: Notifier):
        self._calibration = calibration  # CalibrationApi: record_run
        self._runs = runs
        self._queue = queue
        self._notifier = notifier
        # on_recorded(run) -> run: a stored capture handed on (a campaign's test takes it)
        self.on_recorded: Optional[Callable[[Dict[str, Any]], Dict[str, Any]]] = None

    def record(self, res: CaptureResult, armed, port: str) -> Dict[str, Any]:
        """Store the capture ``res`` of ``armed`` (sensor_api.Armed) on ``port``; returns
        the run."""
        capture = self._metadata(res, armed, port)
        spec = res.spec
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        filename = f"live_{spec.plane}_R{spec.radius_mm:g}_{stamp}.csv"
        if not res.ok:
            return self._failed(res.message, capture, res)
        origin = self._calibration.origin_for(res.trace.meta, captured=True)
        _record_origin(res.trace.meta, origin)
        data = res.trace.to_text().encode()
        known = self._calibration.known_now()
        args = {"data": data, "name": filename, "current": known["current"]}
        args.update(known=known["known"], origin=origin)
        try:  # the one analysis of a measurement, in the worker process
            result = self._calibration.analyse_in_worker("analyse", args)
        except (TraceError, ValueError, ArithmeticError) as exc:
            return self._failed(error_message(exc), capture, res)
        result.pop("kind", None)
        run = self._calibration.record_run(
            result,
            filename,
            SOURCE,
            data,
            result.get("plot"),
            extra={"status": "ok", "capture": capture, "profile": known["profile"]},
        )
        self._save_raw(run["id"], res)
        return self.on_recorded(run) if self.on_recorded is not None else run

    def record_missing(self, armed, message) -> Dict[str, Any]:
        """A capture that ended without any result (``message`` says why)."""
        capture = {
            "source": armed.source,
            "program": armed.path,
            "program_hash": armed.program_hash,
            "samples": 0,
        }
        return self._failed(message, capture, None)

    def _metadata(self, res: CaptureResult, armed, port: str) -> Dict[str, Any]:
        stream = res.stream
        return {
            "source": armed.source,
            "port": port,
            "program": armed.path,
            "program_hash": res.program_hash,
            "armed_at": _iso(res.armed_at),
            "ended_at": _iso(res.ended_at),
            "duration_s": round(res.ended_at - res.armed_at, 3) if res.armed_at else None,
            "samples": len(stream) if stream is not None else 0,
            "sensor": dict(stream.meta) if stream is not None else {},
            "runs": res.runs,
            "diagnostics": res.diagnostics,
        }

    def _failed(
        self, message, capture: Dict[str, Any], res: Optional[CaptureResult]
    ) -> Dict[str, Any]:
        current = self._queue.in_force
        run_id = self._runs.new_id()
        plane = res.spec.plane if res is not None else None
        run = {
            "id": run_id,
            "date": _dt.datetime.now().isoformat(timespec="seconds"),
            "filename": f"live capture ({plane or '?'})",
            "source": SOURCE,
            "status": "failed",
            "message": str(message),
            "message_i18n": as_dict(message),
            "simulated": (capture.get("sensor") or {}).get("simulated") == "true",
            "params_before": current.to_dict(),
            "params_before_hash": current.hash(),
            "diagnostics": {"plane": plane} if plane else {},
            "proposed": None,
            "firmware": None,
            "notes": [],
            "notes_i18n": [],
            # the failure as the run's one finding: nothing here can be trusted
            "findings": [
                {
                    "code": "capture.failed",
                    "severity": "error",
                    "message": as_dict(message),
                    "advice": {"text": ""},
                    "evidence": {},
                }
            ],
            "trusted": False,
            "plot": None,
            "applied": None,
            "capture": capture,
        }
        self._save_raw(run_id, res)
        self._runs.save(run)
        self._notifier.notify(
            "error",
            N_(
                "The live ballbar capture failed: %(reason)s. The "
                "data so far is kept in the history; the print "
                "itself is not affected."
            ),
            reason=message,
        )
        return run

    def _save_raw(self, run_id: str, res: Optional[CaptureResult]) -> None:
        if res is not None and res.stream is not None:
            self._runs.save_raw(run_id, res.stream.to_text().encode())
