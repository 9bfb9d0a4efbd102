#!/usr/bin/env bash
# Configures and builds one flavour of the project into build/ (or build-<flavour>/).
#   scripts/build.sh            release build with tests and benchmarks, and the web player
#                               (scripts/build-web.sh, into build-web/site)
#   scripts/build.sh check      clang, AddressSanitizer + UndefinedBehaviorSanitizer + libFuzzer's
#                               coverage: the sanitized test suite and the fuzz targets, one build
#                               (into build-check/; `asan` and `fuzz` are other names for it)
#   scripts/build.sh tsan       clang, ThreadSanitizer (into build-tsan/): not part of the test
#                               command; docs/reliability.md says how to run it and what it found
set -euo pipefail
cd "$(dirname "$0")/.."
flavour=${1:-release}
jobs=$(nproc)
case "$flavour" in
  release) dir=build; args=(-DCMAKE_BUILD_TYPE=Release) ;;
  check | asan | fuzz)
    # Line tables only: the sanitizers' reports name file and line at a fraction of full debug
    # information's compile and link time.
    dir=build-check
    args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPSTREAM_FUZZ=ON -DPSTREAM_BENCH=OFF -DCMAKE_C_COMPILER=clang
      -DCMAKE_CXX_COMPILER=clang++ "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O2 -gline-tables-only -DNDEBUG"
      "-DCMAKE_C_FLAGS_RELWITHDEBINFO=-O2 -gline-tables-only -DNDEBUG") ;;
  tsan)
    dir=build-tsan
    args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPSTREAM_SANITIZE=ON -DPSTREAM_SANITIZERS=thread -DPSTREAM_BENCH=OFF
      -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g -DNDEBUG"
      "-DCMAKE_C_FLAGS_RELWITHDEBINFO=-O1 -g -DNDEBUG") ;;
  *) echo "usage: $0 [release|check|tsan]" >&2; exit 2 ;;
esac
# The web player (web/, docs/web.md) with the release build: its test runs in that suite. It needs
# none of the native build, so it runs beside it in the idle scheduling class, on the CPU that
# the native build's serial steps (its links, its last big files) leave idle.
source scripts/background.sh
web_log=""
if [ "$flavour" = release ]; then
  web_log=$(mktemp)
  trap 'stop_background; rm -f "$web_log"' EXIT
  start_background "$web_log" chrt --idle 0 bash scripts/build-web.sh
fi
cmake -S . -B "$dir" -G Ninja "${args[@]}" >/dev/null
cmake --build "$dir" -j"$jobs"
if [ -n "$background" ]; then finish_background "build-web.sh"; fi
