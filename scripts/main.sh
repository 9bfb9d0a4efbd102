#!/usr/bin/env bash
# The main job from a fresh machine: dependencies, a release build, then `pstream info` on the
# bundled sample cache (births and deaths, sparse ids, velocities, colours, widths).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh release
build/apps/pstream/pstream info tests/data/alembic/points_varying.abc
