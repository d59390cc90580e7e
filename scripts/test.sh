#!/usr/bin/env bash
# The whole test suite from a fresh machine: install dependencies, configure, build (ccache, -j2),
# run every test. Tests that need ../shared/reference read TOPOS_REFERENCE_DIR; this script sets
# it when that folder exists beside the checkout and the variable is unset.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
TOPOS_WITH_CHROMIUM="${TOPOS_WITH_CHROMIUM:-1}" bash scripts/setup.sh
if [ -z "${TOPOS_REFERENCE_DIR:-}" ] && [ -d "$root/../shared/reference" ]; then
  export TOPOS_REFERENCE_DIR="$root/../shared/reference"
fi
# The raw benchmark datasets (TU, DGCNN, Planetoid; the TopoBench tests), likewise.
if [ -z "${TOPOS_DATASETS_DIR:-}" ] && [ -d "$root/../shared/datasets" ]; then
  export TOPOS_DATASETS_DIR="$root/../shared/datasets"
fi
build="${TOPOS_BUILD_DIR:-$root/build}"
jobs="${TOPOS_JOBS:-2}"
# ccache: the precompiled headers are cacheable only with this sloppiness; relative paths let
# clones in other folders share hits.
export CCACHE_SLOPPINESS="${CCACHE_SLOPPINESS:-pch_defines,time_macros,include_file_mtime,include_file_ctime}"
export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$root}"
start=$(date +%s)
# Warnings are errors here (CI): the tree builds without one under -Wall -Wextra -Wpedantic.
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DTOPOS_WERROR="${TOPOS_WERROR:-ON}" >/dev/null
cmake --build "$build" -j "$jobs"
built=$(date +%s)
# Keep BLAS/OpenMP from oversubscribing the two cores while ctest runs tests in parallel.
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
ctest --test-dir "$build" --output-on-failure --no-tests=error -j "$jobs" ${TOPOS_CTEST_ARGS:-}
echo "build: $((built - start)) s, tests: $(( $(date +%s) - built )) s"
