#!/usr/bin/env python3
"""Do a cache's particles keep their identity from frame to frame, and what does a frame cost if not?

For a cache without ids (a FLIP liquid, say), the particle codec pairs each frame's particles with the
previous frame's by nearest position. That only predicts well if the pairs are the same particles.
This script measures, on a few frames of one points object:

- how far each particle's nearest previous particle is, with the previous frame as it is and moved on
  along its stored velocity by 0.5 and 1 frame (a particle that persists lands on itself when moved
  by its velocity: the distance falls towards the position bound; a re-sampled one does not), and
  by the fraction of a frame, from -0.5 to 1.5, that brings them nearest (a velocity in other units
  or at another time than the position would show as a fraction other than 1), and along the
  parabola of one frame under gravity (the velocity's step plus half of gravity's, ½ g h², which
  `--gravity` sets: a falling particle that persists misses itself by that much when moved by its
  velocity alone, 8.5 mm at 24 fps);
- the particle spacing (each particle's nearest neighbour in its own frame) and the step along the
  velocity in one frame;
- the share of particles with a previous particle at exactly their position (particles at rest);
- an estimate of the frame's cost as a set of points that owes nothing to the frame before: each
  voxel of 1.5 spacings holding k of its m grid cells (the codec's grid at the default bound) costs
  about k*log2(m/k) + k*log2(e) bits. What the voxels' counts cost is left out, so the estimate is
  low.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/particle_identity.py tests/data/sims/blender_flip_pour_small.abc
"""
import argparse
import json
import math
import sys

import numpy as np

import particlestream as ps


FRACTIONS = (-0.5, -0.25, 0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)


