#!/usr/bin/env bash
# Builds every fuzz harness (tests/fuzz: libFuzzer + AddressSanitizer + UndefinedBehaviorSanitizer,
# clang) and runs each for SECONDS (default 60), then prints a table: harness, executions,
# exec/s, crashes. Usage: scripts/fuzz.sh [SECONDS] [HARNESS...]
# The seed corpus is built at run time from tests/fuzz/seeds, tests/fuzz/regressions and, when
# present, the real files of ../shared/reference (TOPOS_REFERENCE_DIR; never copied into the
# repository). Findings go to <build>/findings/<harness>/; minimise one with
# `<build>/fuzz/fuzz_<harness> -minimize_crash=1 -runs=10000 <file>` and add it to
# tests/fuzz/regressions/<harness>/, which the normal test suite replays.
# Fuzzers run at normal priority (TOPOS_FUZZ_NICE, default 0: at nice 19 beside a compile they
# got ~10 exec/s instead of thousands), TOPOS_FUZZ_PARALLEL (default 1) at a time.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
secs="${1:-60}"
shift || true
all=(obj kubric collisions npy checkpoint stats split dataset config tdl tu dgcnn planetoid)
harnesses=("$@")
[ ${#harnesses[@]} -eq 0 ] && harnesses=("${all[@]}")
TOPOS_WITH_FUZZ=1 bash scripts/setup.sh
build="${TOPOS_FUZZ_BUILD_DIR:-$root/build-fuzz}"
jobs="${TOPOS_JOBS:-2}"
parallel="${TOPOS_FUZZ_PARALLEL:-1}"
nice_level="${TOPOS_FUZZ_NICE:-0}"
# The reference beside the checkout, or beside the folder of worktrees (/work/wt/<name>).
for ref in "$root/../shared/reference" "$root/../../shared/reference"; do
  if [ -z "${TOPOS_REFERENCE_DIR:-}" ] && [ -d "$ref" ]; then
    TOPOS_REFERENCE_DIR="$(cd "$ref" && pwd)"
    export TOPOS_REFERENCE_DIR
  fi
done

CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTOPOS_FUZZ=ON \
  -DBUILD_TESTING=OFF -DTOPOS_BUILD_APPS=OFF -DTOPOS_BUILD_EXAMPLES=OFF \
  -DTOPOS_BUILD_BENCHMARKS=OFF >/dev/null
targets=()
for h in "${harnesses[@]}"; do targets+=("fuzz_$h"); done
cmake --build "$build" -j "$jobs" --target "${targets[@]}"

# Seed corpus: the repository's seeds and regressions, and the reference's real files.
generated="$build/seeds"
rm -rf "$generated"
mkdir -p "$generated"
python=/usr/bin/python3
[ -x "$python" ] || python=python3
if [ -n "${TOPOS_REFERENCE_DIR:-}" ]; then
  "$python" scripts/fuzz_seeds.py "$TOPOS_REFERENCE_DIR" "$generated"
else
  echo "fuzz: TOPOS_REFERENCE_DIR unset; seeding from tests/fuzz only"
fi

run_one() {
  local h="$1" corpus="$build/corpus/$1" findings="$build/findings/$1"
  mkdir -p "$corpus" "$findings"
  for src in tests/fuzz/seeds/"$h" tests/fuzz/regressions/"$h" "$generated/$h"; do
    [ -d "$src" ] && find "$src" -maxdepth 1 -type f -exec cp -f {} "$corpus/" \;
  done
  # -malloc_limit_mb: an allocation above it is a finding (a size taken from the input unchecked).
  nice -n "$nice_level" "$build/fuzz/fuzz_$h" "$corpus" -max_total_time="$secs" -timeout=25 \
    -rss_limit_mb=2048 -malloc_limit_mb=512 -max_len=65536 -print_final_stats=1 \
    -artifact_prefix="$findings/" >"$build/fuzz-$h.log" 2>&1 || true
}

# Findings of earlier runs stay in findings/ (to minimise and keep); the table counts this run's.
stamp="$build/.fuzz-run-start"
touch "$stamp"
pids=()
for h in "${harnesses[@]}"; do
  run_one "$h" &
  pids+=($!)
  if [ ${#pids[@]} -ge "$parallel" ]; then
    wait "${pids[0]}"
    pids=("${pids[@]:1}")
  fi
done
wait

printf '%-12s %14s %10s %8s\n' harness executions exec/s crashes
status=0
for h in "${harnesses[@]}"; do
  log="$build/fuzz-$h.log"
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  crashes=$(find "$build/findings/$h" -maxdepth 1 -type f -newer "$stamp" \( -name 'crash-*' -o -name 'leak-*' -o -name 'timeout-*' -o -name 'oom-*' \) | wc -l)
  printf '%-12s %14s %10s %8s\n' "$h" "${execs:-?}" "${rate:-?}" "$crashes"
  [ "$crashes" -eq 0 ] || status=1
done
[ $status -eq 0 ] || echo "findings in $build/findings/ (logs: $build/fuzz-<harness>.log)"
exit $status
