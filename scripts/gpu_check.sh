#!/usr/bin/env bash
# The GPU checks of issue 26 (BENCHMARKS.md, "On a GPU") in one call of the library's `device` tool, for a
# session whose task is lent a GPU. Everything is prepared here first (no Rust toolchain and no network
# there; `../shared` does not travel):
#
#   echo /.gpu/ >> .git/info/exclude; echo /.gl/ >> .git/info/exclude
#   cargo build --release -p deepview --features wgpu          # 22-32 min cold on 2 cores
#   mkdir -p .gpu/data/llff/fern .gpu/bench
#   strip -o /tmp/deepview-wgpu target/release/deepview && xz -T2 -6 -c /tmp/deepview-wgpu > .gpu/deepview.xz
#   cp -r ../shared/data/vgg16 .gpu/data/ && cp -r ../shared/data/llff/fern/{images_8,poses_bounds.npy} .gpu/data/llff/fern/
#   cp ../shared/bench/corenet_gpu.py .gpu/bench/
#   # optional, for the `tune` stage: the same build with cubecl's autotuning (burn's default conv is direct)
#   cargo build --release -p deepview --features wgpu,autotune && strip -o /tmp/dv-tune target/release/deepview \
#     && xz -T2 -6 -c /tmp/dv-tune > .gpu/deepview-tune.xz
#   # optional, for the `vulkan` stage: cubecl's SPIR-V compiler (cooperative matrices, i.e. tensor cores,
#   # which WGSL lacks) with autotuning, so that convolutions may take the implicit GEMM (65 min here beside
#   # other builds, in its own target folder)
#   CARGO_TARGET_DIR=../vulkan-target cargo build --release -p deepview --features vulkan,autotune && \
#     strip -o /tmp/dv-vk ../vulkan-target/release/deepview && xz -T2 -6 -c /tmp/dv-vk > .gpu/deepview-vulkan.xz
#   # the Vulkan loaders into .gl: the device README's `apt-get download` recipe
#
# Dry runs here (lavapipe instead of the H200: `OUT=/tmp/x bash scripts/gpu_check.sh infer`): on
# 2026-12-05 fern `images_8` at 32 planes did not infer on wgpu:cpu (lavapipe allocates at most 128 MiB
# at once and tiles were sized by the memory budget alone); since the plan also keeps every tensor
# within the device's largest allocation it does (342 s on lavapipe), and `deepview diff` finds it
# within 1/255 of the CPU engine's MPI (17/255 before tiles sampled exactly as the whole image does).
#
# then `run` with command `bash scripts/gpu_check.sh [STAGES]`, carry [".gpu", ".gl"], timeout_s 560; STAGES
# is any of `infer train net torch dispatches times tune vulkan` (default: the first four; the step timeouts add up to more than one call's 10
# minutes, so on a slow build run `infer train` and `net torch` as two calls). Each step runs
# under its own timeout; the log and the JSON lines come back in $OUT (gpu.log, bench.jsonl). Give the
# machine back afterwards unless rerunning at once.
set -u
OUT=${OUT:-/tmp/gpu-out}
mkdir -p "$OUT"
LOG=$OUT/gpu.log
log() { echo "== $(date +%T) $*" | tee -a "$LOG"; }
# One step: its timeout in seconds, then the command; JSON lines also go to bench.jsonl.
step() {
  local t=$1
  shift
  log "$*"
  timeout "$t" "$@" 2>&1 | grep -v XDG_RUNTIME_DIR | tee -a "$LOG" | grep '^{' >>"$OUT/bench.jsonl"
  log "exit ${PIPESTATUS[0]}"
}

