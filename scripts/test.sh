#!/usr/bin/env bash
# The whole test suite, from a fresh machine: dependencies, a -Werror release build and its
# GoogleTest suite through CTest, the same suite under ASan+UBSan, and a bounded fuzz run.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
jobs=$(nproc)
log=$(mktemp)
trap 'rm -f "$log"' EXIT

run_suite() {  # build dir, label
  echo "== $2"
  ctest --test-dir "$1" -j"$jobs" --output-on-failure --timeout 600 | tee -a "$log" | grep -vE '^ *[0-9]+/[0-9]+ Test' 
}

echo "== build (release)"
bash scripts/build.sh release
run_suite build "tests (release)"

echo "== build (ASan + UBSan)"
bash scripts/build.sh asan
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  run_suite build-asan "tests (ASan + UBSan)"

echo "== build (libFuzzer)"
bash scripts/build.sh fuzz
bash scripts/fuzz.sh

passed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{t+=$NF; f+=$4} END {print t-f}')
failed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{f+=$4} END {print f}')
echo "summary: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
