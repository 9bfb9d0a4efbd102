#!/usr/bin/env bash
# Builds the browser player (web/, docs/web.md) into build-web/: the format's decoder compiled
# from the same sources as the native library with Debian's Emscripten, and the page's npm
# dependencies installed from web/package-lock.json. The page is then build-web/site/.
set -euo pipefail
cd "$(dirname "$0")/.."
out=build-web
mkdir -p "$out/include" "$out/obj" "$out/site"

# Emscripten's own sysroot, plus headers from Debian, linked one by one so that no other system
# header leaks in: fmt (its compiled part is src/base/fmt_impl.cpp), xxhash (inlined), Highway (its
# WebAssembly SIMD target, chosen statically), nlohmann-json (the metadata the worker reads).
ln -sfn /usr/include/fmt "$out/include/fmt"
ln -sfn /usr/include/xxhash.h "$out/include/xxhash.h"
ln -sfn /usr/include/hwy "$out/include/hwy"
ln -sfn /usr/include/nlohmann "$out/include/nlohmann"

# The decoder's sources are the ones CMake builds the native decoder library from (one list).
decoder=$(sed -n '/set(PSTREAM_FORMAT_DECODER_SOURCES/,/)/p' src/format/CMakeLists.txt |
  sed -e 's/set(PSTREAM_FORMAT_DECODER_SOURCES//' -e 's/)//' | tr -s ' \n' '\n' | grep '\.cpp$' |
  grep -v -e '^entropy.cpp$' -e '^zstd_memory.cpp$' | sed 's|^|src/format/|')
sources=($decoder src/base/fmt_impl.cpp src/base/memory.cpp src/base/names.cpp src/base/mapped_file.cpp
  src/io/file_source.cpp src/io/http_unsupported.cpp src/sort/depth.cpp src/sort/radix_sort.cpp src/frame/camera.cpp
  src/playback/interpolate.cpp src/playback/blend_simd.cpp
  web/src/entropy_host.cpp web/src/pstream_wasm.cpp)

export NODE_PATH=/usr/share/nodejs  # emcc's JavaScript optimiser needs Debian's node modules
flags=(-std=c++20 -O3 -msimd128 -fwasm-exceptions -ffp-contract=off -Wall -Wextra -Werror
  -include web/src/compat.hpp -DXXH_INLINE_ALL -DHWY_COMPILE_ONLY_STATIC=1 -Iinclude -Isrc -I"$out/include")
objects=()
pids=()
for s in "${sources[@]}"; do
  o="$out/obj/$(echo "$s" | tr '/' '_').o"
  objects+=("$o")
  if [ ! -f "$o" ] || [ "$s" -nt "$o" ] || [ -n "$(find include src/format src/playback web/src -newer "$o" -name '*.hpp' -print -quit)" ]; then
    em++ "${flags[@]}" -c "$s" -o "$o" &
    pids+=($!)
    if [ ${#pids[@]} -ge "$(nproc)" ]; then wait "${pids[0]}"; pids=("${pids[@]:1}"); fi
  fi
done
for p in "${pids[@]}"; do wait "$p"; done
em++ -O3 -msimd128 -fwasm-exceptions "${objects[@]}" -o "$out/site/pstream.js" \
  -sENVIRONMENT=worker -sMODULARIZE=1 -sEXPORT_NAME=createDecoder -sEXPORT_ES6=1 -sALLOW_MEMORY_GROWTH=1 \
  -sINITIAL_MEMORY=64MB -sMAXIMUM_MEMORY=4GB -sFILESYSTEM=0 \
  -sEXPORTED_FUNCTIONS=_malloc,_free -sEXPORTED_RUNTIME_METHODS=UTF8ToString,stringToUTF8,lengthBytesUTF8,HEAPU8,HEAPF32

# The page and its npm dependencies (pinned by the lockfile; puppeteer-core drives the test).
if [ ! -d web/node_modules ] || [ web/package-lock.json -nt web/node_modules/.package-lock.json ]; then
  (cd web && npm ci --no-audit --no-fund --loglevel=error)
fi
cp web/index.html web/player.js web/worker.js web/style.css "$out/site/"
cp web/node_modules/zstddec/dist/zstddec-stream.mjs "$out/site/"
echo "build-web: $out/site/ (open index.html?url=CLIP from any static server with range requests)"
