#!/usr/bin/env bash
# L2 hit rate and DRAM traffic of the relaxation's kernels at 1024^2, 4 x 8, stick arrays against implicit grid
# sticks, with Nsight Compute on the lent GPU machine (Warp installed there as ../shared/tools/gpu-warp/README.md
# says). Profiles 24 relax launches of the second frame (a frame launches 4 x 8 x 12 colours = 384). Results
# under $OUT (default bench/results/implicit_grid).
set -uo pipefail
out=${OUT:-bench/results/implicit_grid}
mkdir -p "$out"
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
ncu=$(command -v ncu || ls /usr/local/cuda*/bin/ncu /opt/nvidia/nsight-compute/*/ncu 2>/dev/null | head -1)
[ -n "$ncu" ] || { echo "no ncu on this machine"; exit 3; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$out/ncu-gpu.txt"
"$ncu" --version | tail -1 | tee -a "$out/ncu-gpu.txt"
for sticks in explicit auto; do
  timeout 280 "$ncu" --cache-control none --replay-mode application --kernel-name regex:relax \
    --launch-skip 400 --launch-count 24 --csv \
    --metrics gpu__time_duration.sum,lts__t_sector_hit_rate.pct,dram__bytes_read.sum,dram__bytes_write.sum,lts__t_bytes.sum \
    python3 -m bench.l2_profile --size 1024 --budget 4x8 --sticks "$sticks" > "$out/ncu-l2-$sticks.csv" 2> "$out/ncu-l2-$sticks.log"
  echo "$sticks: rc=$? $(wc -l < "$out/ncu-l2-$sticks.csv") lines"
  tail -3 "$out/ncu-l2-$sticks.log"
done
