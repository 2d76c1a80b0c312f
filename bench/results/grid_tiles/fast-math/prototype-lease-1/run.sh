set -u
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee $OUT/gpu.txt
B="python3 -m bench.implicit_grid --device cuda --sizes 1024 2048 --budgets 4x8 32x1 64x1 --large-budgets 64x1 --forms tiled --target-size 0"
mkdir -p $OUT/base $OUT/fast $OUT/base2 $OUT/fast2
timeout 150 $B --out $OUT/base > $OUT/base/log.txt 2>&1; tail -12 $OUT/base/log.txt
WV_FAST_MATH=1 timeout 150 $B --out $OUT/fast > $OUT/fast/log.txt 2>&1; tail -12 $OUT/fast/log.txt
timeout 60 python3 .gpu/exp47/ks3.py 1024 3 > $OUT/ks3.txt 2>&1; cat $OUT/ks3.txt
timeout 60 python3 .gpu/exp47/ks3.py 1024 1 > $OUT/ks1.txt 2>&1; cat $OUT/ks1.txt
