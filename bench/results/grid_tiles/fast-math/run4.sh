set -u
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee $OUT/gpu.txt
timeout 300 python3 -m pytest -q -m cuda tests -p no:cacheprovider --continue-on-collection-errors 2>&1 | tail -15 > $OUT/pytest-cuda.txt; tail -4 $OUT/pytest-cuda.txt
mkdir -p $OUT/tiled $OUT/mesh
timeout 150 python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 --large-budgets 4x8 64x1 --forms tiled --target-size 0 --out $OUT/tiled > $OUT/tiled/log.txt 2>&1; grep "^| " $OUT/tiled/implicit-grid.md
timeout 260 python3 -m bench.mesh_throughput --device cuda --sizes 1024 --triangles ply --sticks clustered --out $OUT/mesh --stem h100-fast-math-1024 > $OUT/mesh/log.txt 2>&1; grep "^| \|x the grid" $OUT/mesh/*.md | cut -c1-220
