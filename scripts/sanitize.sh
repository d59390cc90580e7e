#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer: configures a separate build
# folder with TOPOS_SANITIZE (default address,undefined), builds the tests and the hopnet program,
# runs ctest, and prints the build and test times. Any sanitizer report fails its test.
# Usage: scripts/sanitize.sh [ctest arguments...]; TOPOS_SANITIZE_CMAKE_ARGS adds configure
# arguments (e.g. -DTOPOS_WITH_NN=OFF for the suite without LibTorch, much quicker to build);
# TOPOS_SANITIZE_TARGETS builds only some targets (e.g. topos_nn_tests, with `-L topos_nn_tests`).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
# The reference beside the checkout, or beside the folder of worktrees (/work/wt/<name>).
for ref in "$root/../shared/reference" "$root/../../shared/reference"; do
  if [ -z "${TOPOS_REFERENCE_DIR:-}" ] && [ -d "$ref" ]; then
    TOPOS_REFERENCE_DIR="$(cd "$ref" && pwd)"
    export TOPOS_REFERENCE_DIR
  fi
done
build="${TOPOS_SANITIZE_BUILD_DIR:-$root/build-sanitize}"
jobs="${TOPOS_JOBS:-2}"
start=$(date +%s)
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTOPOS_SANITIZE="${TOPOS_SANITIZE:-address,undefined}" \
  -DTOPOS_BUILD_BENCHMARKS=OFF ${TOPOS_SANITIZE_CMAKE_ARGS:-} >/dev/null
# TOPOS_SANITIZE_TARGETS: build only these (e.g. topos_nn_tests, then run with -L topos_nn_tests).
cmake --build "$build" -j "$jobs" ${TOPOS_SANITIZE_TARGETS:+--target $TOPOS_SANITIZE_TARGETS}
built=$(date +%s)
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
# Reports abort the process (a failed test); LibTorch's and OpenBLAS's own allocations held to
# exit are not the project's leaks (scripts/lsan.supp).
export ASAN_OPTIONS="${ASAN_OPTIONS:-abort_on_error=1:detect_leaks=1:strict_string_checks=1}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$root/scripts/lsan.supp:print_suppressions=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
ctest --test-dir "$build" --output-on-failure --no-tests=error -j "$jobs" "$@"
echo "sanitize: build $((built - start)) s, tests $(( $(date +%s) - built )) s"
