"""Calibration history: one JSON file per run in the plugin's data folder (no OctoPrint import).

A run records when it was made, where its data came from (trace, .b5r, typed summary,
printed artifact; simulated or not), the parameters active during the test, the analysis
(diagnostics), the proposed parameters, and whether and when they were applied. A trace
file, if any, is kept next to it. Run ids are generated here and checked on every lookup,
so a request can never name a path outside the runs folder. A run that is not plain JSON
(a NaN or an infinity) is never stored; one stored by an older version is read with those
numbers as null, so it can still be shown.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import secrets
from typing import Any, Dict, List, Optional

from ..core.atomic import write_atomic

_ID = re.compile(r"[0-9]{8}-[0-9]{6}-[0-9a-f]{6}")
MAX_RUNS_LISTED = 500


class RunNotFound(KeyError):
    pass


class RunNotStorable(ValueError):
    """The run holds a number that is not finite (or something that is not JSON)."""


class RunStore:
    def __init__(self, data_folder: str):
        self.folder = os.path.join(data_folder, "runs")
        os.makedirs(self.folder, exist_ok=True)

    def _path(self, run_id: str, suffix: str = ".json") -> str:
        if not isinstance(run_id, str) or not _ID.fullmatch(run_id):
            raise RunNotFound(run_id)
        return os.path.join(self.folder, run_id + suffix)

    def new_id(self) -> str:
        now = _dt.datetime.now()
        return now.strftime("%Y%m%d-%H%M%S-") + secrets.token_hex(3)

    def save(self, run: Dict[str, Any], trace: Optional[bytes] = None) -> None:
        """Stores ``run`` (and its measurement file ``trace``); :class:`RunNotStorable`
        (nothing stored) if it is not plain JSON."""
        path = self._path(run["id"])
        try:
            text = json.dumps(run, indent=1, sort_keys=True, default=float, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise RunNotStorable(str(exc)) from None
        if trace is not None:
            self.save_trace(run["id"], trace)
        write_atomic(path, text.encode())

    def save_trace(self, run_id: str, data: bytes) -> str:
        path = self._path(run_id, ".trace")
        write_atomic(path, data)
        return path

    def trace_path(self, run_id: str) -> Optional[str]:
        path = self._path(run_id, ".trace")
        return path if os.path.exists(path) else None

    def get(self, run_id: str) -> Dict[str, Any]:
        path = self._path(run_id)
        try:
            with open(path, encoding="utf-8") as f:
                return json.load(f, parse_constant=lambda name: None)  # NaN, Infinity
        except (OSError, ValueError, RecursionError):
            raise RunNotFound(run_id) from None

    def list(self) -> List[Dict[str, Any]]:
        """Summaries, newest first."""
        out = []
        names = sorted((n for n in os.listdir(self.folder) if n.endswith(".json")),
                       reverse=True)[:MAX_RUNS_LISTED]
        for name in names:
            run_id = name[:-5]
            if not _ID.fullmatch(run_id):
                continue
            try:
                run = self.get(run_id)
            except RunNotFound:
                continue
            d = run.get("diagnostics") or {}
            out.append({
                "id": run_id,
                "date": run.get("date"),
                "source": run.get("source"),
                "simulated": bool(d.get("simulated") or run.get("simulated")),
                "plane": d.get("plane"),
                "filename": run.get("filename"),
                "squareness_um_per_m": d.get("squareness_um_per_m"),
                "circularity_um": (d.get("circularity_um") or {}).get("bidirectional"),
                "applied": run.get("applied"),
                "params_before_hash": run.get("params_before_hash"),
                "has_trace": self.trace_path(run_id) is not None,
            })
        return out

    def delete(self, run_id: str) -> None:
        for suffix in (".json", ".trace"):
            path = self._path(run_id, suffix)
            if os.path.exists(path):
                os.unlink(path)
