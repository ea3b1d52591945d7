#!/usr/bin/env bash
# KinComp's main job. Sets up .venv on first use.
# For now: compensate the bundled example part with the errors of the paper's Ultimaker
# (Keaveney et al. 2018, Table 1) and print the dry-run report.
set -euo pipefail
cd "$(dirname "$0")"
./scripts/bootstrap.sh
EX=octoprint_kincomp/examples
mkdir -p out
.venv/bin/python -m octoprint_kincomp compensate "$EX/example_part.gcode" \
    -o out/example_part.compensated.gcode --params "$EX/paper_table1_params.json" --report
echo "wrote out/example_part.compensated.gcode"
