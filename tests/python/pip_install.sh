#!/usr/bin/env bash
# `pip install .` as docs/embedding.md gives it, in a fresh virtual environment (Debian's python3
# with its numpy visible: --system-site-packages; --no-index: nothing from PyPI), reusing the
# release build's folder; then the bindings' pytest suite against the installed module, with no
# PYTHONPATH, and a check that it is the venv's copy that was imported.
#   pip_install.sh PYTHON BUILD_DIR
set -euo pipefail
python=$1 build=$2
root=$(cd "$(dirname "$0")/../.." && pwd)
work=$(mktemp -d /tmp/pstream-pip.XXXXXX)
trap 'rm -rf "$work"' EXIT
"$python" -m venv --system-site-packages "$work/venv"
(cd "$root" && "$work/venv/bin/pip" install --quiet --no-index --config-settings "build-dir=$build" .)
"$work/venv/bin/pip" show particlestream | grep -E '^(Name|Version|Location):'
unset PYTHONPATH
where=$("$work/venv/bin/python" -c 'import particlestream, sys; print(particlestream.__file__)')
case $where in
  "$work"/venv/*) echo "imported from the venv: $where" ;;
  *) echo "pip_install.sh: particlestream was imported from $where, not from the venv" >&2; exit 1 ;;
esac
[ -f "$(dirname "$where")/particlestream.pyi" ] || { echo "pip_install.sh: no type stubs beside the module" >&2; exit 1; }
cd "$work"
"$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$root/tests/python/test_particlestream.py"
"$work/venv/bin/pip" uninstall --quiet --yes particlestream
if "$work/venv/bin/python" -c 'import particlestream' 2>/dev/null; then
  echo "pip_install.sh: particlestream still imports after pip uninstall" >&2
  exit 1
fi
echo "pip uninstall removed it"
