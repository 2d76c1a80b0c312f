#!/usr/bin/env bash
# One batch of GPU work on the lent GPU machine (see ../shared/tools/gpu-warp/README.md): the whole test
# suite on CUDA, throughput (with stages and bandwidth) with and without graph capture and with colliders
# and tearing, writer overlap, CPU/CUDA parity on the shipped scenes, CLI runs end to end, and last the CPU
# reference and CPU throughput on the host's many cores. GPU_EXTRA, if set, is run (eval) before the CPU part.
# Tables land in $OUT/results (tarred into $OUT/gpu-results.tar.gz: $OUT may hold few files), the log in
# $OUT/gpu-session.log.
set -uo pipefail
out=${OUT:-bench/results/gpu}
res=/tmp/gpu-results
mkdir -p "$out" "$res"
export PYTHONUNBUFFERED=1
exec > >(tee "$out/gpu-session.log") 2>&1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | tail -2 \
  || { echo "editable install failed (old setuptools?): using the tree on PYTHONPATH"; ln -sfn ../kernels warp_verlet/kernels; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$res/gpu.txt"
python3 -m pytest -q -rs -p no:cacheprovider tests ${PYTEST_ARGS:-} 2>&1 | tail -25 | tee "$res/pytest-cuda.txt"
python3 -m bench.throughput --device cuda --sizes 64 256 512 1024 2048 --repeats 5 --out "$res"
python3 -m bench.throughput --device cuda --sizes 64 1024 --repeats 3 --no-graph --out "$res"
python3 -m bench.throughput --device cuda --sizes 64 1024 --repeats 3 --colliders --tear 1.5 --out "$res"
python3 -m bench.overlap --device cuda --sizes 256 1024 --frames 30 --repeats 3 --out "$res"
python3 -m bench.parity --frames 30 --big-frames 3 --out "$res"
if [ -n "${GPU_EXTRA:-}" ]; then eval "$GPU_EXTRA"; fi
# End to end through the CLI, USD writing included.
{ python3 -m warp_verlet run scenes/hanging_cloth.toml --device cuda -q -o /tmp/hanging.usdc
  python3 -m warp_verlet run scenes/flag_tear.toml --device cuda -q -o /tmp/flag.usdc
  python3 -m warp_verlet run scenes/big_grid_1024.toml --device cuda -q -o /tmp/big.usdc --frames 20; } 2>&1 | tee -a "$res/gpu.txt"
tar -czf "$out/gpu-results.tar.gz" -C "$res" .
# The host's CPU cores too: the threaded CPU relaxation on more than the development machine's 2 cores.
python3 -m bench.cpu_reference --out "$res/cpu_reference_host"
python3 -m bench.throughput --device cpu --sizes 64 256 1024 --repeats 2 --out "$res/cpu_host"
tar -czf "$out/gpu-results.tar.gz" -C "$res" .
