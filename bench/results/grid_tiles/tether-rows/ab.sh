#!/usr/bin/env bash
# A/B in one lease: the landed build (base, HEAD before the change) against the working tree, alternately.
set -u
root=$PWD
ln -sfn ../kernels warp_verlet/kernels
ln -sfn ../kernels .gpu/exp48/base/warp_verlet/kernels
run() {  # name dir
  (cd "$2" && PYTHONPATH=/tmp/site:$PWD python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 \
     --large-budgets 4x8 64x1 --forms tiled --target-size 0 --out "$OUT/$1" 2>&1 | grep -v "^Warp\|Module\|^   \|^     " | tail -30)
}
run new-1 "$root"
run base-1 "$root/.gpu/exp48/base"
run new-2 "$root"
run base-2 "$root/.gpu/exp48/base"
