set -u
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee $OUT/gpu.txt
B="python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 --large-budgets 64x1 --forms tiled --target-size 0"
export WV_FAST_MATH=tiles
mkdir -p $OUT/table $OUT/computed $OUT/reg56
timeout 150 $B --out $OUT/table > $OUT/table/log.txt 2>&1; grep "^| " $OUT/table/implicit-grid.md
WV_GRID_TETHERS=1 timeout 150 $B --out $OUT/computed > $OUT/computed/log.txt 2>&1; grep "^| " $OUT/computed/implicit-grid.md
WV_GRID_TETHERS=1 timeout 100 python3 -m bench.implicit_grid --device cuda --sizes 1024 --budgets 4x8 64x1 --forms tiled --target-size 0 --max-registers 56 --out $OUT/reg56 > $OUT/reg56/log.txt 2>&1; grep "^| " $OUT/reg56/implicit-grid.md
WV_GRID_TETHERS=1 timeout 100 python3 -m bench.kernel_times --device cuda --size 1024 --budget 64x1 > $OUT/kt-computed.txt 2>&1; grep -A8 "tiled:" $OUT/kt-computed.txt
