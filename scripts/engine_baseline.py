"""Hashes of every engine's output, to prove a change of the engine floor byte-identical.

For each G-code file (two benchmark files, ``../shared/gcode-samples``, ``../shared/gcode-
corpus``; the first ``--lines`` lines of each), each parameter set (the corpus test's five,
the benchmark's with backlash tables) and each home (unknown, 0,0,0), it runs every path:

* ``reference``: ``Compensator.process`` without an accelerated engine, line by line;
* ``<engine>-lines``: the engine's compensator line by line, its state read every 7 lines
  (position, firmware text, backlash directions, the report: what a homing answer or the
  plugin reads mid-stream);
* ``<engine>-file``: the whole-file path (``compensate_binary``);
* ``<engine>-queue``: the queuing hook (``QueueCompensator.handle``) line by line;

and writes a SHA-256 per (file, params, home, path) of the output, of the report
(``to_dict``) and, for the line paths, of the states read. ``--compare OLD.json`` checks a
new run against an old one and lists every difference.

    PYTHONPATH=$PWD .venv/bin/python scripts/engine_baseline.py --out base.json
    PYTHONPATH=$PWD .venv/bin/python scripts/engine_baseline.py --compare base.json

Issue 24 (the kernel owning its state, the numpy engine retired) was proven so: the hashes
of a copy of the tree at ad45ca6 (its kernel built), ``--lines 3000 --bench-lines 30000``,
against those of the change (``--part 0/2`` and ``--part 1/2`` side by side): 300 cases,
2,100 paths, no difference. The whole-file comparison of every engine with the reference
path on the corpus is the slow test ``tests/corpus/test_corpus.py``.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import tempfile

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.marker import ENCODING, ERRORS
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines import select
from octoprint_kincomp.engines.file_loop import compensate_binary, marker_line
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.service.printing.queue import FILE_TAG, QueueCompensator
from octoprint_kincomp.tools.benchmark import BENCH_PARAMS, generate
from octoprint_kincomp.tools.line_path import compensate_lines

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(ROOT), "shared")
with open(os.path.join(ROOT, "octoprint_kincomp", "examples", "paper_table1_params.json")) as _f:
    PAPER = json.load(_f)
PARAMS = {  # tests/corpus's five, and the benchmark's (backlash tables)
    "xy1000": {"squareness_um_per_m": {"xy": 1000.0}},
    "paper": PAPER,
    "xz_yz500": {"squareness_um_per_m": {"xz": 500.0, "yz": 500.0}},
    "backlash": {"backlash": {"x": 50.0, "y": 30.0}},
    "all": {
        "squareness_um_per_m": {"xy": PAPER["squareness_um_per_m"]["xy"], "xz": 500.0, "yz": 500.0},
        "scale_ppm": PAPER["scale_ppm"],
        "backlash": {"x": 50.0, "y": 30.0},
    },
    "bench_tables": BENCH_PARAMS,
}
HOMES = {"home_unknown": (None, None, None), "home_000": (0.0, 0.0, 0.0)}
PEEK_EVERY = 7


def files(bench_lines: int, workdir: str):
    out = []
    for name, arcs in (("bench.gcode", 0.0), ("bench_arcs.gcode", 0.2)):
        path = os.path.join(workdir, name)
        generate(path, bench_lines, arc_fraction=arcs)
        out.append(path)
    for d in ("gcode-samples", "gcode-corpus"):
        full = os.path.join(SHARED, d)
        out += sorted(os.path.join(full, n) for n in os.listdir(full) if n.endswith(".gcode"))
    return out


def read(path: str, limit: int) -> str:
    """The first ``limit`` lines of the file (0: all), endings and odd bytes kept."""
    with open(path, encoding=ENCODING, errors=ERRORS, newline="") as f:
        lines = f.readlines()
    return "".join(lines[:limit] if limit else lines)


def digest(text) -> str:
    data = text if isinstance(text, bytes) else str(text).encode(ENCODING, ERRORS)
    return hashlib.sha256(data).hexdigest()[:20]


def peek(comp: Compensator) -> tuple:
    st = comp.state
    return (
        list(st.m),
        list(st.fw),
        list(st.fw_text),
        list(st.backlash.dir),
        list(st.backlash.anchor),
        st.e_pos,
        st.feed,
        st.lineno,
        comp.report.to_dict(),
    )


def by_lines(comp: Compensator, params: Params, text: str) -> dict:
    out, seen = [], []
    lines = io.StringIO(text, newline="")
    for i, chunk in enumerate(compensate_lines(lines, comp, marker_line(params))):
        out.append(chunk)
        if i % PEEK_EVERY == 0:
            seen.append(repr(peek(comp)))
    return {
        "out": digest("".join(out)),
        "report": digest(json.dumps(comp.report.to_dict(), sort_keys=True)),
        "states": digest("\n".join(seen)),
    }


def by_file(params: Params, options: Options, text: str) -> dict:
    dst = io.BytesIO()
    rep = compensate_binary(io.BytesIO(text.encode(ENCODING, ERRORS)), dst, params, options)
    return {
        "out": digest(dst.getvalue()),
        "report": digest(json.dumps(rep.to_dict(), sort_keys=True)),
    }


def by_queue(params: Params, options: Options, text: str) -> dict:
    queue = QueueCompensator(params, options, enabled=True)
    tags = {FILE_TAG}
    out = []
    for raw in text.splitlines():
        got = queue.handle(raw, tags)
        out.append(raw if got is None else repr(got))
    return {
        "out": digest("\n".join(out)),
        "report": digest(json.dumps(queue.comp.report.to_dict(), sort_keys=True)),
    }


def run(limit: int, bench_lines: int, part=(0, 1)) -> dict:
    res = {"lines": limit, "bench_lines": bench_lines, "cases": {}}
    names = select.ENGINES if select.available() == "compiled" else ("python",)
    with tempfile.TemporaryDirectory() as tmp:
        for path in files(bench_lines, tmp)[part[0] :: part[1]]:
            text = read(path, limit)
            for pname, pdict in PARAMS.items():
                params = Params.from_dict(pdict)
                for hname, home in HOMES.items():
                    options = Options(home_mm=home)
                    case = {"reference": by_lines(Compensator(params, options), params, text)}
                    for name in names:
                        with select.use(name):
                            comp = make_compensator(params, options)
                            case[name + "-lines"] = by_lines(comp, params, text)
                            case[name + "-file"] = by_file(params, options, text)
                            case[name + "-queue"] = by_queue(params, options, text)
                    key = f"{os.path.basename(path)} {pname} {hname}"
                    res["cases"][key] = case
                    print(key, file=sys.stderr, flush=True)
    return res


def compare(old: dict, new: dict, whole: bool = True) -> list:
    diffs = []
    keys = set(old["cases"]) | set(new["cases"]) if whole else set(new["cases"])
    for key in sorted(keys):
        a, b = old["cases"].get(key), new["cases"].get(key)
        if a is None or b is None:
            diffs.append(f"{key}: only in {'new' if a is None else 'old'}")
            continue
        for path in sorted(set(a) | set(b)):
            if a.get(path) != b.get(path):
                diffs.append(f"{key} {path}: {a.get(path)} != {b.get(path)}")
    return diffs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=3000, help="lines of each file (0: all)")
    ap.add_argument("--bench-lines", type=int, default=30000)
    ap.add_argument("--out", help="write the hashes to this JSON file")
    ap.add_argument("--compare", help="compare with the hashes of this JSON file")
    ap.add_argument("--part", default="0/1", help="I/N: only every N-th file from the I-th")
    args = ap.parse_args(argv)
    part = tuple(int(v) for v in args.part.split("/"))
    res = run(args.lines, args.bench_lines, part)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=1, sort_keys=True)
    if args.compare:
        with open(args.compare) as f:
            old = json.load(f)
        diffs = compare(old, res, whole=part == (0, 1))
        for d in diffs:
            print(d)
        n = sum(len(c) for c in res["cases"].values())
        print(f"{len(res['cases'])} cases, {n} paths: {len(diffs)} differences")
        return 1 if diffs else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
