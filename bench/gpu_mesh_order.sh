#!/usr/bin/env bash
# Mesh cloth beside the grid on the lent GPU machine, with the particles held in the file's order and in Morton
# order (warp_verlet/geometry/particle_order.py), for row-major and shuffled vertex lists; 4 x 8 at 1024^2, the
# quads from USD and the triangles from PLY. Results under $OUT (default bench/results/mesh).
set -uo pipefail
out=${OUT:-bench/results/mesh}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu-orders.txt"
timeout 280 python3 -m bench.mesh_throughput --device cuda --sizes ${SIZES:-1024} --triangles ply \
  --orders input reordered --out "$out" --stem h100-orders 2>&1 | grep "^|"
timeout 280 python3 -m bench.mesh_throughput --device cuda --sizes ${SIZES:-1024} --triangles ply \
  --orders input reordered --shuffle --out "$out" --stem h100-orders-shuffled 2>&1 | grep "^|"
