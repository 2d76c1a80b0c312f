#!/usr/bin/env bash
# The convergence measurements (tethers, small steps, the budget) in one batch on the lent GPU machine (../shared/tools/gpu-warp/README.md):
# PART=hanging  the hanging cloth at 256^2, 1024^2 and 2048^2, every method, with Newton Style3D and VBD in the
#               same run;
# PART=swinging the same cloth started level (it swings down: hung in its rest pose, two tethers at once hold it still)
#               at 1024^2 and 2048^2, with and without a line pass, Newton Style3D in the same run at 1024^2;
# PART=rest     the drape (1024^2, no pins), the torn net (512^2), throughput for the README, and the shipped
#               big_grid_1024 through the CLI (it must not warn).
# Results under $OUT (default bench/results/convergence/gpu).
set -uo pipefail
out=${OUT:-bench/results/convergence/gpu}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu-${PART}.txt"
if [ "$PART" = hanging ]; then
  timeout 520 python3 -m bench.convergence --device cuda --scenes hanging --sizes 256 1024 2048 \
    --methods plain tethers tethers+multilevel float64+tethers --budgets 4x8 16x2 32x1 64x1 128x1 256x1 \
    --ref 512x2 --peer --peer-sizes 256 1024 --out "$out" --stem gpu-hanging 2>&1 | tail -60
elif [ "$PART" = swinging ]; then
  timeout 560 python3 -m bench.convergence --device cuda --scenes swinging --sizes 1024 2048 \
    --methods plain tethers tethers+lines --budgets 4x8 16x1 32x1 64x1 --ref 64x4 \
    --peer --peer-sizes 1024 --peer-solvers style3d --out "$out" --stem gpu-swinging 2>&1 | tail -40
else
  timeout 300 python3 -m bench.convergence --device cuda --scenes drape torn_net --drape-sizes 1024 --net-sizes 512 \
    --methods plain multilevel float64 tethers --budgets 4x8 16x2 64x2 128x1 256x1 --ref 256x2 \
    --out "$out" --stem gpu-rest 2>&1 | tail -40
  timeout 120 python3 -m bench.throughput --device cuda --sizes 64 256 1024 2048 --repeats 3 --out "$out" 2>&1 | tail -30
  timeout 120 python3 -m warp_verlet run scenes/big_grid_1024.toml --device cuda -o /tmp/big.usdc 2>&1 | tail -16 \
    | tee -a "$out/gpu-${PART}.txt"
fi
