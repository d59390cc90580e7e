#!/usr/bin/env bash
# clang-tidy (.clang-tidy's checks) over the translation units that do not include LibTorch
# (each LibTorch one takes minutes to analyse) and, through them, the headers they include.
# Usage: scripts/tidy.sh [FILES...]   (default: the non-LibTorch tests and fuzz harnesses)
# (-std=c++17 is passed explicitly: GCC needs no flag for it, so the compile database has none,
# and clang would default to C++14.)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
TOPOS_WITH_FUZZ=1 bash scripts/setup.sh
build="${TOPOS_TIDY_BUILD_DIR:-$root/build-tidy}"
cmake -S . -B "$build" -DCMAKE_EXPORT_COMPILE_COMMANDS=ON -DTOPOS_BUILD_BENCHMARKS=OFF >/dev/null
files=("$@")
if [ ${#files[@]} -eq 0 ]; then
  files=(tests/core/*.cpp tests/data/*.cpp tests/geometry/*.cpp tests/fuzz/replay_main.cpp
         tests/fuzz/fuzz_{obj,kubric,npy,stats,split,dataset,collisions}.cpp)
fi
status=0
for f in "${files[@]}"; do
  echo "clang-tidy $f"
  clang-tidy -p "$build" --quiet --extra-arg=-std=c++17 "$f" 2>/dev/null || status=1
done
[ $status -eq 0 ] && echo "clang-tidy: clean (${#files[@]} files)"
exit $status
