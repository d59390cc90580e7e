#!/usr/bin/env bash
# Data-parallel training throughput: `hopnet train` for STEPS optimizer steps with 1 process and
# with --nproc 2 on the same dataset (native features, hidden 128), then per configuration the
# step time (minimum and median over the steps after the first, which grows the heap), steps/s,
# trajectories/s and timesteps/s from rank 0's steps.csv. A multi-process training program is
# measured end to end, so this is a script, not a Google Benchmark.
# Usage: [MAX_FRAMES=F] scripts/bench_distributed.sh HOPNET DATA OUT [STEPS] [SPLIT_JSON]
#   DATA: a topos dataset, e.g. hopnet generate --dataset movi-a --seeds 1-4 --assets .../kubasic
#   SPLIT_JSON: default: every scene of DATA trains.
set -euo pipefail
HOPNET=$1 DATA=$2 OUT=$3 STEPS=${4:-6} SPLIT=${5:-}
mkdir -p "$OUT"
if [ -z "$SPLIT" ]; then
  SPLIT=$OUT/split.json
  python3 -c "import json,sys; ids=json.load(open(sys.argv[1]+'/dataset.json'))['scenes']; print(json.dumps({'train':[s['id'] if isinstance(s,dict) else s for s in ids],'val':[],'test':[]}))" "$DATA" >"$SPLIT"
fi
report() {  # report NAME PROCS CSV
  python3 - "$@" <<'EOF'
import csv, statistics, sys
name, procs, path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
rows = list(csv.DictReader(open(path)))[1:]  # the first step grows the heap
secs = [float(r["seconds_per_step"]) for r in rows]
trajs = [len(r["scene"].split(";")) for r in rows]
ts = [float(r["timesteps_per_second"]) * float(r["seconds_per_step"]) for r in rows]
tot = sum(secs)
print(f"{name:>22}: step min {min(secs):.2f} s, median {statistics.median(secs):.2f} s; "
      f"{len(rows) / tot:.3f} steps/s, {sum(trajs) / tot:.3f} trajectories/s, {sum(ts) / tot:.0f} timesteps/s "
      f"({len(rows)} steps after the first)")
EOF
}
common=(train --data "$DATA" --split-file "$SPLIT" --mode native --epochs 1000 --max-steps "$STEPS" --seed 1 ${MAX_FRAMES:+--max-frames $MAX_FRAMES})
rm -rf "$OUT/p1" "$OUT/p2"
"$HOPNET" "${common[@]}" --out "$OUT/p1" >"$OUT/p1.log" 2>&1
"$HOPNET" "${common[@]}" --out "$OUT/p2" --nproc 2 >"$OUT/p2.log" 2>&1
report "1 process" 1 "$OUT/p1/steps.csv"
report "2 processes (--nproc 2)" 2 "$OUT/p2/steps.csv"
