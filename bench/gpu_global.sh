#!/usr/bin/env bash
# The global correction, the air and the contact work on the lent GPU machine (../shared/tools/gpu-warp/README.md),
# in parts that each fit one command:
# PART=tests    every CUDA-marked test;
# PART=drape256, drape1024  the drape: plain sweeps and the global correction (multigrid, Jacobi);
# PART=rerun    the correction's drape rows again (after a change to it);
# PART=contact  self-collision and mesh colliders at 1024^2 and 2048^2, 32 x 1;
# PART=meshpeer Newton beside the mesh collider at 256^2 (10k and 100k triangles; ITERATIONS, default 1);
# PART=peer     Newton beside self-collision at 256^2 (the wheel from ../shared/tools/gpu-warp/prepare.sh NEWTON_WHEEL);
# PART=meshes   mesh colliders of exactly 10k and 100k triangles at 256^2, 1024^2 and 2048^2, 32 x 1;
# PART=more     the hanging cloth at 1024^2 with the correction, the drape at 2048^2, and the air's cost.
# Results under $OUT (default bench/results/h100-global).
set -uo pipefail
out=${OUT:-bench/results/h100-global}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu-${PART}.txt"
case "$PART" in
  tests)
    timeout 560 python3 -m pytest -q -m cuda -p no:cacheprovider tests 2>&1 | tail -30 | tee "$out/pytest-cuda.txt" ;;
  drape256)
    timeout 560 python3 -m bench.convergence --device cuda --scenes drape --drape-sizes 256 \
      --methods plain global3 global5 global10 global_jacobi30 --budgets 4x1 8x1 16x1 32x1 64x2 --ref 256x2 \
      --out "$out" --stem gpu-drape-256 2>&1 | tail -60 ;;
  drape1024)
    timeout 250 python3 -m bench.convergence --device cuda --scenes drape --drape-sizes 1024 \
      --methods plain --budgets 16x1 32x1 64x2 128x1 --ref 256x2 --out "$out" --stem gpu-drape-1024 2>&1 | tail -20
    timeout 300 python3 -m bench.convergence --device cuda --scenes drape --drape-sizes 1024 \
      --methods global3 global10 --budgets 4x1 8x1 16x1 --ref 256x2 --out "$out" --stem gpu-drape-1024 2>&1 | tail -20 ;;
  rerun)
    timeout 250 python3 -m bench.convergence --device cuda --scenes drape --drape-sizes 256 \
      --methods global3 global10 --budgets 8x1 16x1 32x1 64x2 --ref 256x2 --out "$out" --stem gpu-drape-256-b \
      2>&1 | tail -12
    timeout 300 python3 -m bench.convergence --device cuda --scenes drape --drape-sizes 1024 \
      --methods global3 --budgets 8x1 16x1 32x1 --ref 256x2 --out "$out" --stem gpu-drape-1024-b 2>&1 | tail -8 ;;
  contact)
    timeout 300 python3 -m bench.self_contact --device cuda --sizes 1024 2048 --substeps 32 --iterations 1 --frames 20 \
      --out "$out" 2>&1 | tail -12
    timeout 250 python3 -m bench.mesh_collider --device cuda --sizes 1024 2048 --subdivisions 5 6 --substeps 32 \
      --iterations 1 --frames 20 --out "$out" 2>&1 | tail -12 ;;
  peer)
    timeout 120 python3 -m bench.self_contact --device cuda --sizes 16 --frames 3 --peer > /dev/null 2>&1  # compiles Newton
    timeout 420 python3 -m bench.self_contact --device cuda --sizes 256 --substeps 32 --iterations 1 --frames 60 --peer \
      --out "$out" 2>&1 | tail -12 ;;
  meshpeer)
    timeout 150 python3 -m bench.mesh_collider --device cuda --sizes 16 --triangles 10000 --frames 3 --peer > /dev/null 2>&1  # compiles Newton
    timeout 420 python3 -m bench.mesh_collider --device cuda --sizes 256 --triangles 10000 100000 --substeps 32 \
      --iterations ${ITERATIONS:-1} --frames 20 --peer --out "$out" 2>&1 | tail -14 ;;
  meshes)
    timeout 560 python3 -m bench.mesh_collider --device cuda --sizes 256 1024 2048 --triangles 10000 100000 --substeps 32 \
      --iterations 1 --frames 20 --out "$out" 2>&1 | tail -14 ;;
  more)
    timeout 300 python3 -m bench.convergence --device cuda --scenes hanging drape --sizes 1024 --drape-sizes 2048 \
      --methods plain global3 global10 --budgets 4x1 8x1 16x1 64x1 --ref 128x2 \
      --out "$out" --stem gpu-more 2>&1 | tail -40
    timeout 200 python3 -m bench.aerodynamics --device cuda --sizes 256 1024 --out "$out" 2>&1 | tail -20 ;;
esac
