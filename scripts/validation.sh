#!/usr/bin/env bash
# The validation set of `train --validate-every` scored for any method or weights, for comparison with a
# run's validation.jsonl: held-out views (every 8th) of fern, flower, statue, canclip (LLFF) and room
# (COLMAP) at most 256 px wide, 4 nearest inputs and the few-shot 3 spread inputs (no crop).
# Usage: METHOD=deepview WEIGHTS=weights/cpu scripts/validation.sh     (or METHOD=psv-mean)
set -euo pipefail
D=${DEEPVIEW_DATA:-../shared/data}
BIN=${BIN:-target/release/deepview}
METHOD=${METHOD:-deepview}
W=()
if [ -n "${WEIGHTS:-}" ]; then W=(--weights "$WEIGHTS"); fi
for s in llff/fern:2 llff/flower:2 llff/statue:3 llff/canclip:4 colmap/room:4; do
  scene=${s%%:*}; f=${s##*:}
  a=$("$BIN" eval --data "$D/$scene" --downscale "$f" --method "$METHOD" "${W[@]}" 2>/dev/null | awk '/^ *mean/ {print $2}')
  b=$("$BIN" eval --data "$D/$scene" --downscale "$f" --method "$METHOD" "${W[@]}" --inputs spread:3 --crop 0 2>/dev/null | awk '/^ *mean/ {print $2}')
  echo "$scene nearest:4 $a spread:3 $b"
done
