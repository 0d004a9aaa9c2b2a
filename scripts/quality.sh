#!/usr/bin/env bash
# The quality table of BENCHMARKS.md: every method on fern, flower (posed protocol, images_8), HCI antinous
# (light-field protocol) and a synthetic scene through the real Spaces rig (all four Spaces configurations).
# Usage: scripts/quality.sh [METHOD ...]   (default: nearest psv-mean optimize deepview)
# Results: results/<scene>_<protocol>_<method>.json; then `python3 scripts/quality_table.py results`.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DEEPVIEW_DATA:-../shared/data}
BIN=target/release/deepview
OUT=${OUT:-results}
cargo build --release -p deepview
mkdir -p "$OUT"
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(nearest psv-mean optimize deepview)
# A synthetic scene through the real Spaces calibration (seed fixed: the same scene every time).
# Spaces' models.json carries no depth bounds: the scene is made, and evaluated, between 1 and 10 units.
[ -f "$OUT/synth_spaces/models.json" ] || $BIN synth --cameras "$DATA/spaces/scene_000" --near 1 --far 10 \
  --seed 7 --supersample 2 --out "$OUT/synth_spaces"
for m in "${methods[@]}"; do
  for s in fern flower; do
    $BIN eval --data "$DATA/llff/$s" --images images_8 --method "$m" --protocol posed \
      --targets every:8 --inputs nearest:4 --out "$OUT/${s}_posed_${m}.json"
  done
  $BIN eval --data "$DATA/hci/antinous" --method "$m" --protocol light-field --downscale 2 \
    --targets 10,20,30,40,50,60,70 --out "$OUT/antinous_light-field_${m}.json"
  for p in small_quad medium_quad large_quad dense; do
    $BIN eval --data "$OUT/synth_spaces" --near 1 --far 10 --method "$m" --protocol "$p" --out "$OUT/synth-spaces_${p}_${m}.json"
  done
done
python3 scripts/quality_table.py "$OUT"
