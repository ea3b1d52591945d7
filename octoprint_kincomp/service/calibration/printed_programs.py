"""The ballbar programs KinComp printed, by program hash (issue 34; no OctoPrint import).

When KinComp prints one of its test programs it records, per program hash, what the test ran
with: the test's metadata, the firmware's own compensation then (``firmware/compensation.py``,
from M503 and what was sent), how the queue compensated the program (its decimals and reversal
dead band, ``calibration/ballbar/timing.py`` SentWith; None: not compensated), the parameters
in force and when. A trace uploaded later with that ``program_hash`` is tied to the print:
its result needs no confirmation of plane, radius and feed, and is analysed with the firmware
state and the compensator's settings of that print, not of the moment of the upload.

One JSON file (``printed_programs.json``) in the plugin's data folder, the newest
:data:`MAX_PROGRAMS` entries; a file that cannot be read counts as empty.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import threading
from typing import Any, Dict, Optional

from ...core.atomic import write_atomic

MAX_PROGRAMS = 200
FILE = "printed_programs.json"


class PrintedPrograms:
    def __init__(self, data_folder: str):
        self.path = os.path.join(os.path.abspath(data_folder), FILE)
        self._lock = threading.Lock()

    def _load(self) -> Dict[str, Dict[str, Any]]:
        try:
            with open(self.path, encoding="utf-8") as f:
                doc = json.load(f)
        except (OSError, ValueError):
            return {}
        return doc if isinstance(doc, dict) else {}

    def record(
        self,
        program_hash: str,
        meta: Dict[str, str],
        firmware: Optional[Dict[str, Any]],
        sent: Optional[Dict[str, str]],
        params_hash: str,
    ) -> None:
        """A print of the program ``program_hash`` starts now (the newest record of a hash
        wins). Never raises: a record that cannot be written only costs a confirmation."""
        if not program_hash:
            return
        with self._lock:
            doc = self._load()
            doc[program_hash] = {
                "date": _dt.datetime.now().isoformat(timespec="seconds"),
                "meta": dict(meta),
                "firmware": firmware,
                "sent": sent,
                "params_hash": params_hash,
            }
            newest = sorted(doc.items(), key=lambda kv: str(kv[1].get("date")))[-MAX_PROGRAMS:]
            try:
                write_atomic(self.path, json.dumps(dict(newest), indent=1).encode())
            except (OSError, TypeError, ValueError):
                pass

    def get(self, program_hash: Optional[str]) -> Optional[Dict[str, Any]]:
        """The record of the newest print of ``program_hash``; None if KinComp did not print
        it (or the hash is empty)."""
        key = (program_hash or "").strip()
        if not key:
            return None
        with self._lock:
            rec = self._load().get(key)
        return rec if isinstance(rec, dict) else None


def origin_kwargs(origin: Optional[Dict[str, Any]]) -> Dict[str, Any]:
    """What KinComp knows of a trace's test as JSON (``CalibrationApi.origin_for``:
    ``firmware``, ``confirmed``, ``sent``) as ``analyse``'s ``sent`` and ``origin``."""
    from ...calibration.ballbar.analysis import Provenance
    from ...calibration.ballbar.timing import SentWith
    from ...firmware.compensation import FirmwareCompensation

    origin = origin or {}
    fw = origin.get("firmware")
    sent = origin.get("sent")
    return {
        "sent": SentWith.from_meta(sent) if sent else None,
        "origin": Provenance(
            firmware=FirmwareCompensation.from_dict(fw) if fw else None,
            confirmed=origin.get("confirmed"),
        ),
    }


def trace_meta(data: bytes) -> Dict[str, str]:
    """The ``# key: value`` metadata of a CSV trace's head (empty for anything else)."""
    meta: Dict[str, str] = {}
    for raw in data[:65536].decode("utf-8", "replace").splitlines()[:200]:
        line = raw.strip()
        if line.startswith("#") and ":" in line:
            k, v = line[1:].split(":", 1)
            meta[k.strip()] = v.strip()
        elif line and not line.startswith("#"):
            break
    return meta
