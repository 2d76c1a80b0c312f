#!/usr/bin/env bash
# The landed build (two tethers at once), the one before it (one tether after the other), and the float32 pre-test.
set -u
root=$PWD
ln -sfn ../kernels warp_verlet/kernels
for d in old pre base; do ln -sfn ../kernels .gpu/exp49/$d/warp_verlet/kernels; done
run() {  # name dir
  (cd "$2" && PYTHONPATH=/tmp/site:$PWD timeout 250 python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 \
     --large-budgets 64x1 --forms tiled --target-size 0 --out "$OUT/$1" 2>&1 | grep "^| [0-9]")
}
run old "$root/.gpu/exp49/old"
run pre "$root/.gpu/exp49/pre"
run new-3 "$root"
