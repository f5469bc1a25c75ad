#!/usr/bin/env bash
# Does the hard set's novel-view PSNR* grow with the training budget? One GPU call (about 8 minutes
# on one H200): the hard set's tuning scene (rush traffic at 5 Hz, seed 214, `small`) synthesised and
# prepared once, then trained with rigid actors (the settings chosen on it: from 30 % of the run,
# smoothness 1) for 1 800 (the `small` preset), 3 600 and 5 400 iterations at once on the GPU with
# the pure-PyTorch rasterizer, each evaluated as `benchmarks/reconstruct.py` does.
#
#     OUT=/tmp/gpu bash benchmarks/gpu_budget.sh
#
# Results: $OUT/budget-<iterations>.json (reconstruct.py's JSON) and the logs. A report seed is not
# run: the budget is chosen on the tuning seed only.
set -u
OUT=${OUT:-/tmp/radar4dgs-gpu-budget}
WORK=${WORK:-/tmp/radar4dgs-gpu-budget-work}
DEADLINE=${DEADLINE:-540}
BUDGETS=${BUDGETS:-"1800 3600 5400"}
mkdir -p "$OUT" "$WORK"
export PYTHONPATH="$PWD/src:$PWD/benchmarks:${PYTHONPATH:-}" PYTHONUNBUFFERED=1
start=$SECONDS
stamp() { echo "[$((SECONDS - start)) s] $*"; }
left() { echo $((DEADLINE - (SECONDS - start))); }

nvidia-smi -L
stamp "scene 214: synthesis and front end"
python3 -c "
from pathlib import Path
from reconstruct import prepare_scene
print(prepare_scene(214, 'small', Path('$WORK/base'), 'rush', 5.0)[2], 's')" 2>&1 | tail -n 3
for iterations in $BUDGETS; do
  mkdir -p "$WORK/it$iterations/seed214"
  ln -sfn "$WORK/base/seed214/scene" "$WORK/it$iterations/seed214/scene"
  cp -r "$WORK/base/seed214/prepared" "$WORK/it$iterations/seed214/prepared"
done
stamp "training, budgets: $BUDGETS"
for iterations in $BUDGETS; do
  timeout "$(left)" python3 benchmarks/reconstruct.py --seeds 214 --traffic rush --fps 5 --methods ours \
    --set device=cuda threads=4 raster.backend=torch rigid_actors_at=0.3 rigid_actors_smoothness=1 \
    optim.iterations=$iterations --work "$WORK/it$iterations" --out "$OUT/budget-$iterations.json" \
    >"$OUT/budget-$iterations.log" 2>&1 &
done
wait
for iterations in $BUDGETS; do
  stamp "$iterations iterations: $(grep '^seed 214' "$OUT/budget-$iterations.log" || tail -n 2 "$OUT/budget-$iterations.log")"
done
stamp "end"
