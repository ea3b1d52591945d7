#!/usr/bin/env bash
# Create .venv with KinComp (editable) and its test dependencies, make sure Debian's
# chromium (the browser tests: Playwright drives it, no browser download) and nodejs (the
# web UI's unit tests) are there, and
# create .venv-op110, the oldest supported OctoPrint (1.10.x) with KinComp, for the
# compatibility test (scripts/compat-venv.sh). Idempotent. KINCOMP_NO_BROWSER=1 (run.sh:
# only the server) skips chromium and .venv-op110; KINCOMP_NO_COMPAT=1 skips .venv-op110.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.kincomp-installed
# (again when the packaging or the compiled kernel changed: the install builds it)
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ setup.py -nt "$stamp" ] ||
        [ -n "$(find octoprint_kincomp/engines/csrc -newer "$stamp" 2>/dev/null)" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".[test]"
    touch "$stamp"
fi
# the test set-up's Debian packages: chromium (the browser tests) and nodejs (the web UI's
# unit tests, tests/js, run by node's own test runner)
missing=""
if [ -z "${KINCOMP_NO_BROWSER:-}" ]; then
    command -v chromium >/dev/null 2>&1 || missing="$missing chromium"
    command -v node >/dev/null 2>&1 || missing="$missing nodejs"
fi
if [ -n "$missing" ]; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        [ "$(id -u)" -ne 0 ] && SUDO="sudo"
        echo "installing Debian's$missing for the tests" >&2
        $SUDO apt-get update -qq >/dev/null 2>&1 || true
        # shellcheck disable=SC2086
        $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            $missing >/dev/null
    else
        echo "$missing not found and no apt-get: the browser and UI unit tests will fail" >&2
    fi
fi
if [ -z "${KINCOMP_NO_BROWSER:-}" ] && [ -z "${KINCOMP_NO_COMPAT:-}" ]; then
    ./scripts/compat-venv.sh
fi
