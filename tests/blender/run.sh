#!/usr/bin/env bash
# Runs the Blender add-on's test (test_addon.py) under Debian's Blender, headless, in a temporary
# folder it removes afterwards. PYTHONPATH must name the particlestream module's folder.
#   run.sh BLENDER
set -euo pipefail
blender=$1
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d /tmp/pstream-blender.XXXXXX)
trap 'rm -rf "$work"' EXIT
"$blender" -b --factory-startup --python-use-system-env --python-exit-code 1 \
  --python "$here/test_addon.py" -- "$work" 2>&1 | grep -v '^$'
