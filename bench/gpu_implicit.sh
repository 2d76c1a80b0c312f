#!/usr/bin/env bash
# Implicit grid sticks and the target_stretch budget on the lent GPU machine (../shared/tools/gpu-warp/README.md
# installs Warp there first; usd-core is not needed): the CUDA tests of the step, GPU time per kernel at 1024^2,
# then bench.implicit_grid (stick arrays, implicit sticks with the tether table, and both implicit, at 256^2,
# 1024^2 and 2048^2 with tethers; target_stretch = 0.001 at 1024^2 against the fixed budget it settles on), with
# the device copy rate measured in the same run. Results under $OUT (default bench/results/implicit_grid).
# PART=tests or PART=bench runs one half.
set -uo pipefail
out=${OUT:-bench/results/implicit_grid}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
if [ "${PART:-all}" != bench ]; then
  timeout 200 python3 -m pytest -q -p no:cacheprovider -m cuda tests/test_implicit_grid.py tests/test_stretch_readback.py \
    tests/test_golden.py tests/test_relax.py tests/test_tethers.py tests/test_simulator.py tests/test_memory.py \
    tests/test_state.py tests/test_multilevel.py 2>&1 | tail -8 | tee "$out/pytest-cuda.txt"
fi
if [ "${PART:-all}" != tests ]; then
  timeout 100 python3 -m bench.kernel_times --device cuda --size 1024 --budget 4x8 2>&1 | grep -v "first launches" \
    | tail -14 | tee "$out/kernel-times.txt"
  timeout 440 python3 -m bench.implicit_grid --device cuda --sizes 256 1024 2048 --out "$out" 2>&1 | grep "^|"
fi
