#!/usr/bin/env bash
# bench/flip_pour_scene.py at the fixture's resolution (40) against the fixture it rebuilds
# (tests/data/sims/blender_flip_pour_small.abc), in a temporary folder it removes afterwards.
# PYTHONPATH must name the particlestream module's folder.
#   flip_pour_scene.sh BLENDER PYTHON
set -euo pipefail
blender=$1
python=$2
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d /tmp/pstream-flip-scene.XXXXXX)
trap 'rm -rf "$work"' EXIT
"$blender" -b --factory-startup --python-exit-code 1 --python "$here/../../bench/flip_pour_scene.py" -- \
  --resolution 40 --out "$work/pour" >"$work/blender.log" 2>&1 || { tail -n 30 "$work/blender.log"; exit 1; }
grep '^flip_pour_scene:' "$work/blender.log"
"$python" - "$work" "$here/../data/sims/blender_flip_pour_small.abc" <<'PY'
import os
import sys

import numpy as np

import particlestream as ps

work, fixture = sys.argv[1], sys.argv[2]
archive = ps.Archive(fixture)
name = archive.points()[0]
frames = []
for f in range(1, 49):
    data = open(os.path.join(work, "pour", f"frame.{f:04d}.ply"), "rb").read()
    head = data.index(b"end_header\n") + len(b"end_header\n")
    frames.append(np.frombuffer(data[head:], dtype="<f4").reshape(-1, 4))
# The inflow's first 13 frames seed about 116 particles each, the same counts as the fixture's; the
# solver's randomness then lets them drift a little.
counts = [len(f) for f in frames]
expected = [len(archive.positions(name, t)) for t in range(48)]
assert counts[:13] == expected[:13] and counts[0] == 116, (counts[:13], expected[:13])
assert abs(counts[-1] - expected[-1]) < 0.03 * expected[-1], (counts[-1], expected[-1])
# The same scene: the bounds of every frame's particles within a cell (0.05 m) of the fixture's,
# and the fixture's sizes (its widths are diameters: the radius is half).
for t in (0, 12, 47):
    ours, theirs = frames[t][:, :3], archive.positions(name, t)
    assert np.abs(ours.min(0) - theirs.min(0)).max() < 0.05 and np.abs(ours.max(0) - theirs.max(0)).max() < 0.05, t
assert np.all(frames[0][:, 3] == np.float32(0.08746856451034546 / 2))
# And the same size cooked, positions and sizes alone, within 3 %.
sizes = {}
for label, source in (("scene", os.path.join(work, "pour", "frame.0001.ply")), ("fixture", fixture)):
    report = ps.cook(source, os.path.join(work, f"{label}.pstream"), fps=24, velocity=False, color_from="none")
    sizes[label] = report["file_bytes"] / report["particles"]
print(f"counts {counts[0]}..{counts[-1]} (fixture {expected[0]}..{expected[-1]}); bytes a particle: "
      f"scene {sizes['scene']:.3f}, fixture {sizes['fixture']:.3f}")
assert abs(sizes["scene"] / sizes["fixture"] - 1) < 0.03, sizes
PY
