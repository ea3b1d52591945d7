"""Calibration campaigns as KinComp keeps them (no OctoPrint import): one JSON file per
campaign in the plugin's data folder (``campaigns/<id>.json``), next to the run history.

A campaign records what was planned (the printer, its volume x0,x1,y0,y1,z0,z1 in mm, the
options, and per test: its name, plane, centre mm, radius mm, feed mm/min, the whole test
spec and its program hash), the parameters in force when it began (``params_hash``: every
test must be measured with them), and how far it got: per test the program written
(``path``), when it was printed, the run of its measurement (``run``); then the run of the
joint analysis (``result``) and when it was applied. A new campaign is tagged with the printer
profile in force (``profile``, as runs are); :meth:`CampaignStore.documents` lists those of
one profile. Ids are generated here and checked on
every lookup (the run store's rules): a request cannot name a path outside the folder.

``new_campaign`` makes the document from the planned steps (``ballbar.campaign.Step``);
``next_step`` and ``state`` read how far a document got; ``view`` is what the UI gets: the
document with its progress, each test's run summary and, once analysed, the joint result with
per test the rows of the paper's Table 2 against the campaign it re-tests.

A campaign's record changes under its own lock (:meth:`CampaignStore.change`): the document
is read afresh under it, changed and saved, so that two measurements of different tests
both land (each saved its own copy whole, and the later one dropped the other's link). A
measurement or joint analysis in flight is registered (:meth:`CampaignStore.working`): the
same test twice, or the joint analysis twice, is refused while the first runs; a delete
wins over work in flight, which then finds the campaign gone and stores nothing.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import re
import threading
from typing import Any, Callable, Dict, Iterator, Optional, Sequence, Set, Tuple

from ...calibration.ballbar.campaign import test_words
from ...calibration.ballbar.program import body_hash, spec_dict
from ...core.messages import as_dict
from ...simulator.closed_loop import servo_in_force, table
from .run_store import RunNotFound, RunStore


class CampaignNotFound(KeyError):
    pass


def now() -> str:
    return _dt.datetime.now().isoformat(timespec="seconds")


class CampaignStore(RunStore):
    FOLDER = "campaigns"
    ID = re.compile(r"c[0-9]{8}-[0-9]{6}-[0-9a-f]{6}")
    PREFIX = "c"
    NotFound = CampaignNotFound

    def __init__(self, data_folder: str):
        super().__init__(data_folder)
        self._guard = threading.Lock()  # the tables below
        self._locks: Dict[str, threading.RLock] = {}
        self._work: Set[Tuple[str, str]] = set()  # (campaign id, what: a test's name, "joint")

    def lock(self, cid: str) -> threading.RLock:
        """The lock under which campaign ``cid``'s record changes."""
        with self._guard:
            return self._locks.setdefault(str(cid), threading.RLock())

    def change(self, cid: str, edit: Callable[[Dict[str, Any]], Any]) -> Any:
        """Under campaign ``cid``'s lock: its document read afresh, ``edit(doc)`` (which may
        raise to change nothing), the document saved; returns what ``edit`` returned.
        CampaignNotFound if it is gone (deleted meanwhile): nothing is written."""
        with self.lock(cid):
            doc = self.get(cid)
            out = edit(doc)
            self.save(doc)
            return out

    def delete(self, run_id: str) -> None:
        with self.lock(run_id):
            super().delete(run_id)

    def claim(self, cid: str, what: str) -> bool:
        """Registers work ``what`` (a test's name, or "joint") on campaign ``cid``; False,
        registering nothing, when the same work is in flight (queued or running)."""
        key = (str(cid), str(what))
        with self._guard:
            if key in self._work:
                return False
            self._work.add(key)
            return True

    def release(self, cid: str, what: str) -> None:
        with self._guard:
            self._work.discard((str(cid), str(what)))

    @contextlib.contextmanager
    def working(self, cid: str, what: str) -> Iterator[bool]:
        """:meth:`claim` while the block runs (yields its answer), then released."""
        free = self.claim(cid, what)
        try:
            yield free
        finally:
            if free:
                self.release(cid, what)


