#!/usr/bin/env bash
# HOPNet beside the paper's baselines (FIGNet, MeshGraphNet, MeshGraphNet with the large radius)
# on the same generated MOVi-A-like data, split, statistics recipe and metrics, at two budgets:
# the same wall time of optimizer steps as HOPNet's run, and the same number of optimizer steps.
# Then each model's rollouts of the test split beside the constant-velocity baseline.
# Usage: scripts/baselines.sh [OUT] (default build/baselines); needs a built hopnet.
# Environment: SEEDS (1-40), FRAMES (130), EPOCHS (HOPNet's, 6), BATCH (baseline timesteps per
# step in the wall-time budget, 64 as the FIGNet reimplementation), STEPS_BATCH (the same in the
# steps budget, 16: 192 steps of 64 would take FIGNet 20 minutes and each MGN 40 here), ASSETS (a
# KuBasic asset folder for MOVi-A's own meshes; the built-in shapes when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
H=build/apps/hopnet
OUT=${1:-build/baselines}
SEEDS=${SEEDS:-1-40} FRAMES=${FRAMES:-130} EPOCHS=${EPOCHS:-6} BATCH=${BATCH:-64}
STEPS_BATCH=${STEPS_BATCH:-16}
A=()
[ -n "${ASSETS:-}" ] && A=(--assets "$ASSETS")
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
mkdir -p "$OUT"
[ -d "$OUT/data" ] || $H generate "${A[@]}" --dataset movi-a --seeds "$SEEDS" --frames "$FRAMES" --out "$OUT/data"
# HOPNet as the demo trains it (scripts/demo.sh).
[ -f "$OUT/hopnet/state.json" ] || $H train "${A[@]}" --data "$OUT/data" --out "$OUT/hopnet" --hidden 64 \
  --lr 1e-3 --epochs "$EPOCHS" --mode native
# Its budgets: the seconds its optimizer steps took, and their number.
SECONDS_BUDGET=$(awk -F, 'NR > 1 { s += $5 } END { printf "%.1f", s }' "$OUT/hopnet/steps.csv")
STEPS_BUDGET=$(($(wc -l < "$OUT/hopnet/steps.csv") - 1))
echo "HOPNet: $STEPS_BUDGET optimizer steps in $SECONDS_BUDGET s"
# The wall-time budget first (its runs want the machine to themselves), then the steps budget.
for model in fignet mgn mgn-large-radius; do
  $H train "${A[@]}" --data "$OUT/data" --out "$OUT/$model-time" --config "$model" --lr 1e-3 \
    --batch-timesteps "$BATCH" --checkpoint-every 20 --max-seconds "$SECONDS_BUDGET" --epochs 1000 --resume
done
for model in fignet mgn mgn-large-radius; do
  $H train "${A[@]}" --data "$OUT/data" --out "$OUT/$model-steps" --config "$model" --lr 1e-3 \
    --batch-timesteps "$STEPS_BATCH" --checkpoint-every 20 --max-steps "$STEPS_BUDGET" --epochs 1000 --resume
done
# One table and one set of curves per budget, every model beside constant velocity, on TEST_SEEDS
# (60 scenes no model has seen; the 40-scene set's own test split has only 4).
TEST_SEEDS=${TEST_SEEDS:-1001-1060}
[ -d "$OUT/test" ] || $H generate "${A[@]}" --dataset movi-a --seeds "$TEST_SEEDS" --frames "$FRAMES" --out "$OUT/test"
for budget in time steps; do
  $H evaluate "${A[@]}" --checkpoint "$OUT/hopnet/checkpoint.pt" "$OUT/fignet-$budget/checkpoint.pt" \
    "$OUT/mgn-$budget/checkpoint.pt" "$OUT/mgn-large-radius-$budget/checkpoint.pt" \
    --stats "$OUT/hopnet/stats.json" --data "$OUT/test" --split all --mode native \
    --out "$OUT/eval/$budget"
done
echo "baselines done: $OUT/eval/time/index.html, $OUT/eval/steps/index.html"
