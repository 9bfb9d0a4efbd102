#!/usr/bin/env bash
# Bounded libFuzzer run of every reader of untrusted bytes, seeded with the test fixtures.
#   By default each target runs a fixed number of inputs, about 25 s of one core each on the
#   project's 2-core machine (runs, not seconds: the test command runs this beside the sanitized
#   suite, on the CPU the suite leaves idle, and a bound in seconds would then fuzz less).
#   FUZZ_SECONDS=1800 runs each target for that long instead (the long runs in docs/reliability.md).
#   FUZZ_TARGETS="fuzz_pstream fuzz_ply" runs only those.
#   FUZZ_LANES targets at a time (default: one per core); each one's report is printed when it ends.
#   FUZZ_TIMEOUT: seconds one input may take before it counts as a hang (default 10).
# Expects `scripts/build.sh check` to have built build-check/.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${FUZZ_SECONDS:-}
input_timeout=${FUZZ_TIMEOUT:-10}
# Inputs per target: what each ran in 25 s on one core in the test command before (CI of 63b9425).
declare -A runs=([fuzz_alembic]=25000 [fuzz_pstream]=36000 [fuzz_particle]=120000 [fuzz_ply]=500000)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

targets=()
add_target() {  # name, seed files...: its corpus, filled now; run below
  local name=$1; shift
  if [[ -n ${FUZZ_TARGETS:-} && " $FUZZ_TARGETS " != *" $name "* ]]; then return 0; fi
  mkdir -p "$work/$name"
  cp "$@" "$work/$name/"
  targets+=("$name")
}

run_target() {  # name
  local name=$1 corpus="$work/$1"
  local bound
  if [ -n "$seconds" ]; then
    bound=(-max_total_time="$seconds")
    echo "fuzz: $name for ${seconds}s from $(find "$corpus" -type f | wc -l) seeds"
  else
    # The wall-clock cap only stops a machine far slower than ours from running on.
    bound=(-runs="${runs[$name]}" -max_total_time=1200)
    echo "fuzz: $name, ${runs[$name]} inputs from $(find "$corpus" -type f | wc -l) seeds"
  fi
  # Crash reproducers land in the work directory; libFuzzer exits non-zero on any finding.
  if ! "build-check/tests/fuzz/$name" "$corpus" "${bound[@]}" -max_len=1048576 -timeout="$input_timeout" \
      -rss_limit_mb=2048 -artifact_prefix="$work/" -print_final_stats=1 >"$work/$name.log" 2>&1; then
    tail -n 60 "$work/$name.log"
    mkdir -p fuzz-findings && cp "$work"/crash-* "$work"/timeout-* "$work"/oom-* fuzz-findings/ 2>/dev/null || true
    echo "fuzz: $name FAILED (reproducers in fuzz-findings/)"
    return 1
  fi
  grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "$work/$name.log" | sed 's/^/  /'
  echo "  $(grep -cE '^#[0-9]+.*(NEW|REDUCE)' "$work/$name.log") new or smaller inputs kept"
}

seeds=$(find tests/data/alembic -name '*.abc' -size -1024k | sort)
# shellcheck disable=SC2086
add_target fuzz_alembic $seeds

# .pstream seeds: small fixtures cooked with each codec and the smallest chunks.
mkdir -p "$work/pstream-seeds"
for codec in raw lz4 zstd particle particle-lossless; do
  for fixture in points_widths_constant points_empty_frames; do
    build-check/apps/pstream/pstream cook -q "tests/data/alembic/$fixture.abc" --chunk-size 64KiB --codec $codec \
      --attributes velocity,id -o "$work/pstream-seeds/$fixture-$codec.pstream" 2>/dev/null ||
      build-check/apps/pstream/pstream cook -q "tests/data/alembic/$fixture.abc" --chunk-size 64KiB --codec $codec \
        -o "$work/pstream-seeds/$fixture-$codec.pstream"
  done
done
# Keyframes linked to the frame before (version 6, id order): the sparks' first 12 frames, a keyframe every 4.
build-check/apps/pstream/pstream cook -q tests/data/sims/blender_sparks.abc --frames 0:12 --keyframe-interval 4 \
  -o "$work/pstream-seeds/sparks-linked-keyframes.pstream"
# and the committed clips: version 1, 2 and 3 (a relative scale word), records and particle codec.
add_target fuzz_pstream "$work"/pstream-seeds/*.pstream tests/data/pstream/*.pstream tests/data/pstream_v1/*.pstream

# Particle-codec bodies, from the encoder itself.
mkdir -p "$work/particle-seeds"
build-check/tests/fuzz/fuzz_particle_seeds "$work/particle-seeds"
add_target fuzz_particle "$work"/particle-seeds/*

# PLY files: the test suite's sequences and a few written here (ascii, binary, with faces after).
mkdir -p "$work/ply-seeds"
printf 'ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float pscale\nend_header\n0 1 2 0.1\n3 4 5 0.2\n' >"$work/ply-seeds/ascii.ply"
printf 'ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty double z\nproperty uchar red\nend_header\n0123456789abcdefg' >"$work/ply-seeds/binary.ply"
printf 'ply\nformat ascii 1.0\nelement vertex 1\nproperty int x\nproperty short y\nproperty uint z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3\n3 0 0 0\n' >"$work/ply-seeds/faces.ply"
cp tests/fuzz/ply_regressions/* "$work/ply-seeds/"  # inputs that once failed, kept as seeds
add_target fuzz_ply "$work"/ply-seeds/*

# FUZZ_LANES targets at a time; any failure fails the run, after all have ended.
lanes=${FUZZ_LANES:-$(nproc)}
failed=0
running=0
for name in "${targets[@]}"; do
  if [ "$running" -ge "$lanes" ]; then
    wait -n || failed=1
    running=$((running - 1))
  fi
  (
    rc=0
    run_target "$name" >"$work/$name.report" 2>&1 || rc=$?
    cat "$work/$name.report"
    exit "$rc"
  ) &
  running=$((running + 1))
done
while [ "$running" -gt 0 ]; do
  wait -n || failed=1
  running=$((running - 1))
done
exit "$failed"
