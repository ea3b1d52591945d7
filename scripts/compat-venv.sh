#!/usr/bin/env bash
# The second environment of the compatibility test (tests/e2e/test_compat.py): the oldest
# OctoPrint release line KinComp supports (1.10.x, its latest patch on PyPI) with KinComp
# installed from this tree (editable: the server runs the tree's code, as in .venv).
# Idempotent: does nothing when it is there and the packaging did not change since.
#   KINCOMP_COMPAT_VENV       where (default .venv-op110)
#   KINCOMP_COMPAT_OCTOPRINT  which OctoPrint (default "OctoPrint==1.10.*")
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${KINCOMP_COMPAT_VENV:-.venv-op110}
SPEC=${KINCOMP_COMPAT_OCTOPRINT:-OctoPrint==1.10.*}
PY=${PYTHON:-python3}
# OctoPrint 1.10.x does not cap `limits` (Flask-Limiter's backend); limits 5 dropped the
# rate-limit strategy it configures, so a 1.10 installed today does not start without this
# cap (installs made before limits 5 have it; OctoPrint 1.11 caps it itself)
CONSTRAINTS="limits<5"
stamp="$VENV/.kincomp-installed"
# one at a time: ./test.sh makes it in the background while the tests start, and the
# compatibility test's own call waits here for that one
exec 9>"$VENV.lock"
flock 9
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$SPEC $CONSTRAINTS compat" ] &&
        [ ! pyproject.toml -nt "$stamp" ] && [ ! setup.py -nt "$stamp" ] && [ -z "$(find octoprint_kincomp/engines/csrc -newer "$stamp" 2>/dev/null)" ]; then
    exit 0
fi
start=$(date +%s)
if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install --quiet --upgrade pip
# editable in "compat" mode: a path entry, not an import hook (OctoPrint 1.10 looks plugins
# up with imp.find_module, which sees only sys.path, as a normal install provides)
"$VENV/bin/python" -m pip install --quiet "$SPEC" "$CONSTRAINTS" -e . \
    --config-settings editable_mode=compat
echo "$SPEC $CONSTRAINTS compat" > "$stamp"
version=$("$VENV/bin/python" -c "import octoprint; print(octoprint.__version__)")
echo "compatibility environment $VENV: OctoPrint $version, KinComp from this tree" \
     "($(( $(date +%s) - start )) s)" >&2
