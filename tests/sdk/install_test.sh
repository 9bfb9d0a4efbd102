#!/usr/bin/env bash
# The installed SDK as a user gets it: install the build into a temporary prefix, then build the
# C example against it with find_package(ParticleStream) and with pkg-config, run both on a clip
# (the same output), check that libparticlestream exports only pstream_* functions, and that
# the C API test uses every function the header declares.
#   install_test.sh BUILD_DIR SOURCE_DIR PSTREAM_CLI
set -euo pipefail
build=$1 source=$2 cli=$3
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
prefix=$work/prefix

cmake --install "$build" --prefix "$prefix" --component Runtime >/dev/null
cmake --install "$build" --prefix "$prefix" --component Development >/dev/null
# Everything under the prefix, the Python module too (it used to go to the system's dist-packages).
cmake --install "$build" --prefix "$prefix" --component Python >/dev/null
outside=$(cat "$build"/install_manifest*.txt | grep -v "^$prefix/" || true)
[ -z "$outside" ] || { echo "installed outside the prefix $prefix:"; echo "$outside"; exit 1; }
module=$(find "$prefix" -name 'particlestream*.so' -path '*site-packages*' | head -1)
[ -n "$module" ] || { echo "the Python module is not under $prefix"; find "$prefix"; exit 1; }
[ -f "$(dirname "$module")/particlestream.pyi" ] || { echo "the type stubs are not beside the module"; exit 1; }
PYTHONPATH=$(dirname "$module") /usr/bin/python3 -c 'import particlestream; print("python module from the prefix:", particlestream.__file__)'
lib=$(find "$prefix" -name libparticlestream.so.0 | head -1)
[ -n "$lib" ] || { echo "libparticlestream.so.0 not installed under $prefix"; find "$prefix"; exit 1; }
libdir=$(dirname "$lib")
[ -f "$prefix/include/particlestream/particlestream.h" ] || { echo "header not installed"; exit 1; }

# Only the API is exported.
exported=$(nm -D --defined-only "$lib" | awk '$2 == "T" || $2 == "W" || $2 == "D" || $2 == "B" || $2 == "R" {sub(/@.*/, "", $3); print $3}')
others=$(echo "$exported" | grep -v '^pstream_' || true)
if [ -n "$others" ]; then echo "exported besides the API:"; echo "$others" | head -20; exit 1; fi
declared=$(grep -oE 'PSTREAM_API [^;]*\b(pstream_[a-z_]+)\(' "$source/include/particlestream/particlestream.h" |
           grep -oE 'pstream_[a-z_]+\($' | tr -d '(' | sort -u)
[ "$(echo "$exported" | sort -u)" = "$declared" ] || {
  echo "exported and declared differ:"; diff <(echo "$exported" | sort -u) <(echo "$declared"); exit 1; }
# The C API test calls each of them.
for f in $declared; do
  grep -q "\b$f(" "$source/tests/sdk/every_function.c" "$source/tests/sdk/check.h" ||
    { echo "tests/sdk/every_function.c never calls $f"; exit 1; }
done
echo "exports: $(echo "$declared" | wc -l) pstream_* functions, nothing else"

# A clip to play.
"$cli" cook "$source/tests/data/alembic/points_varying.abc" --attributes velocity,id -o "$work/clip.pstream" -q

# find_package: the C examples and the C++ one
cmake -S "$source/examples/c" -B "$work/cmake-build" -DCMAKE_PREFIX_PATH="$prefix" >/dev/null
cmake --build "$work/cmake-build" >/dev/null
LD_LIBRARY_PATH=$libdir "$work/cmake-build/play_clip" "$work/clip.pstream" >"$work/cmake.out"
cmake -S "$source/examples/cpp" -B "$work/cmake-build-cpp" -DCMAKE_PREFIX_PATH="$prefix" >/dev/null
cmake --build "$work/cmake-build-cpp" >/dev/null
LD_LIBRARY_PATH=$libdir "$work/cmake-build-cpp/play_clip_cpp" "$work/clip.pstream" >"$work/cmake-cpp.out"
# The exporter's loop (a Spool): its clip holds every frame it handed over, and its temporary is gone.
mkdir "$work/export"
LD_LIBRARY_PATH=$libdir "$work/cmake-build-cpp/export_sim" "$work/export/fountain.pstream" >"$work/export.out"
grep -q '^48 frames, 43800 particles' "$work/export.out" || { echo "export_sim:"; cat "$work/export.out"; exit 1; }
grep -q '^read back: 48 frames at 24 fps, at most 1200 particles a frame' "$work/export.out" ||
  { echo "export_sim:"; cat "$work/export.out"; exit 1; }
