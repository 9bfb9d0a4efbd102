#!/usr/bin/env bash
# The main job from a fresh machine: dependencies, a release build, then `pstream demo`: a
# built-in fountain simulation (>= 200k particles at peak, 10 s at 30 fps) written to Alembic,
# cooked, streamed in real time, sorted and rendered headless to out/demo/ (frames, demo.mp4,
# contact_sheet.png, report.md and report.json). Extra arguments go to `pstream demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh release
build/apps/pstream/pstream demo --out out/demo --headless "$@"
