#!/usr/bin/env bash
# The web player's end-to-end test (docs/web.md): cooks a fixture, asks the native library for its
# answers (a decoded frame, a rendered image), then drives the page in Debian's headless Chromium
# (puppeteer-core) against nginx and against the fault-injecting server.
#   run.sh PSTREAM_CLI REFERENCE_FRAME SITE_DIR
set -euo pipefail
trap 'echo "run.sh: line $LINENO failed (exit code $?): $BASH_COMMAND" >&2' ERR
cli=$1 reference=$2 site=$(cd "$3" 2>/dev/null && pwd) || {
  echo "run.sh: no web player at $3: build it with scripts/build-web.sh" >&2
  exit 1
}
here=$(cd "$(dirname "$0")" && pwd)
data=$(cd "$here/../data" && pwd)
work=$(mktemp -d /tmp/pstream-web.XXXXXX)
trap 'rm -rf "$work"' EXIT

frame=30
camera=2.6,2.4,4.2:0,0.9,0
"$cli" cook "$data/sims/blender_sparks.abc" -o "$work/sparks.pstream" --chunk-size 64KiB -q
"$reference" "$work/sparks.pstream" $frame "$work/frame.bin"
"$cli" render "$work/sparks.pstream" --frames $frame:$((frame + 1)) --size 480x270 --camera $camera \
  --preset debug --out "$work/native" -q
native=$(ls "$work"/native/*.png)
# The looks the browser draws from the library's presets: the sparks (additive, streaked, bloom)
# and sprites coloured by speed, as the native renderer draws them.
"$cli" render "$work/sparks.pstream" --frames $frame:$((frame + 1)) --size 480x270 --camera $camera \
  --preset sparks --out "$work/native_sparks" -q
"$cli" render "$work/sparks.pstream" --frames $frame:$((frame + 1)) --size 480x270 --camera $camera \
  --color-by speed --ramp fire --ramp-range 0,4 --out "$work/native_speed" -q
# Colour by a float attribute: the sparks' age, kept in the cook, seen from nearer.
age_camera=0.9,1.3,1.5:0,1.0,0
"$cli" cook "$data/sims/blender_sparks.abc" --attributes age -o "$work/sparks_age.pstream" -q
"$cli" render "$work/sparks_age.pstream" --frames $frame:$((frame + 1)) --size 480x270 --camera $age_camera \
  --ramp-attribute age --ramp viridis --ramp-range 0,1.5 --out "$work/native_age" -q
# Self-shadowing (the smoke preset) on the FLIP pour's dense liquid, and the same without shadows.
flip_camera=1.6,1.5,2.6:0,0.35,0
"$cli" cook "$data/sims/blender_flip_pour_small.abc" -o "$work/flip.pstream" -q
# The liquid's surface over the ground grid (the backdrop "auto" gives it), the same without its
# shadow on the ground, and on the plain background; the smoke over the ground, with its shadow on
# it, and the ground alone (no opacity).
for look in "smoke:--preset smoke --backdrop none" "unshadowed:--opacity 0.55 --backdrop none" \
  "liquid:--preset liquid" "liquid_bare:--preset liquid --liquid-shadow-depth 0" \
  "liquid_none:--preset liquid --backdrop none" "smoke_ground:--preset smoke" \
  "ground:--preset smoke --opacity 0"; do
  # shellcheck disable=SC2086 # the look's flags are words
  "$cli" render "$work/flip.pstream" --frames 40 --size 480x270 --camera $flip_camera \
    ${look#*:} --out "$work/native_flip_${look%%:*}" -q
done

# A sprite image (`--texture`: a ring, green along its top row and red along its bottom one),
# near enough to see it.
texture_camera=0.5,0.55,0.9:0.15,0.2,0
"$cli" render "$work/flip.pstream" --frames 40 --size 480x270 --camera $texture_camera --preset debug \
  --texture "$data/render/sprite_ring.png" --out "$work/native_flip_texture" -q

# The native images, each checked to be there (a `$(ls ...)` inside `export` would hide a failure).
pngs=()
for image in SPARKS:native_sparks SPEED:native_speed AGE:native_age SMOKE:native_flip_smoke \
  UNSHADOWED:native_flip_unshadowed LIQUID:native_flip_liquid LIQUID_BARE:native_flip_liquid_bare \
  LIQUID_NONE:native_flip_liquid_none \
  SMOKE_GROUND:native_flip_smoke_ground GROUND:native_flip_ground TEXTURE:native_flip_texture; do
  file=$(ls "$work/${image#*:}"/*.png)
  pngs+=("WEB_NATIVE_${image%%:*}_PNG=$file")
done
export "${pngs[@]}" WEB_NATIVE_PNG="$native"
export WEB_SITE=$site WEB_CLIP=$work/sparks.pstream WEB_FRAME=$frame WEB_CAMERA=$camera \
  WEB_EMPTY_CLIP=$data/pstream/empty_frames.pstream WEB_REFERENCE=$work/frame.bin \
  WEB_AGE_CLIP=$work/sparks_age.pstream WEB_AGE_CAMERA=$age_camera WEB_FLIP_CLIP=$work/flip.pstream \
  WEB_FLIP_CAMERA=$flip_camera WEB_TEXTURE=$data/render/sprite_ring.png WEB_TEXTURE_CAMERA=$texture_camera \
  WEB_OUT=${PSTREAM_WEB_OUT:-$work}
bash "$here/../http/with_server.sh" nginx node "$here/player_test.mjs" playback
bash "$here/../http/with_server.sh" faulty node "$here/player_test.mjs" faults