def nearest(points, queries):
    """The distance from each query to its nearest point, by brute force in bounded chunks."""
    out = np.empty(len(queries))
    chunk = max(1, int(2e7 // max(1, len(points))))
    for s in range(0, len(queries), chunk):
        q = queries[s:s + chunk]
        d2 = ((q[:, None, :] - points[None, :, :]) ** 2).sum(-1)
        out[s:s + chunk] = np.sqrt(d2.min(1))
    return out


def spacing(points, sample):
    """Each sampled particle's distance to its nearest other particle in the same frame."""
    out = np.empty(len(sample))
    for n, i in enumerate(sample):
        d2 = ((points - points[i]) ** 2).sum(-1)
        d2[i] = np.inf
        out[n] = math.sqrt(d2.min())
    return out


def clip_grid(archive, name, error, samples=None):
    """The codec's position grid for a points object at the bound `error` (a fraction of the clip's
    bounds diagonal): its origin, the clip's least corner, and its step, twice the bound. Over the
    first `samples` samples where given (a cook of those frames alone), else all."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for t in range(archive.num_samples(name) if samples is None else samples):
        p = archive.positions(name, t)
        if len(p):
            lo, hi = np.minimum(lo, p.min(0)), np.maximum(hi, p.max(0))
    return lo, 2 * error * float(np.linalg.norm(hi - lo))


def clip_arguments(parser):
    """The arguments the scripts on a clip's positions share: the Alembic file, its points object
    and the position bound (as the cook's --error)."""
    parser.add_argument("file", help="an Alembic file")
    parser.add_argument("--object", help="the points object (default: the first)")
    parser.add_argument("--error", type=float, default=1e-4,
                        help="the position bound as a fraction of the clip's bounds diagonal (default 1e-4, the cook's)")


def set_bits(points, voxel, step):
    """Bits a particle for the frame as a set of points within voxels of side `voxel` (see above)."""
    _, counts = np.unique(np.floor(points / voxel).astype(np.int64), axis=0, return_counts=True)
    cells = (voxel / step) ** 3
    bits = np.sum(counts * np.log2(cells / counts) + counts * math.log2(math.e))
    return float(bits / len(points))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    clip_arguments(parser)
    parser.add_argument("--frames", default="", help="comma-separated frames (default: five spread over the clip)")
    parser.add_argument("--gravity", default="0,-9.81,0",
                        help="gravity in the clip's units a second squared, x,y,z (default 0,-9.81,0: "
                             "Alembic's y up, metres)")
    parser.add_argument("--sample", type=int, default=4000, help="particles measured a frame (default 4000)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()

    try:
        gravity = np.array([float(g) for g in args.gravity.split(",")])
    except ValueError:
        gravity = np.array([])
    if gravity.shape != (3,):
        parser.error(f"--gravity {args.gravity!r}: expected three numbers, x,y,z")
    archive = ps.Archive(args.file)
    name = args.object or archive.points()[0]
    samples = archive.num_samples(name)
    if samples < 2:
        sys.exit(f"{args.file}: {name} has {samples} sample(s); two or more are needed")
    _, step = clip_grid(archive, name, args.error)
    frames = [int(f) for f in args.frames.split(",") if f] or sorted({max(1, samples * k // 6) for k in range(1, 6)})
    rng = np.random.default_rng(1)
    rows = []
    for t in frames:
        if not 1 <= t < samples:
            sys.exit(f"{args.file}: frame {t} is outside 1..{samples - 1} (a frame and the one before it are needed)")
        prev = archive.positions(name, t - 1).astype(np.float64)
        cur = archive.positions(name, t).astype(np.float64)
        vel = archive.velocities(name, t - 1).astype(np.float64)
        if len(prev) == 0 or len(cur) < 2:
            continue
        dt = archive.time(name, t) - archive.time(name, t - 1)
        pick = rng.choice(len(cur), size=min(args.sample, len(cur)), replace=False)
        row = {"frame": t, "particles": len(cur)}
        queries = cur[pick]
        unmoved = nearest(prev, queries)
        row["nearest_previous"] = float(np.median(unmoved))
        if len(vel) == len(prev):
            # Moved on by fractions of a frame's velocity (0.5 and 1 among them): a particle that
            # persists lands on itself at 1; velocities in other units or at another time than the
            # positions would show as another fraction. The one that brings the particles nearest.
            moved = {k: row["nearest_previous"] if k == 0 else float(np.median(nearest(prev + k * vel * dt, queries)))
                     for k in FRACTIONS}
            row["nearest_moved_half_step"] = moved[0.5]
            row["nearest_moved_one_step"] = moved[1.0]
            ballistic = prev + vel * dt + 0.5 * gravity * dt * dt
            row["nearest_moved_ballistic"] = float(np.median(nearest(ballistic, queries)))
            row["velocity_step"] = float(np.median(np.linalg.norm(vel, axis=1)) * dt)
            best = min(moved, key=moved.get)
            row["best_fraction"], row["nearest_moved_best"] = best, moved[best]
        row["at_rest"] = float(np.mean(unmoved == 0))
        gap = float(np.median(spacing(cur, pick[:min(1000, len(pick))])))
        row["spacing"] = gap
        row["set_bits_per_particle"] = set_bits(cur, 1.5 * gap, step)
        rows.append(row)

    if args.json:
        print(json.dumps({"file": args.file, "object": name, "grid_step": step, "frames": rows}, indent=1))
        return
    print(f"{args.file} ({name}): grid step {step:.3g} (bound {args.error:g} of the diagonal), medians")
    print(f"{'frame':>5} {'particles':>9} {'spacing':>8} {'v*dt':>8} {'nearest':>8} {'moved ½':>8} {'moved 1':>8} "
          f"{'best k':>6} {'moved k':>8} {'1 + ½gh²':>8} {'at rest':>7} {'set bits':>8} {'set B/p':>7}")
    for r in rows:
        cells = [r.get(k) for k in ("spacing", "velocity_step", "nearest_previous", "nearest_moved_half_step",
                                    "nearest_moved_one_step")]
        text = " ".join(f"{c:8.4f}" if c is not None else f"{'-':>8}" for c in cells)
        k = (f"{r['best_fraction']:6.2f} {r['nearest_moved_best']:8.4f} {r['nearest_moved_ballistic']:8.4f}"
             if "best_fraction" in r else f"{'-':>6} {'-':>8} {'-':>8}")
        print(f"{r['frame']:>5} {r['particles']:>9} {text} {k} {100 * r['at_rest']:6.1f}% "
              f"{r['set_bits_per_particle']:8.2f} {r['set_bits_per_particle'] / 8:7.3f}")

if __name__ == "__main__":
    main()
