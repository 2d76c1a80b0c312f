set -u
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee $OUT/gpu.txt
B="python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 --large-budgets 64x1 --forms tiled --target-size 0"
for v in tiles tiles,step; do mkdir -p $OUT/A-$v; WV_FAST_MATH=$v timeout 150 $B --out $OUT/A-$v > $OUT/A-$v/log.txt 2>&1; grep "^| " $OUT/A-$v/implicit-grid.md; done
C="python3 -m bench.implicit_grid --device cuda --sizes 256 --budgets 4x8 64x1 --forms implicit --target-size 0"
for v in none colour,step; do mkdir -p $OUT/B-$v; WV_FAST_MATH=$v timeout 100 $C --out $OUT/B-$v > $OUT/B-$v/log.txt 2>&1; grep "^| " $OUT/B-$v/implicit-grid.md; done
S="python3 -m bench.self_contact --device cuda --sizes 1024 --substeps 32 --iterations 1 --frames 20 --strides 1 3"
for v in none contact,plane,tiles,step; do mkdir -p $OUT/C-$v; WV_FAST_MATH=$v timeout 150 $S --out $OUT/C-$v > $OUT/C-$v/log.txt 2>&1; grep "^| " $OUT/C-$v/self_contact.md; done
M="python3 -m bench.mesh_throughput --device cuda --sizes 512 --triangles ply --sticks clustered"
for v in none cluster,tiles; do mkdir -p $OUT/D-$v; WV_FAST_MATH=$v timeout 200 $M --out $OUT/D-$v > $OUT/D-$v/log.txt 2>&1; grep "^| " $OUT/D-$v/*.md | cut -c1-200; done
