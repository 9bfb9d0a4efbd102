#!/usr/bin/env python3
"""Would predicting a cache's particles along the local flow make its frames cheaper to code?

The particle codec predicts a particle without id from the previous frame's particle it is paired
with. This script models that over a whole clip, with the previous frame's particles first moved
by one of these predictions, and then paired closest first with the current frame's (each current
particle's 6 nearest, within --reach), as the codec's matching does:

- previous: where each was (the codec's prediction where the linear one does not pay);
- linear: moved on by its own last step over the model's pairing;
- flow: moved by the mean last step of the previous particles within --radius (a local flow that
  a decoder could compute from the frames it holds);
- flow of stored velocity: moved by the mean stored velocity within --radius over one frame (an
  oracle: a decoder does not hold the velocities, so an encoder would have to send this flow);
- stored velocity: moved by its own stored velocity over one frame.

A paired particle costs the empirical entropy of its residuals on the codec's grid, axis by axis
(the default bound: 1e-4 of the clip's bounds diagonal), an unpaired one --new-bits (about what a
new particle costs the codec on the FLIP fixture). The model leaves out the codec's per-block bias,
its leftovers' pairing and zstd, so compare the predictions with each other, not with a cook.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/flow_prediction.py tests/data/sims/blender_flip_pour_small.abc
"""
import argparse
import json

import numpy as np

import particlestream as ps
from particle_identity import clip_arguments, clip_grid  # bench/, beside this script

PREDICTIONS = ("previous", "linear", "flow", "flow of stored velocity", "stored velocity")


def squared_distances(a, b):
    """Every squared distance from a's points to b's, as a len(a) x len(b) matrix."""
    return np.maximum((a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T, 0.0)


def pair(predicted, current, reach):
    """Closest-first pairs among each current particle's 6 nearest predicted ones within `reach`:
    for each current particle, the index of its predicted particle or -1."""
    k = min(6, len(predicted))
    rows, cols, dist = [], [], []
    for s in range(0, len(current), 2048):
        d2 = squared_distances(current[s:s + 2048], predicted)
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        rows.append(np.repeat(np.arange(s, s + len(near)), k))
        cols.append(near.ravel())
        dist.append(np.take_along_axis(d2, near, 1).ravel())
    rows, cols, dist = np.concatenate(rows), np.concatenate(cols), np.concatenate(dist)
    keep = dist <= reach * reach
    rows, cols, dist = rows[keep], cols[keep], dist[keep]
    match = np.full(len(current), -1)
    taken = np.zeros(len(predicted), bool)
    for i in np.argsort(dist, kind="stable"):
        if match[rows[i]] < 0 and not taken[cols[i]]:
            match[rows[i]] = cols[i]
            taken[cols[i]] = True
    return match


def local_mean(points, values, radius):
    """The mean of `values` over the points within `radius` of each point (itself included)."""
    out = np.empty_like(values)
    for s in range(0, len(points), 2048):
        w = (squared_distances(points[s:s + 2048], points) <= radius * radius).astype(float)
        out[s:s + 2048] = (w @ values) / w.sum(1, keepdims=True)
    return out


def entropy_bits(values):
    """The empirical entropy of integer values, in bits over all of them."""
    _, counts = np.unique(values, return_counts=True)
    p = counts / counts.sum()
    return float(-(p * np.log2(p)).sum() * len(values))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    clip_arguments(parser)
    parser.add_argument("--reach", type=float, default=0.03,
                        help="the farthest a pair may be, in scene units (default 0.03)")
    parser.add_argument("--radius", type=float, default=0.06,
                        help="the flow's neighbourhood, in scene units (default 0.06)")
    parser.add_argument("--new-bits", type=float, default=28.0, help="bits an unpaired particle costs (default 28)")
    parser.add_argument("--from-frame", type=int, default=8,
                        help="the first frame counted; the model starts two frames before (default 8)")
    parser.add_argument("--to-frame", type=int, help="the last frame counted (default: the clip's last)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()

    archive = ps.Archive(args.file)
    name = args.object or archive.points()[0]
    samples = archive.num_samples(name)
    last = samples - 1 if args.to_frame is None else args.to_frame
    if not 1 <= args.from_frame <= last < samples:
        parser.error(f"{args.file}: frames {args.from_frame} to {last}: expected 1 <= from <= to <= {samples - 1}")
    first = max(0, args.from_frame - 2)
    positions = {t: archive.positions(name, t).astype(np.float64) for t in range(first, last + 1)}
    if sum(len(p) > 0 for p in positions.values()) < 2:
        parser.error(f"{args.file}: {name} has fewer than two frames with particles from {first} to {last}")
    lo, step = clip_grid(archive, name, args.error)
    fps = 1.0 / (archive.time(name, 1) - archive.time(name, 0)) if samples > 1 else 24.0

    results = {}
    for prediction in PREDICTIONS:
        bits = paired = unpaired = 0.0
        previous, steps = None, None
        for t in range(first, last + 1):
            current = np.round((positions[t] - lo) / step)  # on the codec's grid
            if previous is None or len(previous) == 0 or len(current) == 0:
                previous, steps = current, np.zeros_like(current)
                continue
            if prediction == "previous":
                moved = previous
            elif prediction == "linear":
                moved = previous + steps
            elif prediction == "flow":
                moved = previous + np.round(local_mean(previous * step, steps, args.radius))
            else:
                velocity = archive.velocities(name, t - 1).astype(np.float64) / fps / step
                if prediction == "flow of stored velocity":
                    velocity = local_mean(previous * step, velocity, args.radius)
                moved = previous + np.round(velocity)
            match = pair(moved * step, current * step, args.reach)
            ok = match >= 0
            if t >= args.from_frame:
                residual = current[ok] - moved[match[ok]]
                bits += sum(entropy_bits(residual[:, axis]) for axis in range(3))
                paired += ok.sum()
                unpaired += (~ok).sum()
            steps = np.zeros_like(current)
            steps[ok] = current[ok] - previous[match[ok]]
            previous = current
        total = bits + unpaired * args.new_bits
        results[prediction] = {
            "paired_bits": bits / max(paired, 1),
            "unpaired_share": unpaired / max(paired + unpaired, 1),
            "bits_per_particle": total / max(paired + unpaired, 1),
        }

    if args.json:
        print(json.dumps({"file": args.file, "object": name, "grid_step": step, "reach": args.reach,
                          "radius": args.radius, "new_bits": args.new_bits, "predictions": results}, indent=2))
        return
    print(f"{args.file} {name}: grid step {step * 1000:.3f} mm, pairs within {args.reach * 1000:.0f} mm, "
          f"flow over {args.radius * 1000:.0f} mm, {args.new_bits:.0f} bits an unpaired particle")
    print(f"{'prediction':<26}{'bits a pair':>12}{'unpaired':>10}{'bits a particle':>17}")
    for prediction, r in results.items():
        print(f"{prediction:<26}{r['paired_bits']:>12.2f}{100 * r['unpaired_share']:>9.1f}%"
              f"{r['bits_per_particle']:>17.2f}")


if __name__ == "__main__":
    main()
