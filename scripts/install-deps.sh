#!/usr/bin/env bash
# Installs every build, test and benchmark dependency from Debian's packages.
# Idempotent: prints nothing and touches nothing when all packages are present.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git
  clang libclang-rt-14-dev           # libFuzzer and the sanitizer runtimes
  libgtest-dev libgmock-dev libbenchmark-dev
  libfmt-dev nlohmann-json3-dev libcli11-dev
  libxxhash-dev libzstd-dev liblz4-dev libhwy-dev
  zstd                               # the zstd command: bench/point_set_coders.py codes its streams with it
  libepoxy-dev libegl-dev libegl-mesa0 libgl1-mesa-dri libglfw3-dev libglvnd-dev libimgui-dev libstb-dev  # rendering
  ffmpeg xvfb xauth                  # MP4 output; the viewer's test under a virtual display
  libmeshoptimizer-dev libdraco-dev  # the particle codec's peers in `pstream bench codec`
  python3-dev pybind11-dev python3-numpy python3-pytest python3-venv  # the Python bindings, `pip install .`, their tests
  libcurl4-openssl-dev nginx-light   # streaming over HTTP(S); nginx serves clips to its tests
  emscripten chromium                # the web player (web/): its WebAssembly build and its headless test
  blender                            # the Blender add-on's test (blender/)
)
# npm installs the web player's pinned packages (web/package-lock.json); Node.js's own npm is
# used where it has one, Debian's otherwise.
command -v npm >/dev/null || packages+=(npm)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}"
sudo_cmd=()
[ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
