#!/usr/bin/env bash
# The HOPNet demo, end to end on a fresh machine with the built-in shapes (no reference data):
# install and build, generate a small MOVi-A-like dataset with Bullet, train a small HOPNet for
# a few minutes, roll out the held-out scenes, print the table beside the constant-velocity
# baseline, and write the report, the training curves and the 3D viewer. Output in build/demo/. About 2 minutes after setup and build.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DTOPOS_WERROR="${TOPOS_WERROR:-ON}" >/dev/null  # as scripts/test.sh: one build serves both
cmake --build build -j2 --target hopnet
H=build/apps/hopnet
OUT=build/demo
rm -rf "$OUT"
$H generate --dataset movi-a --seeds 1-40 --frames 130 --out "$OUT/data"
$H train --data "$OUT/data" --out "$OUT/model" --hidden 64 --lr 1e-3 --epochs 6 --mode native
$H evaluate --checkpoint "$OUT/model/checkpoint.pt" --stats "$OUT/model/stats.json" --data "$OUT/data" \
  --split test --mode native --out "$OUT/eval"
$H plot --log "$OUT/model"
echo "demo done: $OUT/eval/index.html (the report: open it in a browser), $OUT/eval/viewer.html (3D), $OUT/model/training.html"
