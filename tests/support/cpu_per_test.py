"""CPU per test: ``./test.sh -p tests.support.cpu_per_test`` (a pytest plugin, off by default).

Around each test (set-up, body and teardown) it adds up the CPU time (s: utime + stime of
every process, and what each has collected of its ended children) of the worker's whole
process tree from ``/proc``: the worker itself, its OctoPrint test servers, Chromium and
Playwright's driver, KinComp's analysis workers, klippy. Each worker writes a line per test
to ``test-artifacts/cpu-per-test.<worker>.jsonl`` (``{"id", "cpu", "wall"}``); at the end the
main process prints the sums and the modules that took the most CPU. CPU beside wall time
shows what waits (a printer's pace, a real-time stream) and what computes (docs/tests.md,
"How long it takes"). Linux only."""

from __future__ import annotations

import collections
import glob
import json
import os
import time

import pytest

from tests.support import ARTIFACTS

OUT = ARTIFACTS
TICKS = os.sysconf("SC_CLK_TCK")


def tree_cpu_s(root: int) -> float:
    """CPU seconds of process ``root`` and every process below it (ended children count
    once their parent has waited for them: its cutime/cstime)."""
    children, own = collections.defaultdict(list), {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                stat = f.read()
        except OSError:  # (ended meanwhile)
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        children[int(fields[1])].append(int(name))
        own[int(name)] = sum(int(x) for x in fields[11:15])  # utime stime cutime cstime
    total, todo = 0, [root]
    while todo:
        pid = todo.pop()
        total += own.get(pid, 0)
        todo.extend(children.get(pid, ()))
    return total / TICKS


def _files():
    return glob.glob(os.path.join(OUT, "cpu-per-test.*.jsonl"))


def pytest_configure(config):
    if not os.environ.get("PYTEST_XDIST_WORKER"):  # (the main process: a fresh record)
        for path in _files():
            os.remove(path)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    cpu0, wall0 = tree_cpu_s(os.getpid()), time.monotonic()
    yield
    cpu, wall = tree_cpu_s(os.getpid()) - cpu0, time.monotonic() - wall0
    os.makedirs(OUT, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(os.path.join(OUT, f"cpu-per-test.{worker}.jsonl"), "a") as f:
        f.write(json.dumps({"id": item.nodeid, "cpu": round(cpu, 2), "wall": round(wall, 2)}))
        f.write("\n")


def pytest_terminal_summary(terminalreporter):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return
    rows = [json.loads(line) for path in _files() for line in open(path)]
    if not rows:
        return
    by_module = collections.defaultdict(lambda: [0.0, 0.0])
    for r in rows:
        m = by_module[r["id"].split("::", 1)[0]]
        m[0] += r["cpu"]
        m[1] += r["wall"]
    tr = terminalreporter
    tr.section("CPU per test (tests/support/cpu_per_test.py)")
    cpu, wall = sum(r["cpu"] for r in rows), sum(r["wall"] for r in rows)
    tr.write_line(f"{len(rows)} tests: {cpu:.0f} s of CPU, {wall:.0f} s of test time summed")
    for name, (c, w) in sorted(by_module.items(), key=lambda kv: -kv[1][0])[:15]:
        tr.write_line(f"{c:8.1f} s CPU {w:8.1f} s wall  {name}")
