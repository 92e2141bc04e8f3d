#!/usr/bin/env bash
# The README's main job: set up and build, synthesise a survey (procedural seafloor, no
# download), mosaic it online into a store, compose the global mosaic, close the loops between
# lanes and compose again, and show what was made and how to look at it.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
rm -rf demo-survey demo.rolamos
build/rolamos synth -o demo-survey --frames "${FRAMES:-60}"
build/rolamos mosaic demo-survey/frames -o demo.rolamos
build/rolamos compose demo.rolamos
build/rolamos align demo.rolamos
build/rolamos compose demo.rolamos
build/rolamos info demo.rolamos
build/rolamos export demo.rolamos --scale 0.2 -o demo-overview.jpg
echo
echo "Look at it in a browser:  build/rolamos serve demo.rolamos   then open http://127.0.0.1:8080/"
echo "Accuracy against the survey's ground truth: /usr/bin/python3 bench/eval_global.py demo-survey demo.rolamos"
