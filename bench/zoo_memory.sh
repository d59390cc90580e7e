#!/usr/bin/env bash
# Peak resident memory of each zoo benchmark (bench_zoo's "peak_rss_MB"), one process per
# benchmark so that each peak is its own (it includes LibTorch and both complexes, built at start);
# before_MB is the peak before the benchmark built its model, above_MB what the model added to the
# peak (library code paged in included), anon_MB the anonymous memory (heap, tensors) it added.
# Usage: bench/zoo_memory.sh [BUILD_DIR] [FILTER_REGEX]   (default build, all BM_zoo/ benchmarks)
set -euo pipefail
build="${1:-build}"
filter="${2:-^BM_zoo/}"
bin="$build/bench/bench_zoo"
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
printf '%-45s %10s %10s %10s %10s\n' benchmark before_MB peak_MB above_MB anon_MB
for name in $("$bin" --benchmark_list_tests=true 2>/dev/null | grep -E "$filter"); do
  read -r before peak anon <<<"$("$bin" --benchmark_filter="^${name}\$" --benchmark_min_time=0.01 \
    --benchmark_format=json 2>/dev/null |
    python3 -c 'import json,sys; b=json.load(sys.stdin)["benchmarks"]; print("%.0f %.0f %.0f" % (b[0]["rss_before_MB"], b[0]["peak_rss_MB"], b[0]["anon_above_MB"]))')"
  printf '%-45s %10s %10s %10s %10s\n' "$name" "$before" "$peak" "$((peak - before))" "$anon"
done
