#!/usr/bin/env bash
# A mosaic of N x N tiles (30% overlap) of a simulated impasto painting through the virtual rig
# at a quarter of the paper rig's resolution (220 um pixels), each tile re-placed by up to 2 mm
# and 5 degrees, stitched by `mesoscan stitch` under /usr/bin/time -v: its wall time, peak RSS
# against the memory budget (core/budget.h: MESOSCAN_MEMORY_BUDGET_MB, else half the physical
# memory), the pairs accepted and the pose graph's edge RMS.
#   bench/stitch_mosaic.sh [BUILD] [N=6] [CROP=96]   (tiles of CROP x CROP camera pixels)
# The tiles are cached in $BUILD/bench-results/stitch_NxN_CROP/.
set -euo pipefail
BUILD=${1:-build}
N=${2:-6}
CROP=${3:-96}
M="$(realpath "$BUILD/app/mesoscan")"
OUT="$BUILD/bench-results/stitch_${N}x${N}_${CROP}"
mkdir -p "$OUT"
cd "$OUT"
cat > quarter.json <<'RIG'
{"rig": {
 "camera": {"K": [[1136.3636363636363, 0, 271.5], [0, 1136.3636363636363, 178.5], [0, 0, 1]],
  "black_level": 0, "distortion": [0, 0, 0, 0, 0], "width": 544, "height": 358,
  "response": "linear", "world_from_device": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0.25],
  [0, 0, 0, 1]]},
 "lens_shifter": {"axis": "x", "range_steps": [-2048, 2048], "steps_per_px": 2048.0},
 "projector": {"K": [[412.5, 0, 99.5], [0, 412.5, 74.5], [0, 0, 1]],
  "distortion": [0, 0, 0, 0, 0], "width": 200, "height": 150, "response": "linear",
  "world_from_device": [[0.9396926207859084, 0, -0.3420201433256687, 0.09063533798130222],
   [0, -1, 0, 0], [-0.3420201433256687, 0, -0.9396926207859084, 0.24901854450826574],
   [0, 0, 0, 1]]}}}
RIG
# Step 70% of a tile; the canvas covers the mosaic with a margin.
read -r STEP CANVAS < <(python3 -c "s=0.7*$CROP*0.22; print(f'{s:.4f}', int(($N-1)*s+$CROP*0.22+12))")
scans=()
offsets=()
for ((k = 0; k < N * N; ++k)); do
  read -r OX OY RZ TX TY < <(python3 -c "
import random
k, n, s = $k, $N, $STEP
r = random.Random(k)
ox, oy = (k % n - (n - 1) / 2) * s, ((n - 1) / 2 - k // n) * s
rz, tx, ty = (0, 0, 0) if k == 0 else (r.uniform(-5, 5), r.uniform(-2, 2), r.uniform(-2, 2))
print(f'{ox:.4f} {oy:.4f} {rz:.3f} {tx:.3f} {ty:.3f}')")
  if [[ ! -f "t$k.scan/height.exr" ]]; then
    "$M" simulate --object "impasto:${CANVAS}x${CANVAS}" --rig quarter.json \
      --crop $((272 - CROP / 2)),$((179 - CROP / 2)),$CROP,$CROP --supersample 1 --ls-frames 8 \
      --seed $((k + 1)) --field-offset "$OX,$OY" --object-pose "0,0,$RZ,$TX,$TY,0" \
      --out "t$k" > /dev/null
    "$M" reconstruct "t$k" --out "t$k.scan" > /dev/null
  fi
  scans+=("t$k.scan")
  offsets+=("$OX,$OY")
done
echo "stitch: ${N}x${N} tiles of ${CROP}x${CROP} px, canvas ${CANVAS} mm"
/usr/bin/time -v "$M" stitch "${scans[@]}" --offset "${offsets[@]}" --out mosaic.scan --force \
  2> time.txt | tail -2
grep -E "Elapsed|Maximum resident" time.txt
python3 - "$CANVAS" <<'PY'
import json, os, sys
rep = json.load(open("mosaic.scan/report.json"))
st = rep["stitch"]
acc = sum(1 for p in st["pairs"] if p["accepted"])
print(f"pairs accepted {acc}/{len(st['pairs'])}, pose-graph edge RMS {st.get('edge_rms_um', 0):.2f} um, "
      f"grid {rep['grid']['width']}x{rep['grid']['height']}")
budget = os.environ.get("MESOSCAN_MEMORY_BUDGET_MB")
if budget is None:
    pages = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    budget = pages / 2 / 2**20
rss = [l for l in open("time.txt") if "Maximum resident" in l][0].split()[-1]
print(f"peak RSS {int(rss) / 1024:.0f} MB, memory budget {float(budget):.0f} MB")
PY
