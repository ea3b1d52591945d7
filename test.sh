#!/usr/bin/env bash
# Run KinComp's whole test suite (sets up .venv on first use). Extra arguments go to pytest,
# e.g. ./test.sh -m "not slow" for the quick suite.
set -euo pipefail
cd "$(dirname "$0")"
./scripts/bootstrap.sh
# the linter and the formatter first: the tree is kept clean (pyproject.toml [tool.ruff])
.venv/bin/ruff check --quiet .
.venv/bin/ruff format --check --quiet .
exec .venv/bin/python -m pytest -q "$@"
