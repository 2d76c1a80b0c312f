#!/usr/bin/env bash
# One batch of GPU work on the lent GPU machine (see ../shared/tools/gpu-warp/README.md): the whole test
# suite on CUDA, throughput with and without graph capture, and CPU/CUDA parity on the shipped scenes.
# Results land in $OUT (or bench/results/gpu when run by hand).
set -uo pipefail
out=${OUT:-bench/results/gpu}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | tail -2 \
  || { echo "editable install failed (old setuptools?): using the tree on PYTHONPATH"; ln -sfn ../kernels warp_verlet/kernels; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
python3 -m pytest -q -rs tests 2>&1 | tail -25 | tee "$out/pytest-cuda.txt"
python3 bench/throughput.py --device cuda --sizes 64 256 512 1024 2048 --repeats 5 --out "$out"
python3 bench/throughput.py --device cuda --sizes 64 1024 --repeats 3 --no-graph --out "$out"
python3 bench/parity.py --frames 30 --big-frames 3 --out "$out"
# End to end through the CLI, USD writing included (summaries appended to gpu.txt: $OUT holds 8 files at most).
{ python3 -m warp_verlet run scenes/hanging_cloth.toml --device cuda -q -o /tmp/hanging.usdc
  python3 -m warp_verlet run scenes/big_grid_1024.toml --device cuda -q -o /tmp/big.usdc --frames 20; } 2>&1 | tee -a "$out/gpu.txt"
