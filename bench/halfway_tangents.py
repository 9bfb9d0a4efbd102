#!/usr/bin/env python3
"""Which tangents put a clip's left-out frames back best: what the derived velocity would gain from
central differences (Catmull-Rom) over the backward ones the decoder computes.

The clip is taken every other frame (as if cooked at half the rate); each left-out frame is put back
as the cubic Hermite curve halfway between its two neighbours, with the tangents from:

- the source's stored velocities;
- the second-order backward difference over the kept frames, (3 p[f] - 4 p[f-2] + p[f-4]) / 2, what
  the particle codec's derived velocity is (docs/format.md, "Derived velocity"), falling back to one
  step, then to the stored velocity, where a particle is too young;
- the central difference, (p[f+2] - p[f-2]) / 2: Hermite through these is Catmull-Rom, and needs the
  frame after, which a decoder that hands each frame out as it decodes it does not have; backward
  where a particle is born or dies;
- the central difference at the curve's start only, the backward one at its end: what a player holding
  just the two frames could compute (the start's central difference follows from the end's backward
  one and the two positions), the parabola through f-2, f and f+2;
- none: the straight line.

Only particles present (by id) in both neighbours and the left-out frame count, and positions are the
source's floats (no quantisation), so that the tangents are all that differs. Prints the RMS distance
to the left-out frames, or JSON with --json.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/halfway_tangents.py tests/data/sims/blender_sparks.abc
"""
import argparse
import json

import numpy as np

import particlestream as ps


def hermite(p0, p1, m0, m1, t):
    t2, t3 = t * t, t * t * t
    return (2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + t) * m0 + (-2 * t3 + 3 * t2) * p1 + (t3 - t2) * m1


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("file", help="an Alembic file whose points have ids and velocities")
    parser.add_argument("--object", help="the points object (default: the first)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()
    archive = ps.Archive(args.file)
    name = args.object or archive.points()[0]
    samples = archive.num_samples(name)
    if samples < 5:
        parser.error(f"{args.file}: {name} has {samples} samples; at least 5 are needed")
    if archive.count(name, 0) and not len(archive.ids(name, 0)):
        parser.error(f"{args.file}: {name} has no ids to pair particles by")
    positions, velocities = [], []
    for s in range(samples):
        ids = archive.ids(name, s).tolist()
        p = archive.positions(name, s).astype(np.float64)
        v = archive.velocities(name, s).astype(np.float64)
        if len(v) != len(ids):
            parser.error(f"{args.file}: {name} has no velocities at sample {s}")
        positions.append(dict(zip(ids, p)))
        velocities.append(dict(zip(ids, v)))
    dt = archive.time(name, 2) - archive.time(name, 0)  # the kept frames' spacing

    def backward(c, i):
        p = positions
        if c >= 4 and i in p[c - 2] and i in p[c - 4]:
            return (3 * p[c][i] - 4 * p[c - 2][i] + p[c - 4][i]) / 2
        if c >= 2 and i in p[c - 2]:
            return p[c][i] - p[c - 2][i]
        return velocities[c][i] * dt

    def central(c, i):
        p = positions
        if c >= 2 and c + 2 < samples and i in p[c - 2] and i in p[c + 2]:
            return (p[c + 2][i] - p[c - 2][i]) / 2
        return backward(c, i)

    squared = {"stored": [], "backward": [], "central": [], "central_start": [], "linear": []}
    for a in range(0, samples - 2, 2):
        b, mid = a + 2, a + 1
        for i, pa in positions[a].items():
            if i not in positions[b] or i not in positions[mid]:
                continue
            pb, truth = positions[b][i], positions[mid][i]
            squared["linear"].append(np.sum((0.5 * (pa + pb) - truth) ** 2))
            tangents = {
                "stored": (velocities[a][i] * dt, velocities[b][i] * dt),
                "backward": (backward(a, i), backward(b, i)),
                "central": (central(a, i), central(b, i)),
                "central_start": (central(a, i), backward(b, i)),
            }
            for k, (m0, m1) in tangents.items():
                squared[k].append(np.sum((hermite(pa, pb, m0, m1, 0.5) - truth) ** 2))
    rms = {k: float(np.sqrt(np.mean(v))) if v else 0.0 for k, v in squared.items()}
    if args.json:
        print(json.dumps({"file": args.file, "object": name, "compared": len(squared["linear"]), "rms": rms}))
        return
    print(f"{args.file} ({name}): {len(squared['linear'])} particles at left-out frames")
    for k, v in rms.items():
        print(f"  {k:13s} RMS {v:.5f}")


if __name__ == "__main__":
    main()
