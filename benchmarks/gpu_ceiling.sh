#!/usr/bin/env bash
# The front-end ceiling on a GPU: one hard scene (rush traffic at 5 Hz, default report seed 209)
# trained at the bench grid budget (600 iterations) twice, on the GPU with the pure-PyTorch
# rasterizer: once as prepared, once with every front-end input from the generator's truth (depth,
# dynamic masks, scene flow: prepare's depth.source=oracle flow.method=oracle flow.mask_source=oracle
# and training's mask_source=gt). About 12 minutes on one H200: both scenes prepared at once on its
# CPUs (about 3 minutes), then each training about 4.5 minutes. A cell stopped at DEADLINE is
# run again by the next call with the same WORK (finished cells are reused).
#
#     OUT=/tmp/ceiling SEED=209 bash benchmarks/gpu_ceiling.sh
#
# The same on the CPU: benchmarks/traffic.py with the --prepare-set and --set below, without
# device=cuda (benchmarks/results/front-end-ceiling.json).
set -u
OUT=${OUT:-/tmp/radar4dgs-gpu-ceiling}
WORK=${WORK:-/tmp/radar4dgs-gpu-ceiling-work}
SEED=${SEED:-209}
DEADLINE=${DEADLINE:-800}   # seconds: a cell still running then is stopped
ORACLE="depth.source=oracle flow.method=oracle flow.mask_source=oracle"
# shellcheck source=benchmarks/gpu_common.sh
source "$(dirname "$0")/gpu_common.sh"
stamp "scene $SEED made and prepared twice (as prepared, from the truth)"
prepare() {  # $1: work folder, rest: PrepareConfig overrides
  python3 -c "import sys; from pathlib import Path; from traffic import prepare_scene
print(prepare_scene($SEED, 'rush', 5.0, 'small', Path(sys.argv[1]), sys.argv[2:])[1])" "$@" 2>&1 | tail -n 2
}
prepare "$WORK/prepared" & prepare "$WORK/oracle" $ORACLE & wait
stamp "prepared"

cell() {  # $1: work folder, $2: method, $3: --prepare-set items
  timeout "$(left)" python3 benchmarks/traffic.py --seeds "$SEED" --traffic rush --fps 5 --methods "$2" --jobs 1 \
    --set device=cuda threads=8 raster.backend=torch --prepare-set $3 --work "$1" \
    --out "$OUT/traffic-$SEED-$(basename "$1").json" 2>&1 | tail -n 4
  stamp "$(basename "$1") done"
}
cell "$WORK/oracle" ours-gt-masks "$ORACLE"
cell "$WORK/prepared" ours ""
