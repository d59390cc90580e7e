#!/usr/bin/env bash
# Reproduces the paper's rollout tables with the published checkpoints and writes
# docs/reproduction.md: regenerates the 120 test seeds (the reference split) of MOVi-A, MOVi-spheres
# and MOVi-B with Bullet and the KuBasic assets, and evaluates
#  - modela / models / modelb in reference and native mode (Tables 4, 5, 6's diagonal),
#  - every published checkpoint on every dataset it was not trained on (Table 6),
#  - the variants' published weights: NoObjectCells and NoSequential on MOVi-A (Table 8), GELU
#    on MOVi-spheres (Table 11), the second spheres seed (models_seed2), MOVi-B alt.
# With TOPOS_REPRO_FULL=1 it also regenerates all 1,200 MOVi-A scenes (480 frames) to study why
# the numbers differ from the paper's (the whole dataset rolled out with modela: standard errors,
# bootstrap intervals, other splits and subsets) and counts the dataset's contact cells X(3) at
# d_c = 0.05, 0.10, 0.20 (`hopnet stats`, the paper's Supplementary Section 3.6).
# Needs the reference folder (TOPOS_REFERENCE_DIR, default ../shared/reference). On 2 idle
# cores: about 15 minutes after the build, 40 more with TOPOS_REPRO_FULL=1. Work files go to
# build/reproduction (TOPOS_REPRO_DIR); scenes and evaluations already there are kept (delete
# the folder to start over). TOPOS_NICE=1 runs everything under nice.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
REF="${TOPOS_REFERENCE_DIR:-$root/../shared/reference}"
if [ ! -d "$REF/data/checkpoints" ]; then
  echo "reproduce: the reference folder is missing; set TOPOS_REFERENCE_DIR (it holds data/checkpoints)" >&2
  exit 1
fi
NICE=()
[ "${TOPOS_NICE:-0}" = 1 ] && NICE=(nice -n 15)
if [ -z "${TOPOS_HOPNET:-}" ]; then
  bash scripts/setup.sh
  cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
  cmake --build build -j2 --target hopnet
fi
H="${TOPOS_HOPNET:-$root/build/apps/hopnet}"
OUT="${TOPOS_REPRO_DIR:-$root/build/reproduction}"
FULL="${TOPOS_REPRO_FULL:-0}"
mkdir -p "$OUT/eval"
start=$(date +%s)
"$H" split --seeds 1-1200 --out "$OUT/split.json"
TEST=$("$H" split --seeds 1-1200 --part test)
for d in movi-a movi-spheres movi-b; do
  "${NICE[@]}" "$H" generate --dataset "$d" --seeds "$TEST" --assets "$REF/data/kubasic" --format topos --out "$OUT/data/$d"
done
if [ "$FULL" = 1 ]; then
  "${NICE[@]}" "$H" generate --dataset movi-a --seeds 1-1200 --assets "$REF/data/kubasic" --format topos --out "$OUT/data/movi-a-all"
fi
generated=$(date +%s)
evaluate() {  # name checkpoint statistics dataset mode [split] [extra options...]
  local name=$1 ckpt=$2 stats=$3 data=$4 mode=$5 split=${6:-test}
  shift 6 2>/dev/null || shift $#
  if [ -f "$OUT/eval/$name/per_scene.json" ]; then return; fi
  "${NICE[@]}" "$H" evaluate --checkpoint "$REF/data/checkpoints/$ckpt.pt" --stats "$REF/data/normalization/$stats.json" --data "$OUT/data/$data" \
    --assets "$REF/data/kubasic" --split-file "$OUT/split.json" --split "$split" --mode "$mode" --viewer-scenes 0 --out "$OUT/eval/$name" "$@"
}
for mode in reference native; do
  evaluate "modela-movi-a-$mode" modela_seed2_e39 movia movi-a "$mode"
  evaluate "models-movi-spheres-$mode" models_seed0_e39 movis movi-spheres "$mode"
  evaluate "modelb-movi-b-$mode" modelb_seed0_e39 movib movi-b "$mode"
done
# Table 6: each model on the other two datasets (its own statistics, as the reference does).
evaluate models-movi-a-reference models_seed0_e39 movis movi-a reference
evaluate models-movi-b-reference models_seed0_e39 movis movi-b reference
evaluate modela-movi-spheres-reference modela_seed2_e39 movia movi-spheres reference
evaluate modela-movi-b-reference modela_seed2_e39 movia movi-b reference
evaluate modelb-movi-spheres-reference modelb_seed0_e39 movib movi-spheres reference
evaluate modelb-movi-a-reference modelb_seed0_e39 movib movi-a reference
# The variants' published weights (the paper's ablations).
evaluate nox4-movi-a-reference movia-nox4_seed0_e39 movia-nox4 movi-a reference
evaluate noseq-movi-a-reference movia-noseq_seed1_e39 movia movi-a reference
evaluate gelu-movi-spheres-reference gelu_seed0_e39 movis movi-spheres reference test --activation gelu
evaluate models2-movi-spheres-reference models_seed2_e39 movis movi-spheres reference
evaluate movibalt-movi-b-reference movib-alt_seed0_e39 movib movi-b reference
if [ "$FULL" = 1 ]; then
  # All 1,200 MOVi-A scenes: the split is irrelevant ("all"), per-scene errors go to per_scene.json.
  "$H" split --seeds 1-1200 --out "$OUT/split-all.json"
  if [ ! -f "$OUT/eval/modela-movi-a-all/per_scene.json" ]; then
    "${NICE[@]}" "$H" evaluate --checkpoint "$REF/data/checkpoints/modela_seed2_e39.pt" --stats "$REF/data/normalization/movia.json" --data "$OUT/data/movi-a-all" \
      --assets "$REF/data/kubasic" --split all --mode reference --viewer-scenes 0 --out "$OUT/eval/modela-movi-a-all"
  fi
  if [ ! -f "$OUT/stats-movi-a.json" ]; then
    "${NICE[@]}" "$H" stats --data "$OUT/data/movi-a-all" --assets "$REF/data/kubasic" --collision-radius 0.05 0.1 0.2 --out "$OUT/stats-movi-a.json"
  fi
  # The test split of every dataset size n = 1200 - k (one sample missing: the reference split).
  mkdir -p "$OUT/splits"
  for n in 1199 1198 1197 1196 1195 1190 1180 1100; do
    "$H" split --seeds "1-$n" --part test > "$OUT/splits/test-$n.txt"
  done
fi
done_at=$(date +%s)
python3 scripts/reproduction_table.py "$OUT" "$((generated - start))" "$((done_at - generated))" > docs/reproduction.md.tmp
mv docs/reproduction.md.tmp docs/reproduction.md
echo "reproduce: wrote docs/reproduction.md (generation $((generated - start)) s, evaluation $((done_at - generated)) s)"
