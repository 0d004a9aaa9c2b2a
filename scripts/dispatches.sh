#!/usr/bin/env bash
# GPU dispatches (kernel launches) per training step of `deepview bench train` on a cubecl device: the
# count that issue 26's "few dispatches" is about, measurable without a GPU (on lavapipe, `wgpu:cpu`).
# cubecl's profiling logger ("minimal": every kernel launch, no timing) is turned on by a cubecl.toml in
# the working directory; the count of a 3-step run minus that of a 1-step run, halved, is one step (the
# setup and the first step's one-time work cancel out).
#
#   bash scripts/dispatches.sh [DEVICE] [PRESET] [BINARY]
#   (defaults: wgpu:cpu, cpu, target/release/deepview built with --features wgpu; VIEWS, PLANES and CROP
#   override the tuple's 4 views, 32 planes and 16-pixel crop: e.g. VIEWS=2 PLANES=4 for the paper presets on
#   lavapipe, where a full-size step takes minutes)
#
# Prints the dispatches per step, then the kernels by count (per step).
set -eu
DEVICE=${1:-wgpu:cpu}
PRESET=${2:-cpu}
BIN=$(realpath "${3:-target/release/deepview}")
VGG=${VGG:-$(realpath ../shared/data/vgg16/vgg16_conv1_1-conv3_3.safetensors)}
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT
cat >"$DIR/cubecl.toml" <<TOML
[profiling.logger]
level = "minimal"
file = "$DIR/kernels.log"
TOML
count() {
  rm -f "$DIR/kernels.log"
  (cd "$DIR" && "$BIN" bench train --device "$DEVICE" --preset "$PRESET" --views "${VIEWS:-4}" --planes "${PLANES:-32}" --crop "${CROP:-16}" \
    --steps "$1" --vgg-weights "$VGG" >/dev/null 2>&1)
  sed -E 's/^Executing //; s/_[0-9a-f]{8}$//' "$DIR/kernels.log" | sort | uniq -c |
    awk '{c=$1; $1=""; print substr($0,2) "\t" c}' | sort -t$'\t' -k1,1 >"$DIR/k$1"
}
count 1
count 3
join -t$'\t' -a1 -e 0 -o 0,1.2,2.2 "$DIR/k3" "$DIR/k1" |
  awk -F'\t' '{d=($2-$3)/2; t+=d; if (d>0) printf "%8.1f  %s\n", d, $1} END {printf "%8.1f  dispatches per step\n", t}' |
  sort -rn
