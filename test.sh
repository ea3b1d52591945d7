#!/usr/bin/env bash
# Run KinComp's whole test suite (sets up .venv on first use). Extra arguments go to pytest,
# e.g. ./test.sh -m "not slow" for the quick suite, ./test.sh --durations=25 for where the
# time goes. The tests run in two processes (pytest-xdist: -n 2, the slowest handed out
# first, see tests/conftest.py); KINCOMP_TEST_PROCESSES=1 runs them in one.
set -euo pipefail
cd "$(dirname "$0")"
./scripts/bootstrap.sh
# the linter and the formatter first: the tree is kept clean (pyproject.toml [tool.ruff])
.venv/bin/ruff check --quiet .
.venv/bin/ruff format --check --quiet .
n=${KINCOMP_TEST_PROCESSES:-2}
if [ "$n" -gt 1 ]; then
    exec .venv/bin/python -m pytest -q -n "$n" --dist loadgroup --no-loadscope-reorder "$@"
fi
exec .venv/bin/python -m pytest -q "$@"
