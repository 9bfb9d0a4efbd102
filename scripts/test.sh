#!/usr/bin/env bash
# The whole test suite, from a fresh machine: dependencies, a -Werror release build and its
# GoogleTest suite through CTest, then one clang build with ASan+UBSan and libFuzzer's coverage
# that runs the same suite sanitized and a bounded fuzz run of every reader of untrusted bytes.
# Prints each stage's time at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc)
log=$(mktemp)
trap 'rm -f "$log"' EXIT

stages=()
stage_start=$SECONDS
stage_done() {  # label
  stages+=("$(printf '%-28s %4d s' "$1" $((SECONDS - stage_start)))")
  stage_start=$SECONDS
}

run_suite() {  # build dir, label
  echo "== $2"
  ctest --test-dir "$1" -j"$jobs" --output-on-failure --timeout 600 | tee -a "$log" | grep -vE '^ *[0-9]+/[0-9]+ Test'
}

bash scripts/install-deps.sh
stage_done "dependencies"

echo "== build (release)"
bash scripts/build.sh release
stage_done "build (release, gcc)"
run_suite build "tests (release)"
stage_done "tests (release)"

echo "== build (ASan + UBSan + libFuzzer coverage)"
bash scripts/build.sh check
stage_done "build (check, clang)"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  run_suite build-check "tests (ASan + UBSan)"
stage_done "tests (ASan + UBSan)"

bash scripts/fuzz.sh
stage_done "fuzz"

echo "== stage times"
printf '  %s\n' "${stages[@]}"
printf '  %-28s %4d s\n' "total" "$SECONDS"
passed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{t+=$NF; f+=$4} END {print t-f}')
failed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{f+=$4} END {print f}')
echo "summary: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
