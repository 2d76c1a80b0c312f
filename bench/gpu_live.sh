#!/usr/bin/env bash
# The live view's numbers on the lent GPU machine (see ../shared/tools/gpu-warp/README.md; viser and its needs
# travel as extra wheels): the live-session and live-bench tests on CUDA, then bench.live_throughput at the
# throughput budget (4 x 8, no tethers) and at the converged one (32 x 1 with tethers), on CUDA. Tables and logs
# land in $OUT.
set -uo pipefail
out=${OUT:-bench/results/live}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
exec > >(tee "$out/gpu-live.log") 2>&1
python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | tail -2 \
  || { echo "editable install failed: using the tree on PYTHONPATH"; ln -sfn ../kernels warp_verlet/kernels; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -m pytest -q -rs -p no:cacheprovider tests/test_live_session.py tests/test_bench_live_throughput.py 2>&1 | tail -8
for budget in "--substeps 4 --iterations 8" "--substeps 32 --iterations 1 --tethers"; do
  # shellcheck disable=SC2086  # the budget is several words on purpose
  python3 -m bench.live_throughput --device cuda --sizes 64 256 1024 $budget --out "$out"
done
