#!/usr/bin/env bash
# The generalisation tables of BENCHMARKS.md (issue: a shipped model that generalises): every method on
# every real forward-facing scene at half resolution, 4 nearest inputs, every 16th view a target, and the
# plane count of `--planes auto` (the same for every method).
# Usage: WEIGHTS=runs/gen2/checkpoints/step-N scripts/generalisation.sh [METHOD ...]
#   (default methods: nearest psv-mean optimize deepview; WEIGHTS defaults to the shipped weights)
# ARGS adds options to every eval (e.g. ARGS="--aggregate 8" with the method psv-mean alone: an option
# of one method is refused by the others).
# Results: ${OUT:-results/gen}/<scene>_<method>.json; then `python3 scripts/quality_table.py results/gen`.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DEEPVIEW_DATA:-../shared/data}
BIN=${BIN:-target/release/deepview}
OUT=${OUT:-results/gen}
mkdir -p "$OUT"
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(nearest psv-mean optimize deepview)
# scene name, folder, image folder (half resolution = --downscale 2 of these)
scenes=(
  "fern llff/fern images_4"
  "flower llff/flower images_4"
  "statue llff/statue images_4"
  "canclip llff/canclip images_4"
  "room colmap/room images"
)
for m in "${methods[@]}"; do
  extra=()
  [ "$m" = deepview ] && [ -n "${WEIGHTS:-}" ] && extra=(--weights "$WEIGHTS")
  for s in "${scenes[@]}"; do
    read -r name dir images <<<"$s"
    [ -n "${SCENES:-}" ] && [[ " $SCENES " != *" $name "* ]] && continue
    $BIN eval --data "$DATA/$dir" --images "$images" --downscale 2 --method "$m" --protocol posed \
      --targets every:16 --inputs nearest:4 "${extra[@]}" ${ARGS:-} --out "$OUT/${name}_${m}.json"
  done
done
python3 scripts/quality_table.py "$OUT"
