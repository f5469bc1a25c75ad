# Sourced by the GPU scripts (gpu_check.sh, gpu_ceiling.sh) after they set OUT, WORK and DEADLINE:
# the folders, the package on the path, and the clock every step is stamped and limited by.
mkdir -p "$OUT" "$WORK"
export PYTHONPATH="$PWD/src:$PWD/benchmarks:${PYTHONPATH:-}" PYTHONUNBUFFERED=1
start=$SECONDS
stamp() { echo "[$((SECONDS - start)) s] $*"; }
left() { echo $((DEADLINE - (SECONDS - start))); }
nvidia-smi -L
