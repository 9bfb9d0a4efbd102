#!/usr/bin/env bash
# Configures and builds one flavour of the project into build/ (or build-<flavour>/).
#   scripts/build.sh            release build with tests and benchmarks
#   scripts/build.sh asan       AddressSanitizer + UndefinedBehaviorSanitizer, tests only
#   scripts/build.sh fuzz       clang + libFuzzer targets
set -euo pipefail
cd "$(dirname "$0")/.."
flavour=${1:-release}
jobs=$(nproc)
case "$flavour" in
  release) dir=build; args=(-DCMAKE_BUILD_TYPE=Release) ;;
  asan) dir=build-asan; args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPSTREAM_SANITIZE=ON -DPSTREAM_BENCH=OFF) ;;
  fuzz) dir=build-fuzz; args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPSTREAM_FUZZ=ON -DCMAKE_CXX_COMPILER=clang++) ;;
  *) echo "usage: $0 [release|asan|fuzz]" >&2; exit 2 ;;
esac
cmake -S . -B "$dir" -G Ninja "${args[@]}" >/dev/null
cmake --build "$dir" -j"$jobs"
