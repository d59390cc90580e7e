#!/bin/bash
# A user's compile time: each example's translation unit against a plain LibTorch one that trains
# an MLP (bench/plain_libtorch_tu.cpp), compiled with the flags CMake gives the example (read from
# BUILD's flags.make: -O3, topos's include paths, compiled topos::nn), no compiler cache, one
# compiler at a time, in interleaved rounds (plain, example, ...), user CPU seconds. Prints every
# round and the median per unit with its ratio to the plain unit's median (docs/benchmarks.md,
# "A user's translation unit"). The machine is shared: compare only figures of one run.
#   bash bench/compile_time.sh build 3 custom_backbone sheaf_diffusion
set -euo pipefail
build=${1:?usage: compile_time.sh BUILD_DIR [ROUNDS] [EXAMPLE...]}
rounds=${2:-3}
shift $(($# >= 2 ? 2 : 1))
examples=("$@")
[ ${#examples[@]} -gt 0 ] || examples=(custom_backbone)
root=$(cd "$(dirname "$0")/.." && pwd)
flags_of() {  # the compile flags of example target $1
  local f="$build/examples/CMakeFiles/$1.dir/flags.make"
  [ -f "$f" ] || { echo "compile_time.sh: $f not found (configure $build with the examples)" >&2; exit 1; }
  sed -n 's/^CXX_\(DEFINES\|INCLUDES\|FLAGS\) = //p' "$f" | tr '\n' ' '
}
cxx=${CXX:-c++}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
timed() {  # user seconds of compiling $1 with flags $2
  /usr/bin/time -f %U -o "$out/t" $cxx $2 -std=gnu++17 -c "$1" -o "$out/o.o"
  cat "$out/t"
}
plain_flags=$(flags_of "${examples[0]}")
declare -A times
for ((r = 1; r <= rounds; ++r)); do
  t=$(timed "$root/bench/plain_libtorch_tu.cpp" "$plain_flags")
  times[plain]+="$t "
  echo "round $r: plain LibTorch TU ${t} s"
  for e in "${examples[@]}"; do
    t=$(timed "$root/examples/$e.cpp" "$(flags_of "$e")")
    times[$e]+="$t "
    echo "round $r: $e ${t} s"
  done
done
median() { tr ' ' '\n' | grep . | sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
p=$(echo "${times[plain]}" | median)
echo "median: plain LibTorch TU $p s (${times[plain]% })"
for e in "${examples[@]}"; do
  m=$(echo "${times[$e]}" | median)
  echo "median: $e $m s (${times[$e]% }), $(awk -v a="$m" -v b="$p" 'BEGIN {printf "%.2f", a / b}')x the plain TU"
done
