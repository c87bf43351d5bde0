#!/usr/bin/env bash
# The palpation sweep end to end (docs/palpation.md): Snakemake runs the four-case CI config
# (workflow/config-ci.yaml) with `--cores 2` in a scratch folder, then the detectability table
# is checked: four rows, every shallow lesion found (within 2 mm), and for each stiffness ratio
# the contrast falls from the 1 mm to the 3 mm deep lesion and is higher for the stiffer lesion.
# Usage: sweep_test.sh SOURCE_DIR VOXELASTIC_BINARY. Exit 77 (skipped) without snakemake.
set -euo pipefail
src=$1
vx=$2
if ! command -v snakemake >/dev/null 2>&1; then
  echo "sweep_test: SKIPPED: snakemake is not installed (Debian: apt-get install snakemake, or scripts/install-deps.sh)"
  exit 77
fi
work=$(mktemp -d "${TMPDIR:-/tmp}/vx_sweep_test.XXXXXX")
trap 'rm -rf "$work"' EXIT
cd "$work"
snakemake -s "$src/workflow/Snakefile" --configfile "$src/workflow/config-ci.yaml" \
  --config voxelastic="$vx" --cores 2 -q >snakemake.log 2>&1 || { cat snakemake.log; exit 1; }
csv=sweep/detectability.csv
[ -s sweep/detectability.png ] || { echo "sweep_test: no detectability.png"; exit 1; }
# a real picture of the size the gather asks `voxelastic plot` for (the PNG header's IHDR), and
# more than a blank page (a blank 900 x 560 PNG compresses to a few hundred bytes)
python3 - sweep/detectability.png <<'PY'
import struct, sys, os
data = open(sys.argv[1], "rb").read(24)
assert data[:8] == b"\x89PNG\r\n\x1a\n", "detectability.png is not a PNG"
w, h = struct.unpack(">II", data[16:24])
assert (w, h) == (900, 560), f"detectability.png is {w} x {h}, expected 900 x 560"
assert os.path.getsize(sys.argv[1]) > 15000, f"detectability.png is only {os.path.getsize(sys.argv[1])} bytes"
PY
for c in r3.5_d1_k3 r3.5_d3_k3 r3.5_d1_k10 r3.5_d3_k10; do
  for f in summary.json map.csv map.png; do
    [ -s "sweep/cases/$c/$f" ] || { echo "sweep_test: missing sweep/cases/$c/$f"; exit 1; }
  done
done
cat "$csv"
python3 - "$csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
assert len(rows) == 4, f"{len(rows)} rows, expected 4"
by = {(float(r["lesion_depth_mm"]), float(r["stiffness_ratio"])): r for r in rows}
for k in (3.0, 10.0):
    shallow, deep = by[(1.0, k)], by[(3.0, k)]
    assert shallow["found"] == "1", f"the 1 mm deep lesion ({k:g}x) was missed: {shallow}"
    assert float(shallow["error_mm"]) < 2.0, shallow
    assert float(shallow["contrast"]) > float(deep["contrast"]) > 1.0, (shallow, deep)
assert float(by[(1.0, 10.0)]["contrast"]) > float(by[(1.0, 3.0)]["contrast"]) > 1.2, by
print("sweep_test: passed")
PY
