#!/usr/bin/env bash
# The README's main job: set up, build, and write a generated seafloor image into a new store.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
rm -rf demo.rolamos
build/rolamos demo -o demo.rolamos "$@"
