#!/usr/bin/env bash
# The two-tether pass in the positions' precision (working tree) against HEAD (float64 on squares), alternately.
set -u
root=$PWD
ln -sfn ../kernels warp_verlet/kernels
ln -sfn ../kernels .gpu/exp49/base/warp_verlet/kernels
run() {  # name dir
  (cd "$2" && PYTHONPATH=/tmp/site:$PWD timeout 250 python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 \
     --large-budgets 64x1 --forms tiled --target-size 0 --out "$OUT/$1" 2>&1 | grep "^| [0-9]")
}
run new-1 "$root"
run base-1 "$root/.gpu/exp49/base"
run new-2 "$root"
nvidia-smi --query-gpu=name,driver_version --format=csv > "$OUT/gpu.txt"
