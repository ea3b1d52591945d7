"""Calibration history: one JSON file per run in the plugin's data folder (no OctoPrint import).

A run records when it was made, where its data came from (trace, .b5r, typed summary,
printed artifact; simulated or not), the parameters active during the test, the analysis
(diagnostics), the proposed parameters, and whether and when they were applied; a run of a
campaign also its campaign id and test (``campaign``, ``campaign_step``; the joint analysis
has no test). A trace file, if any, is kept next to it, and for a live capture the sensor's
raw stream (``.raw``); a live capture that failed is a run too (``status: failed``, its
message, its partial data). Run ids are generated here and checked on every lookup, so a
request can never name a path outside the runs folder (the campaign store, ``campaign_store.py``,
keeps its documents by the same rules). A run that is not plain JSON (a NaN or an infinity)
is never stored; one stored by an older version is read with those numbers as null, so it
can still be shown. A new run is tagged with the printer profile in force (``profile``); the
history lists the runs of one profile.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import secrets
import threading
from typing import Any, Callable, Dict, List, Optional, Tuple

from ...calibration.findings import worst_first
from ...core.atomic import write_atomic
from .findings_view import verdict_of

_ID = re.compile(r"[0-9]{8}-[0-9]{6}-[0-9a-f]{6}")
MAX_RUNS_LISTED = 500


# what :func:`slim` keeps of a run (besides the parts of its diagnostics and proposal below)
_SLIM = (
    "id",
    "date",
    "source",
    "simulated",
    "filename",
    "applied",
    "trusted",
    "verdict",
    "params_before_hash",
    "status",
    "message",
    "campaign",
    "campaign_step",
    "profile",
)
_SLIM_DIAGNOSTICS = ("simulated", "plane", "planes", "squareness_um_per_m", "scale_mismatch_ppm")


def slim(run: Dict[str, Any]) -> Dict[str, Any]:
    """What the history's row (:meth:`RunStore.summary`) and the known squareness
    (``known_squareness.py``) read of a stored run, in the run's own shape."""
    out = {k: run[k] for k in _SLIM if k in run}
    d = run.get("diagnostics")
    d = d if isinstance(d, dict) else {}
    diag = {k: d[k] for k in _SLIM_DIAGNOSTICS if k in d}
    circ = d.get("circularity_um")
    if isinstance(circ, dict):
        diag["circularity_um"] = {"bidirectional": circ.get("bidirectional")}
    camp = d.get("campaign")
    if isinstance(camp, dict):
        diag["campaign"] = {"planes": camp.get("planes")}
    out["diagnostics"] = diag
    proposed = run.get("proposed")
    if isinstance(proposed, dict) and "squareness_um_per_m" in proposed:
        out["proposed"] = {"squareness_um_per_m": proposed["squareness_um_per_m"]}
    return out


class RunNotFound(KeyError):
    pass


class RunNotStorable(ValueError):
    """The run holds a number that is not finite (or something that is not JSON)."""


