#!/usr/bin/env bash
# The whole test suite, from a fresh machine: dependencies, a -Werror release build and its
# GoogleTest suite through CTest, then one clang build with ASan+UBSan and libFuzzer's coverage
# that runs the same suite sanitized and a bounded fuzz run of every reader of untrusted bytes.
# Prints each stage's time at the end.
#
# Two jobs run beside a test suite, on the CPU it leaves idle (its tests wait on servers, browsers,
# timers and one another: about 90 core-seconds in the release suite and 120 in the sanitized one
# on 2 cores):
#   - the sanitized build, beside the release tests, in the idle scheduling class (`chrt --idle`):
#     it gets a core only when no test wants it. The tests still run slower beside it (224 s
#     alone, about 310 s beside it on the project's machine: its two vCPUs share one core's
#     caches), but the build is two-thirds done when they end: about 85 s less in all;
#   - the fuzz targets, beside the sanitized tests, at nice 19. They are bounded by inputs run,
#     not seconds, so they fuzz as much as alone; an input may take 120 s before it counts as a
#     hang, because a niced fuzzer can wait for a core.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc)
log=$(mktemp)
check_log=$(mktemp)
fuzz_log=$(mktemp)
source scripts/background.sh  # a job beside a suite
trap 'stop_background; rm -f "$log" "$check_log" "$fuzz_log"' EXIT

stages=()
stage_start=$SECONDS
stage_done() {  # label
  stages+=("$(printf '%-32s %4d s' "$1" $((SECONDS - stage_start)))")
  stage_start=$SECONDS
}

run_suite() {  # build dir, label
  echo "== $2"
  local rc=0
  ctest --test-dir "$1" -j"$jobs" --output-on-failure --timeout 600 | tee -a "$log" |
    grep -vE '^ *[0-9]+/[0-9]+ Test' || rc=$?
  [ "$rc" -eq 0 ] && return
  # Each failed test's output again, at the end, where whoever reads only the log's tail sees it
  # (--output-on-failure printed it when the test ended, among the others).
  local temporary="$1/Testing/Temporary"
  cut -d: -f2 "$temporary/LastTestsFailed.log" 2>/dev/null | while read -r name; do
    echo "== $name failed: its output again"
    awk -v test="$name" '$0 ~ "^[0-9]+/[0-9]+ Test: " test "$" { on = 1; next }
      on && /^<end of output>$/ { exit } on' "$temporary/LastTest.log" >"$log.failed"
    grep -m 20 -E 'FAIL|[Ee]rror|failed|Failure' "$log.failed" || true  # what went wrong first
    echo "-- its last lines"
    tail -n 40 "$log.failed"
  done
  rm -f "$log.failed"
  exit "$rc"
}

bash scripts/install-deps.sh
stage_done "dependencies"

echo "== build (release)"
bash scripts/build.sh release
stage_done "build (release, gcc)"

start_background "$check_log" chrt --idle 0 bash scripts/build.sh check
run_suite build "tests (release; the check build beside them)"
stage_done "tests (release)"
echo "== build (ASan + UBSan + libFuzzer coverage; begun beside the release tests)"
finish_background "build (check)"
stage_done "build (check, clang): the rest"

start_background "$fuzz_log" env FUZZ_LANES=4 FUZZ_TIMEOUT=120 nice -n 19 bash scripts/fuzz.sh
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  run_suite build-check "tests (ASan + UBSan; the fuzz targets beside them)"
stage_done "tests (ASan + UBSan)"
echo "== fuzz (begun beside the sanitized tests)"
finish_background "fuzz"
stage_done "fuzz: the rest"

echo "== stage times"
printf '  %s\n' "${stages[@]}"
printf '  %-32s %4d s\n' "total" "$SECONDS"
passed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{t+=$NF; f+=$4} END {print t-f}')
failed=$(grep -oE '[0-9]+% tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | awk '{f+=$4} END {print f}')
echo "summary: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
