#!/usr/bin/env bash
# KinComp's main job: OctoPrint with KinComp on the built-in virtual printer, on
# http://127.0.0.1:5000, demo mode on (hidden SIMULATED printer errors + a virtual ballbar).
# Sets up .venv on first use. OctoPrint's output goes to .octoprint-demo/server.out; the
# admin login is printed last, once the server answers. Stop with Ctrl-C.
# Extra arguments go to the demo server, e.g. ./run.sh --port 5080 --reset
set -euo pipefail
cd "$(dirname "$0")"
KINCOMP_NO_BROWSER=1 ./scripts/bootstrap.sh
exec .venv/bin/python -m octoprint_kincomp demo-server "$@"