class RunStore:
    FOLDER = "runs"  # in the plugin's data folder
    ID = _ID  # what an id looks like (checked on every lookup)
    PREFIX = ""  # of new ids
    NotFound = RunNotFound
    # () -> the printer profile id a new run is recorded for (None: runs are not tagged)
    profile: Optional[Callable[[], str]] = None

    def __init__(self, data_folder: str):
        # absolute, resolved once: a relative basedir (./run.sh) must not be taken against
        # whatever folder a later reader (Flask's send_file: the app's) starts from
        self.folder = os.path.abspath(os.path.join(data_folder, self.FOLDER))
        os.makedirs(self.folder, exist_ok=True)
        # :meth:`index`: id -> ((mtime_ns, size) of its file, its slim document)
        self._index: Dict[str, Tuple[Tuple[int, int], Dict[str, Any]]] = {}
        self._index_lock = threading.Lock()
        self._names: Optional[set] = None  # the folder's names, as index() last read them

    def _path(self, run_id: str, suffix: str = ".json") -> str:
        if not isinstance(run_id, str) or not self.ID.fullmatch(run_id):
            raise self.NotFound(run_id)
        return os.path.join(self.folder, run_id + suffix)

    def new_id(self) -> str:
        now = _dt.datetime.now()
        return self.PREFIX + now.strftime("%Y%m%d-%H%M%S-") + secrets.token_hex(3)

    def save(self, run: Dict[str, Any], trace: Optional[bytes] = None) -> None:
        """Stores ``run`` (and its measurement file ``trace``); :class:`RunNotStorable`
        (nothing stored) if it is not plain JSON. A failed write (disk full: OSError) keeps
        nothing of a new run: not its trace without it."""
        path = self._path(run["id"])
        new = not os.path.exists(path)
        if new and self.profile is not None and "profile" not in run:
            run["profile"] = self.profile()
        run["verdict"] = verdict_of(run)  # decided from its findings, whoever stores it
        try:
            text = json.dumps(run, indent=1, sort_keys=True, default=float, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise RunNotStorable(str(exc)) from None
        try:
            if trace is not None:
                self.save_trace(run["id"], trace)
            write_atomic(path, text.encode())
        except OSError:
            if new and trace is not None:
                try:
                    os.unlink(self._path(run["id"], ".trace"))
                except OSError:
                    pass
            raise

    def save_trace(self, run_id: str, data: bytes, suffix: str = ".trace") -> str:
        path = self._path(run_id, suffix)
        write_atomic(path, data)
        return path

    def trace_path(self, run_id: str, suffix: str = ".trace") -> Optional[str]:
        path = self._path(run_id, suffix)
        return path if os.path.exists(path) else None

    def save_raw(self, run_id: str, data: bytes) -> str:
        """A live capture's raw sensor stream (``time_s,reading_mm,line``)."""
        return self.save_trace(run_id, data, ".raw")

    def raw_path(self, run_id: str) -> Optional[str]:
        return self.trace_path(run_id, ".raw")

    def get(self, run_id: str) -> Dict[str, Any]:
        path = self._path(run_id)
        try:
            with open(path, encoding="utf-8") as f:
                run = json.load(f, parse_constant=lambda name: None)  # NaN, Infinity
        except (OSError, ValueError, RecursionError):
            raise self.NotFound(run_id) from None
        if isinstance(run, dict) and "verdict" not in run:  # stored before verdicts
            run["verdict"] = verdict_of(run)
        if isinstance(run, dict) and isinstance(run.get("findings"), list):
            run["findings"] = worst_first(run["findings"])  # (a file edited or stored before)
        return run

    def ids(self) -> List[str]:
        """The stored ids, newest first (at most MAX_RUNS_LISTED)."""
        names = sorted(
            (n[:-5] for n in os.listdir(self.folder) if n.endswith(".json")), reverse=True
        )
        return [n for n in names if self.ID.fullmatch(n)][:MAX_RUNS_LISTED]

    def documents(self, profile: Optional[str] = None, legacy: str = "") -> List[Dict[str, Any]]:
        """The stored documents, newest first; with ``profile``, only those of that printer
        profile (one recorded before profiles counts as ``legacy``'s: the profile in force
        when the settings moved onto profiles). The others stay stored."""
        out = []
        for doc_id in self.ids():
            try:
                doc = self.get(doc_id)
            except self.NotFound:
                continue
            if profile is not None and (doc.get("profile") or legacy) != profile:
                continue
            out.append(doc)
        return out

    def index(self, profile: Optional[str] = None, legacy: str = "") -> List[Dict[str, Any]]:
        """:meth:`documents`, each cut down to what the history and the known squareness read
        (:func:`slim`: no plots, no traces), newest first. Each is kept in memory as long as
        its file is unchanged (its modification time and size), so that listing the
        history reads only what changed since: a page's read, or an analysis's look at the
        history, costs the server little however long the history is. Read-only."""
        try:
            names = os.listdir(self.folder)
        except OSError:
            return []
        ids = sorted((n[:-5] for n in names if n.endswith(".json")), reverse=True)
        ids = [n for n in ids if self.ID.fullmatch(n)][:MAX_RUNS_LISTED]
        out = []
        with self._index_lock:
            for doc_id in ids:
                doc = self._slim(doc_id)
                if doc is not None and (
                    profile is None or (doc.get("profile") or legacy) == profile
                ):
                    out.append(doc)
            for gone in set(self._index) - set(ids):
                del self._index[gone]
        self._names = set(names)
        return out

    def slim_doc(self, run_id: str) -> Dict[str, Any]:
        """The :func:`slim` form of run ``run_id`` (kept as :meth:`index` keeps it);
        NotFound when there is no such run. Read-only."""
        with self._index_lock:
            doc = self._slim(run_id)
        if doc is None:
            raise self.NotFound(run_id)
        return doc

    def _slim(self, doc_id: str) -> Optional[Dict[str, Any]]:
        try:
            st = os.stat(self._path(doc_id))
        except OSError:
            self._index.pop(doc_id, None)
            return None
        key = (st.st_mtime_ns, st.st_size)
        cached = self._index.get(doc_id)
        if cached is None or cached[0] != key:
            try:
                cached = (key, slim(self.get(doc_id)))
            except self.NotFound:
                return None
            self._index[doc_id] = cached
        return cached[1]

    def list(self, profile: Optional[str] = None, legacy: str = "") -> List[Dict[str, Any]]:
        """Summaries of :meth:`index` (the history's rows)."""
        return [self.summary(run) for run in self.index(profile, legacy)]

    def summary(self, run: Dict[str, Any]) -> Dict[str, Any]:
        """What the history shows of ``run`` (a document, or its :func:`slim` form)."""
        run_id = run.get("id", "")
        d = run.get("diagnostics") or {}
        return {
            "id": run_id,
            "date": run.get("date"),
            "source": run.get("source"),
            "simulated": bool(d.get("simulated") or run.get("simulated")),
            "plane": d.get("plane"),
            "filename": run.get("filename"),
            # a ballbar test: its plane's numbers; a printed artifact: {xy, xz, yz} um/m and
            # {"x-y", "x-z", "y-z"} ppm (null where not measured), ``planes`` those it made
            "planes": d.get("planes"),
            "squareness_um_per_m": d.get("squareness_um_per_m"),
            "scale_mismatch_ppm": d.get("scale_mismatch_ppm"),
            "circularity_um": (d.get("circularity_um") or {}).get("bidirectional"),
            "applied": run.get("applied"),
            "trusted": run.get("trusted") is not False,  # runs from before findings: True
            # what to confirm before it is applied (its trace is not tied to a printed program)
            "needs_confirmation": run.get("needs_confirmation"),
            "verdict": (run.get("verdict") or verdict_of(run))["decision"],
            "params_before_hash": run.get("params_before_hash"),
            "has_trace": self._has(run_id, ".trace"),
            "has_raw": self._has(run_id, ".raw"),
            "status": run.get("status", "ok"),
            "message": run.get("message"),
            "campaign": run.get("campaign"),
            "campaign_step": run.get("campaign_step"),
            "profile": run.get("profile"),
        }

    def _has(self, run_id: str, suffix: str) -> bool:
        """Whether ``run_id`` has a file of ``suffix`` (from the folder listing :meth:`index`
        just read, else asked of the disk)."""
        names = self._names
        if names is not None and run_id + ".json" in names:
            return run_id + suffix in names
        try:
            return self.trace_path(run_id, suffix) is not None
        except self.NotFound:
            return False

    def delete(self, run_id: str) -> None:
        for suffix in (".json", ".trace", ".raw"):
            path = self._path(run_id, suffix)
            if os.path.exists(path):
                os.unlink(path)
