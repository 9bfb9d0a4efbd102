#!/usr/bin/env bash
# Runs PROGRAM DATA_DIR WORK_DIR with a fresh temporary WORK_DIR, removed afterwards.
set -euo pipefail
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$1" "$2" "$work"
