#!/usr/bin/env bash
# The exact two-tether projection (working tree) against HEAD (one tether after the other), one lease.
set -u
root=$PWD
ln -sfn ../kernels warp_verlet/kernels
ln -sfn ../kernels .gpu/exp48/base/warp_verlet/kernels
run() {  # name dir
  (cd "$2" && PYTHONPATH=/tmp/site:$PWD timeout 250 python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 \
     --large-budgets 64x1 --forms tiled --target-size 0 --out "$OUT/$1" 2>&1 | grep "^| [0-9]")
}
run new "$root"
run base "$root/.gpu/exp48/base"
