#!/usr/bin/env bash
# One command from a fresh Debian 12 machine to a converted model: installs what is missing,
# builds in Release, converts the bundled sample to a gradational-resolution model and a
# smoothed surface, prints a summary and writes a picture of the model.
# Outputs go to out/demo/ (model.vtu, surface.vtp, stats.json, model.png).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh
mkdir -p out/demo
sample=${1:-samples/block-lesion64.vti}
scripts/with-display.sh build/apps/voxelastic/voxelastic convert "$sample" \
  -o out/demo/model.vtu --surface out/demo/surface.vtp --stats out/demo/stats.json --png out/demo/model.png
echo
echo "demo: outputs in out/demo/: model.vtu (open in ParaView), surface.vtp, stats.json, model.png"
