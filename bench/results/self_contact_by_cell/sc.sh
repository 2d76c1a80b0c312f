#!/usr/bin/env bash
# Self-contact search: the working tree (a lane per cell) against HEAD (a thread per query), alternately, one lease.
set -u
root=$PWD
ln -sfn ../kernels warp_verlet/kernels
ln -sfn ../kernels .gpu/exp48/base/warp_verlet/kernels
run() {  # name dir
  (cd "$2" && PYTHONPATH=/tmp/site:$PWD timeout 280 python3 -m bench.self_contact --device cuda --sizes 1024 --substeps 32 --iterations 1 \
     --frames 20 --strides 1 3 --out "$OUT/$1" 2>&1 | grep -v "^Warp\|Module\|^   \|^     " | tail -12)
}
run new-1 "$root"
run base-1 "$root/.gpu/exp48/base"
run new-2 "$root"