for f in .gl/*.deb; do [ -e "$f" ] && dpkg -x "$f" /; done
ldconfig
# NVIDIA's Vulkan driver where it is (elsewhere, e.g. a dry run here, the system's: lavapipe).
if [ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
xz -dc .gpu/deepview.xz >/tmp/deepview && chmod +x /tmp/deepview
B=/tmp/deepview
D=.gpu/data
VGG=$D/vgg16/vgg16_conv1_1-conv3_3.safetensors
STAGES=" ${*:-infer train net torch} "
want() { [[ $STAGES == *" $1 "* ]]; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv >>"$LOG" 2>&1

# Correctness first (the issue: GPU inference equals the CPU engine's MPI on fern to 1/255).
if want infer; then
  step 120 $B infer --data $D/llff/fern --images images_8 --planes 32 --device cpu --out /tmp/fern_cpu
  step 180 $B infer --data $D/llff/fern --images images_8 --planes 32 --device wgpu --out /tmp/fern_wgpu
  step 60 $B diff /tmp/fern_cpu /tmp/fern_wgpu --max 1
fi

# Speed: training steps (4 views x 32 planes) and the paper's headline inference case, each beside PyTorch.
if want train; then
  for p in cpu paper-kalantari paper-spaces-4view; do
    step 150 $B bench train --device wgpu --preset $p --views 4 --planes 32 --crop 32 --steps 3 --vgg-weights "$VGG"
  done
fi
if want dispatches; then
  # Kernel launches per training step on the GPU (scripts/dispatches.sh; the count lavapipe gives here).
  for p in cpu paper-kalantari; do
    log "dispatches $p"
    VGG=$(realpath "$VGG") timeout 200 bash scripts/dispatches.sh wgpu $p $B 2>&1 | head -25 | tee -a "$LOG"
  done
fi
if want times; then
  # Each kernel's time on the GPU (scripts/kernel_times.sh: cubecl's profiling logger, every launch timed):
  # where a step's time goes, kernel by kernel, for the next kernels to write.
  for p in cpu paper-kalantari; do
    log "kernel times $p"
    VGG=$(realpath "$VGG") CROP=32 timeout 200 bash scripts/kernel_times.sh wgpu $p $B 2 2>&1 | head -30 | tee -a "$LOG"
  done
fi
if want tune && [ -e .gpu/deepview-tune.xz ]; then
  # The autotuned build against the default one (direct convolutions), paper presets.
  xz -dc .gpu/deepview-tune.xz >/tmp/deepview-tune && chmod +x /tmp/deepview-tune
  for p in paper-kalantari paper-spaces-4view; do
    step 200 /tmp/deepview-tune bench train --device wgpu --preset $p --views 4 --planes 32 --crop 32 --steps 4 --vgg-weights "$VGG"
  done
  step 240 /tmp/deepview-tune bench net --device wgpu --preset paper-spaces-4view --views 12 --planes 64 --size 980x580
fi
if want vulkan && [ -e .gpu/deepview-vulkan.xz ]; then
  # The SPIR-V build (with autotuning): correctness on fern first, then the paper presets and the headline case.
  xz -dc .gpu/deepview-vulkan.xz >/tmp/deepview-vulkan && chmod +x /tmp/deepview-vulkan
  step 180 /tmp/deepview-vulkan infer --data $D/llff/fern --images images_8 --planes 32 --device wgpu --out /tmp/fern_vk
  [ -d /tmp/fern_cpu ] && step 60 $B diff /tmp/fern_cpu /tmp/fern_vk --max 1
  for p in cpu paper-kalantari paper-spaces-4view; do
    step 200 /tmp/deepview-vulkan bench train --device wgpu --preset $p --views 4 --planes 32 --crop 32 --steps 4 --vgg-weights "$VGG"
  done
  step 240 /tmp/deepview-vulkan bench net --device wgpu --preset paper-spaces-4view --views 12 --planes 64 --size 980x580
fi
if want net; then
  step 240 $B bench net --device wgpu --preset paper-spaces-4view --views 12 --planes 64 --size 980x580
fi
if want torch; then
  for p in cpu paper-kalantari paper-spaces-4view; do
    step 90 python3 .gpu/bench/corenet_gpu.py --preset $p --views 4 --planes 32 --train-crop 32
  done
  step 120 python3 .gpu/bench/corenet_gpu.py --preset paper-spaces-4view --views 12 --planes 64 --height 580 --width 980
fi
log "done"
