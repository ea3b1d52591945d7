#!/usr/bin/env bash
# Run KinComp's whole test suite (sets up .venv on first use). Extra arguments go to pytest,
# e.g. ./test.sh -m "not slow" for the quick suite, ./test.sh --durations=25 for where the
# time goes. The tests run in three processes (pytest-xdist: -n 3 on two cores, since many
# tests wait on a printer or a real-time stream; the slowest handed out first, see
# tests/conftest.py); KINCOMP_TEST_PROCESSES=1 runs them in one.
set -euo pipefail
cd "$(dirname "$0")"
# the compatibility test's second environment (OctoPrint 1.10, about a minute on its first
# run) is made in the background while the tests start: the test waits for it
KINCOMP_NO_COMPAT=1 ./scripts/bootstrap.sh
# the linter and the formatter first: the tree is kept clean (pyproject.toml [tool.ruff])
.venv/bin/ruff check --quiet .
.venv/bin/ruff format --check --quiet .
compat=""
if [ -z "${KINCOMP_NO_COMPAT:-}" ] && [ -z "${KINCOMP_NO_BROWSER:-}" ]; then
    ./scripts/compat-venv.sh >.venv-op110.log 2>&1 &
    compat=$!
fi
n=${KINCOMP_TEST_PROCESSES:-3}
rc=0
if [ "$n" -gt 1 ]; then
    .venv/bin/python -m pytest -q -n "$n" --dist loadgroup --no-loadscope-reorder "$@" || rc=$?
else
    .venv/bin/python -m pytest -q "$@" || rc=$?
fi
# (a run of a few tests may end first: the environment is finished, not left half made)
[ -z "$compat" ] || wait "$compat" || echo "scripts/compat-venv.sh failed: .venv-op110.log" >&2
exit $rc
