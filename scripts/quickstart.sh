#!/usr/bin/env bash
# The README's main job: set up and build, synthesise a survey (procedural seafloor, no
# download), mosaic it online into a store, compose the global mosaic, and show what was made.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
rm -rf demo-survey demo.rolamos
build/rolamos synth -o demo-survey --frames "${FRAMES:-60}"
build/rolamos mosaic demo-survey/frames -o demo.rolamos
build/rolamos compose demo.rolamos
build/rolamos info demo.rolamos
build/rolamos export demo.rolamos --scale 0.2 -o demo-overview.jpg
echo "Accuracy against the survey's ground truth: /usr/bin/python3 bench/eval_mosaic.py demo-survey demo.rolamos"
