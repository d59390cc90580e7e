#!/usr/bin/env bash
# The code style check (ctest code_style): every tracked C++ source formatted as .clang-format
# says, and no line over 100 columns (characters, not bytes). Exits 77 (skipped) without
# clang-format or git; scripts/setup.sh installs clang-format, so CI runs it.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v clang-format >/dev/null || ! git rev-parse --git-dir >/dev/null 2>&1; then
  echo "SKIPPED: the style check needs clang-format and a git checkout"; exit 77
fi
mapfile -t files < <(git ls-files '*.hpp' '*.cpp' '*.h')
status=0
if ! clang-format --dry-run --Werror "${files[@]}" 2>&1 | head -40; then status=1; fi
if clang-format --dry-run "${files[@]}" 2>&1 | grep -q warning; then
  echo "code style: run clang-format -i on the files above"; status=1
fi
long=$(python3 - "${files[@]}" <<'PY'
import sys
for f in sys.argv[1:]:
    for i, line in enumerate(open(f, encoding="utf-8"), 1):
        if len(line.rstrip("\n")) > 100:
            print(f"{f}:{i}: {len(line.rstrip())} columns")
PY
)
if [ -n "$long" ]; then echo "$long"; echo "code style: lines over 100 columns"; status=1; fi
# ctest splits a discovered Catch test name at ';' into names that match nothing, so such a test
# never runs: a test case's name must not hold one.
semi=$(grep -n 'TEST_CASE("[^"]*;' $(git ls-files 'tests/*.cpp') || true)
if [ -n "$semi" ]; then
  echo "$semi"; echo "code style: a test case name with ';' (ctest would never run it)"; status=1
fi
[ $status -eq 0 ] && echo "code style: ${#files[@]} files formatted, no line over 100 columns"
exit $status
