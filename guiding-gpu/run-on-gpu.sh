#!/usr/bin/env bash
# The GPU checks on a real GPU, for a machine that has one (never lavapipe):
#   bash guiding-gpu/run-on-gpu.sh [--quick]
#
# 1. the difftests of every kernel (guiding-gpu/tests/difftest.rs) and the
#    device tests of the embedding API (tests/tests/device.rs);
# 2. the throughput benchmark: the kernels, and the two backends of one
#    GuidingField (CPU threads against the device) in the same process;
# 3. a guided render of builtin:door on the device, with its statistics.
#
# GUIDING_VK_DEVICE=gpu makes every `auto` selection (the tests', the
# benchmark's) refuse CPU implementations, and GUIDING_REQUIRE_VULKAN=1 makes
# a missing device a failure instead of a skip, so nothing here can quietly
# measure lavapipe. Output goes to stdout and to $OUT (or ./gpu-results).
set -euo pipefail
cd "$(dirname "$0")/.."
quick=""
[ "${1:-}" = "--quick" ] && quick="--quick"
out="${OUT:-gpu-results}"
mkdir -p "$out"

if ! command -v cargo >/dev/null 2>&1 && [ -f "$HOME/.cargo/env" ]; then
  # shellcheck disable=SC1091
  . "$HOME/.cargo/env"
fi
# rust-gpu 0.11's pinned nightly (the shaders are compiled on this machine).
rustup toolchain install nightly-2026-08-15 --profile minimal \
  -c rust-src -c rustc-dev -c llvm-tools >/dev/null
if [ ! -e /usr/lib/x86_64-linux-gnu/libvulkan.so.1 ] && ! ldconfig -p | grep -q libvulkan.so.1; then
  echo "no Vulkan loader (libvulkan.so.1): install libvulkan1 and the GPU's driver" >&2
  exit 2
fi

export GUIDING_VK_DEVICE=gpu
export GUIDING_REQUIRE_VULKAN=1
features=(--features guiding-gpu/shaders)

echo "== devices" | tee "$out/devices.txt"
cargo test --release -p guiding-gpu "${features[@]}" --test runtime -- --nocapture \
  enumeration 2>&1 | tee -a "$out/devices.txt"

echo "== difftests and device tests" | tee "$out/tests.txt"
cargo test --release -p guiding-gpu "${features[@]}" --test difftest -- --nocapture \
  2>&1 | tee -a "$out/tests.txt"
cargo test --release -p guiding-tests "${features[@]}" --test device -- --nocapture \
  2>&1 | tee -a "$out/tests.txt"

echo "== throughput" | tee "$out/throughput.txt"
cargo bench -p guiding-gpu --features shaders --bench throughput -- $quick \
  2>&1 | tee -a "$out/throughput.txt"

echo "== guided render on the device" | tee "$out/render.txt"
spp=32
[ -n "$quick" ] && spp=8
cargo run --release -p host-demo "${features[@]}" -- render builtin:door \
  --integrator guided --guide npm --spp "$spp" --device gpu --vk-device gpu \
  --out "$out/door-gpu.exr" --stats "$out/door-gpu.json" 2>&1 | tee -a "$out/render.txt"