[ "$(ls -A "$work/export")" = "fountain.pstream" ] || { echo "export_sim left: $(ls -A "$work/export")"; exit 1; }

# pkg-config: the same sources
pc() { PKG_CONFIG_PATH=$libdir/pkgconfig pkg-config "$@"; }
cc -std=c99 -Wall -Wextra -Werror -pedantic "$source/examples/c/play_clip.c" $(pc --cflags --libs particlestream) \
  -o "$work/play_clip_pc"
LD_LIBRARY_PATH=$libdir "$work/play_clip_pc" "$work/clip.pstream" >"$work/pc.out"
c++ -std=c++20 -Wall -Wextra -Werror -pedantic "$source/examples/cpp/play_clip.cpp" \
  $(pc --cflags --libs particlestream) -o "$work/play_clip_cpp_pc"
LD_LIBRARY_PATH=$libdir "$work/play_clip_cpp_pc" "$work/clip.pstream" >"$work/pc-cpp.out"
cc -std=c99 -Wall -Wextra -Werror -pedantic "$source/examples/c/view_clip.c" \
  $(pc --cflags --libs particlestream glfw3 gl) -lm -o "$work/view_clip_pc"

# docs/embedding.md's pkg-config route verbatim, in a clean shell (no LD_LIBRARY_PATH): the .pc
# file's rpath finds the library.
(
  cd "$source"
  env -i HOME="$work" PATH=/usr/bin:/bin PREFIX="$prefix" CLIP="$work/clip.pstream" OUT="$work" bash -euc '
    export PKG_CONFIG_PATH="$PREFIX/lib/pkgconfig"
    cc -std=c99 examples/c/play_clip.c $(pkg-config --cflags --libs particlestream) -o "$OUT/play_clip"
    "$OUT/play_clip" "$CLIP" > "$OUT/docs-c.out"
    c++ -std=c++20 examples/cpp/play_clip.cpp $(pkg-config --cflags --libs particlestream) -o "$OUT/play_clip_cpp"
    "$OUT/play_clip_cpp" "$CLIP" > "$OUT/docs-cpp.out"'
)
for out in docs-c.out docs-cpp.out; do cmp "$work/cmake.out" "$work/$out"; done
echo "docs/embedding.md's pkg-config route, verbatim in a clean shell: both examples run, no LD_LIBRARY_PATH"

# The C and C++ API give the same frames, whichever way the examples were built.
for out in pc.out cmake-cpp.out pc-cpp.out; do cmp "$work/cmake.out" "$work/$out"; done
lines=$(wc -l <"$work/pc.out")
[ "$lines" -ge 100 ] || { echo "the example played $lines host frames"; exit 1; }
awk '$3 > 0 {drawn++} END {exit !(drawn > NR / 2)}' "$work/pc.out" || { echo "most host frames without particles"; exit 1; }
echo "the C and C++ examples built with find_package and with pkg-config played $lines host frames, the same"

# The window loop under a virtual display: 90 host frames, then a screenshot with particles in it.
[ -x "$work/cmake-build/view_clip" ] || { echo "view_clip was not built with find_package (GLFW?)"; exit 1; }
for viewer in "$work/cmake-build/view_clip" "$work/view_clip_pc"; do
  LD_LIBRARY_PATH=$libdir xvfb-run -a -s "-screen 0 1280x720x24" "$viewer" "$work/clip.pstream" --frames 90 \
    --screenshot "$work/view.ppm" >"$work/view.out"
  grep -q "played 90 host frames" "$work/view.out"
  # Pixels brighter than the background (0.05, 0.06, 0.08): the points drawn.
  lit=$(tail -c +16 "$work/view.ppm" | od -An -v -tu1 -w3 | awk '$1 + $2 + $3 > 120 {n++} END {print n + 0}')
  [ "$lit" -ge 200 ] || { echo "$viewer: only $lit lit pixels in its last frame"; exit 1; }
  echo "$(basename "$viewer"): 90 frames in a GLFW window, $lit lit pixels in the last"
done
