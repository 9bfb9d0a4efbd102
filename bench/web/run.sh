#!/usr/bin/env bash
# The web player's benchmark (docs/web.md): per cached frame, the worker's decode, the worker's sort
# (and packing of the drawn particles), and the page's draw, at about 100k and 1M particles, next
# to the native decoder and sorter on the same clips in the same run (one thread each, wall-clock
# medians, as performance.now() measures the page) and the native renderer drawing the same clip
# (`pstream render --preset debug --playback cpu --json`: flat sprites uploaded from the host, as
# the page draws them, at the page's 1280x720, each image's draw and read-back). Clips come
# from `pstream demo --preset explosion` (every particle born at once; the particle codec).
#   bench/web/run.sh [OUT_DIR]      prints a Markdown table; keeps the clips in OUT_DIR (default: a temporary folder)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
cli=$root/build/apps/pstream/pstream
native=$root/build/bench/pstream_bench_web_native
site=$root/build-web/site
for f in "$cli" "$native" "$site/index.html"; do
  [ -e "$f" ] || { echo "bench/web/run.sh: $f is missing: run scripts/build.sh first" >&2; exit 1; }
done
out=${1:-}
if [ -z "$out" ]; then out=$(mktemp -d /tmp/pstream-webbench.XXXXXX); trap 'rm -rf "$out"' EXIT; fi
mkdir -p "$out"

rows=()
for spec in 100000:1 1000000:0.5; do
  n=${spec%%:*} seconds=${spec##*:}
  dir=$out/demo_$n
  if [ ! -f "$dir/demo.pstream" ]; then
    echo "web bench: simulating and cooking $n particles ($seconds s at 24 fps)..." >&2
    "$cli" demo --preset explosion --particles "$n" --seconds "$seconds" --fps 24 --size 320x180 --out "$dir" \
      --headless -q >&2
    rm -f "$dir/demo.abc" "$dir"/frames/*.png
  fi
  clip=$dir/demo.pstream
  native_json=$("$native" "$clip")
  draw_json=$("$cli" render "$clip" --size 1280x720 --preset debug --playback cpu --out "$dir/native_frames" --json)
  rm -rf "$dir/native_frames"
  web_json=$(bash "$root/tests/http/with_server.sh" nginx node "$root/bench/web/bench.mjs" "$site" "$clip")
  rows+=("$native_json|$web_json|$draw_json")
done

# The liquid (the page's and the native renderer's screen-space surface over the ground grid) on
# the FLIP fixture, 48 frames of up to 7,880 particles: the draw only.
flip=$out/flip.pstream
[ -f "$flip" ] || "$cli" cook "$root/tests/data/sims/blender_flip_pour_small.abc" -o "$flip" -q
liquid_native=$("$cli" render "$flip" --size 1280x720 --preset liquid --playback cpu --out "$out/liquid_frames" --json)
rm -rf "$out/liquid_frames"
liquid_web=$(bash "$root/tests/http/with_server.sh" nginx node "$root/bench/web/bench.mjs" "$site" "$flip" liquid)

python3 - "$liquid_web|$liquid_native" "${rows[@]}" <<'PY'
import json, sys
liquid_web, liquid_native = (json.loads(x) for x in sys.argv[1].split("|", 1))
del sys.argv[1]
print("| particles (median) | stage | browser (WebAssembly, worker) | native (same run) | browser / native |")
print("|---|---|---|---|---|")
for row in sys.argv[1:]:
    n, w, render = (json.loads(x) for x in row.split("|", 2))
    def line(stage, web, nat):
        ratio = f"{web['median'] / nat['median']:.2f}x" if nat and nat['median'] > 0 else "-"
        natv = (f"{nat['median']:.2f} ms" + (f" (p95 {nat['p95']:.2f})" if nat['p95'] == nat['p95'] else "")) if nat else "-"
        print(f"| {int(w['particles']):,} | {stage} | {web['median']:.2f} ms (p95 {web['p95']:.2f}) | {natv} | {ratio} |")
    line("decode", w["decodeMs"], n["decode_ms"])
    b = w.get("backDecodeMs")
    if b:
        print(f"| {int(w['particles']):,} | decode, played backwards: a step back, each image between two frames "
              f"({w['backFramesDecoded']} frames decoded in {w['stepsBack']} steps) | {b['mean']:.2f} ms mean "
              f"(median {b['median']:.2f}, max {b['max']:.2f}) | - | - |")
    line("sort back to front + pack", w["sortMs"], n["sort_ms"])
    line("draw (the page: upload, the sprites into half floats, the composite, a pixel read back; native: the same passes and read-back)", w["drawMs"],
         render["frame_ms"])
lw, ln = liquid_web["drawMs"], liquid_native["frame_ms"]
print(f"| {int(liquid_web['particles']):,} (the FLIP fixture) | draw the liquid over the ground grid (`preset=liquid`: splats, "
      f"the depth filter's five passes, normals, the composite, spray; native: the same passes, the filter in compute) | "
      f"{lw['median']:.2f} ms (p95 {lw['p95']:.2f}) | {ln['median']:.2f} ms (p95 {ln['p95']:.2f}) | {lw['median'] / ln['median']:.2f}x |")
print()
print(f"Browser: {w.get('renderer', '?')}, canvas {w['size'][0]}x{w['size'][1]}. "
      f"Native renderer: {render['gl_renderer']}, {render['size'][0]}x{render['size'][1]}.")
PY