def new_campaign(
    cid: str,
    steps: Sequence[Any],
    volume: Sequence[float],
    printer: Optional[str],
    params_hash: str,
    options: Dict[str, Any],
    retest_of: Optional[str] = None,
) -> Dict[str, Any]:
    """The document of a freshly planned campaign (nothing printed yet)."""
    return {
        "id": cid,
        "created": now(),
        "printer": printer,
        "volume": [float(v) for v in volume],
        "params_hash": params_hash,
        "options": options,
        "retest_of": retest_of,
        "steps": [
            {
                "n": i,
                "name": s.name,
                "plane": s.spec.plane,
                "centre": list(s.spec.centre),
                "radius_mm": s.spec.radius_mm,
                "feed_mm_min": s.spec.feed_mm_min,
                "requested_feed_mm_min": s.spec.requested_feed_mm_min,
                "spec": spec_dict(s.spec),
                "program_hash": body_hash(s.spec),
                "path": None,
                "printed": None,
                "run": None,
                "measured": None,
            }
            for i, s in enumerate(steps, 1)
        ],
        "result": None,
        "applied": None,
    }


def next_step(doc: Dict[str, Any]) -> Optional[int]:
    """The number (from 1) of the first test without a measurement; None when all have one."""
    for step in doc["steps"]:
        if not step.get("run"):
            return step["n"]
    return None


def state(doc: Dict[str, Any]) -> str:
    """'measuring' (tests without a measurement left), 'measured' (ready for the joint
    analysis), 'analysed', 'applied'."""
    if doc.get("applied"):
        return "applied"
    if doc.get("result"):
        return "analysed"
    return "measuring" if next_step(doc) is not None else "measured"


def view(
    doc: Dict[str, Any],
    runs: RunStore,
    campaigns: CampaignStore,
    in_force_hash: str,
    stored: bool = True,
    analysis: bool = True,
) -> Dict[str, Any]:
    """The campaign document with its progress, each test's measurement summary and name in
    words (``test``) and, once
    analysed (and ``analysis``), the joint result with the comparison per test;
    ``in_force_hash``: the parameters in force now (changed: the campaign cannot go on)."""
    out = dict(
        doc,
        stored=stored,
        state=state(doc),
        next_step=next_step(doc),
        measured=sum(1 for s in doc["steps"] if s.get("run")),
        in_force_hash=in_force_hash,
        params_changed=in_force_hash != doc["params_hash"],
    )
    # each test's name in words for the web UI (``test``: translated there)
    out["steps"] = [
        dict(s, summary=_summary(runs, s.get("run")), test=as_dict(test_words(s["name"])))
        for s in doc["steps"]
    ]
    if analysis and doc.get("result"):
        out["analysis"] = _analysis(doc, runs, campaigns)
    return out


def _summary(runs: RunStore, run_id: Optional[str]) -> Optional[Dict[str, Any]]:
    if not run_id:
        return None
    try:
        run = runs.slim_doc(run_id)  # (not the whole run: no plots read)
    except RunNotFound:
        return None
    return runs.summary(run)


def _analysis(
    doc: Dict[str, Any], runs: RunStore, campaigns: CampaignStore
) -> Optional[Dict[str, Any]]:
    """The joint result; per test the Table-2 rows (before: the same test of the campaign
    this one re-tests, if analysed) and the plot of that test."""
    try:
        run = runs.get(doc["result"])
    except RunNotFound:
        return None
    before = _before(doc.get("retest_of"), runs, campaigns)
    comparison = []
    for name, after in zip(run.get("campaign_steps") or [], run["diagnostics"].get("traces") or []):
        b = before.get(name)
        comparison.append(
            {
                "step": name,
                "rows": table(_joint(b["trace"]) if b else {}, _joint(after), servo_in_force(run)),
                "before_plot": b["plot"] if b else None,
                "before_run": b["run"] if b else None,
            }
        )
    return dict(run, comparison=comparison)


def _before(
    cid: Optional[str], runs: RunStore, campaigns: CampaignStore
) -> Dict[str, Dict[str, Any]]:
    """Per test name of campaign ``cid``'s joint analysis: its trace diagnostics and plot;
    empty when there is none."""
    try:
        run = runs.get(campaigns.get(cid or "").get("result") or "")
    except (CampaignNotFound, RunNotFound):
        return {}
    traces = run["diagnostics"].get("traces") or []
    plots = run.get("plots") or [None] * len(traces)
    return {
        name: {"trace": t, "plot": p, "run": run["id"]}
        for name, t, p in zip(run.get("campaign_steps") or [], traces, plots)
    }


def _joint(trace_diag: Dict[str, Any]) -> Dict[str, Any]:
    """A test's diagnostics with its values from the joint fit in their place."""
    return dict(trace_diag, **(trace_diag.get("joint") or {}))
