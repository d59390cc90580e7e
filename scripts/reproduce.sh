#!/usr/bin/env bash
# Reproduces the paper's rollout tables with the published checkpoints and writes
# docs/reproduction.md: regenerates the 120 test seeds (spec section 10) of MOVi-A, MOVi-spheres
# and MOVi-B with Bullet and the KuBasic assets, evaluates modela / models / modelb in reference
# and native mode, and the spheres model on MOVi-A and MOVi-B (Table 6's generalisation rows).
# Needs the reference folder (TOPOS_REFERENCE_DIR, default ../shared/reference). About 5 minutes
# on 2 cores after the build; work files go to build/reproduction (TOPOS_REPRO_DIR).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
REF="${TOPOS_REFERENCE_DIR:-$root/../shared/reference}"
if [ ! -d "$REF/data/checkpoints" ]; then
  echo "reproduce: the reference folder is missing; set TOPOS_REFERENCE_DIR (it holds data/checkpoints)" >&2
  exit 1
fi
bash scripts/setup.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j2 --target hopnet
H="$root/build/examples/hopnet"
OUT="${TOPOS_REPRO_DIR:-$root/build/reproduction}"
mkdir -p "$OUT/eval"
start=$(date +%s)
"$H" split --seeds 1-1200 --out "$OUT/split.json"
TEST=$("$H" split --seeds 1-1200 --part test)
for d in movi-a movi-spheres movi-b; do
  "$H" generate --dataset "$d" --seeds "$TEST" --assets "$REF/data/kubasic" --format topos --out "$OUT/data/$d"
done
generated=$(date +%s)
evaluate() {  # name checkpoint statistics dataset mode
  "$H" evaluate --checkpoint "$REF/data/checkpoints/$2.pt" --stats "$REF/data/normalization/$3.json" --data "$OUT/data/$4" \
    --assets "$REF/data/kubasic" --split-file "$OUT/split.json" --split test --mode "$5" --out "$OUT/eval/$1"
}
for mode in reference native; do
  evaluate "modela-movi-a-$mode" modela_seed2_e39 movia movi-a "$mode"
  evaluate "models-movi-spheres-$mode" models_seed0_e39 movis movi-spheres "$mode"
  evaluate "modelb-movi-b-$mode" modelb_seed0_e39 movib movi-b "$mode"
done
evaluate models-movi-a-reference models_seed0_e39 movis movi-a reference
evaluate models-movi-b-reference models_seed0_e39 movis movi-b reference
done_at=$(date +%s)
python3 scripts/reproduction_table.py "$OUT" "$((generated - start))" "$((done_at - generated))" > docs/reproduction.md.tmp
mv docs/reproduction.md.tmp docs/reproduction.md
echo "reproduce: wrote docs/reproduction.md (generation $((generated - start)) s, evaluation $((done_at - generated)) s)"
