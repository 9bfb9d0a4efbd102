#!/usr/bin/env bash
# The main job from a fresh machine: dependencies, a release build, then the pipeline so far on
# the bundled sample cache (births and deaths, sparse ids, velocities, colours, widths):
# read the Alembic file, cook it to a .pstream, describe and verify the result.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh release
pstream=build/apps/pstream/pstream
out=${OUT_DIR:-out}
mkdir -p "$out"
$pstream info tests/data/alembic/points_varying.abc
echo
$pstream cook tests/data/alembic/points_varying.abc -o "$out/points_varying.pstream" --attributes velocity,id --codec zstd
echo
$pstream info "$out/points_varying.pstream"
$pstream verify "$out/points_varying.pstream"
