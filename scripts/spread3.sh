#!/usr/bin/env bash
# Issue 25's few-shot 3-view protocol (RegNeRF, FreeNeRF, FSGS use it) on every real forward-facing scene:
# every 8th view a target, 3 inputs spread over the rest (`--inputs spread:3`), 1/8 of the capture's
# resolution (LLFF's 4032-px captures: `images_8`; the 3840-px phone captures: `images_4` at half size;
# room's 996-px images at half size), SSIM and PSNR on the whole image (`--crop 0`), `--planes auto`.
# WIDE=1 adds room at its full 996 px (twice the disparities: a stand-in for wider captures).
# Usage: WEIGHTS=runs/gen27/checkpoints/step-N scripts/spread3.sh [METHOD ...]
#   (default methods: psv-mean deepview; WEIGHTS defaults to the shipped weights)
# ARGS adds options to every eval (e.g. ARGS="--aggregate 8" with the method psv-mean alone: an option
# of one method is refused by the others).
# Results: ${OUT:-results/spread3}/<scene>_<method>.json; then `python3 scripts/quality_table.py DIR`.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DEEPVIEW_DATA:-../shared/data}
BIN=${BIN:-target/release/deepview}
OUT=${OUT:-results/spread3}
mkdir -p "$OUT"
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(psv-mean deepview)
# scene name, folder, image folder, downscale
scenes=(
  "fern llff/fern images_8 1"
  "flower llff/flower images_8 1"
  "statue llff/statue images_4 2"
  "canclip llff/canclip images_4 2"
  "room colmap/room images 2"
)
[ "${WIDE:-0}" = 1 ] && scenes+=("room-full colmap/room images 1")
for m in "${methods[@]}"; do
  extra=()
  [ "$m" = deepview ] && [ -n "${WEIGHTS:-}" ] && extra=(--weights "$WEIGHTS")
  for s in "${scenes[@]}"; do
    read -r name dir images down <<<"$s"
    [ -n "${SCENES:-}" ] && [[ " $SCENES " != *" $name "* ]] && continue
    $BIN eval --data "$DATA/$dir" --images "$images" --downscale "$down" --method "$m" \
      --inputs spread:3 --crop 0 "${extra[@]}" ${ARGS:-} --out "$OUT/${name}_${m}.json"
  done
done
python3 scripts/quality_table.py "$OUT"
