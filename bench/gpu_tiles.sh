#!/usr/bin/env bash
# Tiled sweeps (kernels/grid_tiles.py) on the lent GPU machine (../shared/tools/gpu-warp/README.md installs Warp
# there first): PART=tests runs every CUDA test (the previews' and the browser's need what the machine lacks); PART=bench times every form's kernels at
# 1024^2 (4 x 8) and runs bench.implicit_grid at 1024^2 and 2048^2 with the copy rate in the same run, then the
# tiled form alone with other tile sizes; PART=profile runs Nsight Compute's launch, occupancy and warp-state
# sections on two tiled launches and one implicit colour of the second frame at 1024^2; PART=registers runs the
# tiled form at 1024^2 and 2048^2 with each cap on a thread's registers in REGS (0: the compiler's choice); PART=fold
# runs the tiled form with the first tether pass inside the Verlet step and apart (--tethers-apart). Results under $OUT
# (default bench/results/grid_tiles).
set -uo pipefail
out=${OUT:-bench/results/grid_tiles}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
[ -e warp_verlet/kernels ] || ln -sfn ../kernels warp_verlet/kernels  # no editable install there
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
case "${PART:-bench}" in
  tests)
    timeout 560 python3 -m pytest -q -p no:cacheprovider -m cuda tests --ignore=tests/test_preview.py \
      --ignore=tests/test_browser.py 2>&1 | tail -12 | tee "$out/pytest-cuda.txt" ;;
  bench)
    timeout 120 python3 -m bench.kernel_times --device cuda --size 1024 --budget 4x8 2>&1 | grep -v "first launches" \
      | tee "$out/kernel-times.txt" | grep -v "^  " 
    timeout 400 python3 -m bench.implicit_grid --device cuda --sizes ${SIZES:-64 256 1024 2048} \
      --forms ${FORMS:-explicit implicit tiled} --target-size ${TARGET_SIZE:-1024} --out "$out" 2>&1 | grep "^|"
    for tile in ${TILES:-8 24 32}; do
      timeout 200 python3 -m bench.implicit_grid --device cuda --sizes 1024 --forms tiled --tile "$tile" \
        --target-size 0 --out "$out/tile-$tile" 2>&1 | grep "^| 1024"
    done ;;
  fold)
    for apart in "" --tethers-apart; do
      echo "== tethers ${apart:-inside the Verlet step}"
      timeout 200 python3 -m bench.implicit_grid --device cuda --sizes ${SIZES:-512 1024 2048} --budgets 4x8 32x1 64x1 \
        --large-budgets 4x8 64x1 --forms tiled --target-size 0 $apart --out "$out/fold${apart:+-apart}" 2>&1 | grep "^| [125]"
    done ;;
  registers)
    for r in ${REGS:-0 64 56 48}; do
      echo "== registers: $r"
      timeout 200 python3 -m bench.implicit_grid --device cuda --sizes ${SIZES:-1024 2048} --budgets 4x8 64x1 \
        --large-budgets 64x1 --forms tiled --target-size 0 --max-registers "$r" --out "$out/registers-$r" 2>&1 | grep "^| [12]"
    done ;;
  profile)
    ncu=$(command -v ncu || ls /usr/local/cuda*/bin/ncu /opt/nvidia/nsight-compute/*/ncu 2>/dev/null | head -1)
    for sticks in tiled implicit; do
      timeout 250 "$ncu" --cache-control none --kernel-name regex:relax_grid --launch-skip 200 --launch-count 2 \
        --section LaunchStats --section Occupancy --section WarpStateStats --section SchedulerStats \
        --section MemoryWorkloadAnalysis --section SpeedOfLight \
        python3 -m bench.l2_profile --size 1024 --budget 4x8 --sticks "$sticks" > "$out/ncu-$sticks.txt" 2>&1
      echo "$sticks: rc=$?"; grep -E "Duration|Achieved Occupancy|Theoretical Occupancy|Block Limit|Stall|Warp Cycles Per Issued|Shared Memory Configuration|Dynamic Shared|Registers Per" "$out/ncu-$sticks.txt" | head -40
    done ;;
esac
