#!/usr/bin/env bash
# The checks that need a CUDA GPU, in one run (about 8 minutes on one H100/H200):
#
#   1. gsplat 1.5.3's JIT build (sm_90 only, -O3), timed, in the background while 2. runs;
#   2. the hard set's tuning scene (rush traffic at 5 Hz, seed 214, small preset) synthesised and
#      prepared, then trained with the bench grid budget (600 iterations) on the GPU with the
#      pure-PyTorch rasterizer;
#   3. the CUDA tests (torch backend against gsplat, the gsplat exports);
#   4. the same scene trained on the GPU with gsplat;
#   5. `radar4dgs demo` (small preset, seed 1) on the GPU with gsplat, if time is left.
#
# Each step's result is written to $OUT (default /tmp/radar4dgs-gpu-check); the CPU references are
# in benchmarks/results/ (traffic-rush-5hz*.json for seed 214, reconstruct.json for the demo).
#
#     OUT=/tmp/gpu bash benchmarks/gpu_check.sh
#
# Needs gsplat 1.5.3 (pip install gsplat==1.5.3: it compiles its CUDA code on first use, with the
# CUDA toolkit's nvcc and ninja) and the package's own dependencies; ray and imageio-ffmpeg are not
# used by these steps.
set -u
OUT=${OUT:-/tmp/radar4dgs-gpu-check}
WORK=${WORK:-/tmp/radar4dgs-gpu-work}
DEADLINE=${DEADLINE:-500}   # seconds: steps that would start later are skipped
# shellcheck source=benchmarks/gpu_common.sh
source "$(dirname "$0")/gpu_common.sh"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name())"

stamp "1. gsplat JIT build (background)"
(
  t=$SECONDS
  MAX_JOBS=12 TORCH_CUDA_ARCH_LIST="9.0" python3 -c "from gsplat.cuda._backend import _C; assert _C is not None, 'no gsplat CUDA module'" \
    >"$OUT/gsplat_build.log" 2>&1
  echo "rc=$? seconds=$((SECONDS - t))" >"$OUT/gsplat_build.txt"
) &
build=$!

stamp "2. scene 214 + training on the GPU, torch rasterizer"
timeout "$(left)" python3 benchmarks/traffic.py --seeds 214 --traffic rush --fps 5 --methods ours --jobs 1 \
  --set device=cuda threads=4 raster.backend=torch --work "$WORK" --grid grid-cuda-torch \
  --out "$OUT/traffic-214-cuda-torch.json" 2>&1 | tail -n 25
stamp "2. done"

wait $build
stamp "1. gsplat build: $(cat "$OUT/gsplat_build.txt")"
tail -n 30 "$OUT/gsplat_build.log"

stamp "3. CUDA tests"
# One pytest per folder: each test folder has its own conftest.py, imported by that name.
for tests in tests/render/test_raster_gsplat.py tests/apps/test_export_formats.py; do
  timeout "$(left)" python3 -m pytest -q -p no:cacheprovider "$tests" 2>&1 | tail -n 15
done

stamp "4. scene 214 on the GPU with gsplat"
timeout "$(left)" python3 benchmarks/traffic.py --seeds 214 --traffic rush --fps 5 --methods ours --jobs 1 \
  --set device=cuda threads=4 raster.backend=gsplat --work "$WORK" --grid grid-cuda-gsplat \
  --out "$OUT/traffic-214-cuda-gsplat.json" 2>&1 | tail -n 25
for grid in grid-cuda-torch grid-cuda-gsplat; do
  cp "$WORK/$grid/bench.json" "$OUT/bench-$grid.json" 2>/dev/null
done
stamp "4. done"

if [ "$(left)" -gt 200 ]; then
  stamp "5. demo, small preset, on the GPU"
  timeout "$(left)" python3 -m radar4dgs.cli demo --out "$WORK/demo" --preset small --seed 1 2>&1 | tail -n 25
  cp "$WORK/demo/run/metrics.json" "$OUT/demo-metrics.json" 2>/dev/null
fi
stamp "end"
