#!/usr/bin/env bash
# The demo preview's error against time (the goal: make demo's preview reaches 3% relative RMSE
# in the time it takes). Makes the demo's coin scan as scripts/demo does (if DEMO_OUT has none),
# then runs bench_render's demo section: two independent 1024-spp references of the demo's render
# (seeds 1 and 1001, cached in build/bench-results/render/demo_ref_1024spp[_seed1001]_<key>.exr,
# key = a hash of the height field; their mean is the reference and their difference its own
# noise, which the "corrected" figures subtract), fixed 8/16/32/64 spp, the same spp with
# error-driven allocation, and the demo's own `--time 3`, each with its relative RMSE (linear
# luminance, whole image / sample / mount, and in display space), CPU seconds per spp, wall
# seconds and the load average. MESOSCAN_BENCH_DEMO_RUNS="16,alloc8,denoise" picks runs
# ("none": none). MESOSCAN_BENCH_DEMO_SPLIT=9 adds the error split: two seeds at 9 spp allocated,
# raw / denoised / denoised variance / denoised bias^2 per region (mount, first-hit tilt), for
# each denoiser setting in MESOSCAN_BENCH_DENOISE_VARIANTS="window=2,jbf=1;blend=0;..."
# (keys window, eps, radius, jbf, jbfsigma, blend, correct, c: the correction factor).
#   bench/demo_preview.sh [BUILD]     (DEMO_OUT=demo by default)
set -euo pipefail
BUILD=${1:-build}
OUT=${DEMO_OUT:-demo}
M="$BUILD/app/mesoscan"
if [[ ! -f "$OUT/coin.scan/height.exr" ]]; then
  mkdir -p "$OUT"
  "$M" simulate --object coin --rig paper --crop 400x400+888+517 --focus-height 0 --out "$OUT/coin.session"
  "$M" reconstruct "$OUT/coin.session" --out "$OUT/coin.scan"
fi
mkdir -p "$BUILD/bench-results"
MESOSCAN_BENCH_OUT="$BUILD/bench-results" MESOSCAN_BENCH_RENDER_SCENES=demo \
  MESOSCAN_BENCH_DEMO_SCAN="$OUT/coin.scan" "$BUILD/bench/bench_render"
