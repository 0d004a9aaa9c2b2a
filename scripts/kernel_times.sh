#!/usr/bin/env bash
# Each kernel's share of a cubecl device's time over `deepview bench train` (BENCHMARKS.md, "On a GPU"):
# cubecl's profiling logger at level "basic" times every launch (on lavapipe, `wgpu:cpu`, the shaders run on
# the CPU: relative figures, not a GPU's). Sums the durations per kernel over the whole run (the bench's
# warm-up and timed steps).
#
#   bash scripts/kernel_times.sh [DEVICE] [PRESET] [BINARY] [STEPS]
#   (defaults: wgpu:cpu, cpu, target/release/deepview built with --features wgpu, 3; VIEWS, PLANES and CROP
#   override the tuple's 4 views, 32 planes and 16-pixel crop)
set -eu
DEVICE=${1:-wgpu:cpu}
PRESET=${2:-cpu}
BIN=$(realpath "${3:-target/release/deepview}")
STEPS=${4:-3}
VGG=${VGG:-$(realpath ../shared/data/vgg16/vgg16_conv1_1-conv3_3.safetensors)}
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT
cat >"$DIR/cubecl.toml" <<TOML
[profiling.logger]
level = "basic"
file = "$DIR/times.log"
TOML
(cd "$DIR" && "$BIN" bench train --device "$DEVICE" --preset "$PRESET" --views "${VIEWS:-4}" --planes "${PLANES:-32}" \
  --crop "${CROP:-16}" --steps "$STEPS" --vgg-weights "$VGG" >/dev/null 2>&1)
python3 - "$DIR/times.log" <<'PY'
import collections, re, sys
unit = {"ns": 1e-3, "µs": 1.0, "ms": 1e3, "s": 1e6}
total, count = collections.Counter(), collections.Counter()
for line in open(sys.argv[1], encoding="utf-8"):
    parts = [p.strip() for p in line.strip().strip("|").split("|")]
    m = re.match(r"([0-9.]+)(ns|µs|ms|s)$", parts[0]) if len(parts) > 1 else None
    if not m:
        continue
    name = re.sub(r"_[0-9a-f]{8}$", "", " | ".join(parts[1:]))
    total[name] += float(m.group(1)) * unit[m.group(2)]
    count[name] += 1
t = sum(total.values())
print(f"{t / 1e3:10.1f} ms of kernels, {sum(count.values())} launches")
for name, us in total.most_common():
    print(f"{us / 1e3:10.1f} ms {100 * us / t:5.1f}% {count[name]:6d}  {name}")
PY
