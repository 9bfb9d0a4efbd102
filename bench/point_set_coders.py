#!/usr/bin/env python3
"""Would coding each frame as a set of points beat the particle codec's pairing?

For a cache whose particles do not persist (a FLIP solver re-samples them every frame), the
particle codec still pairs each frame's particles with the previous frame's and codes the
residuals. Point-cloud coders take the other road: they code a frame's points as a set (an octree,
or the points sorted along a space-filling curve), with the previous frame as context. This script
estimates what such coders would spend on one points object, on the codec's position grid at the
given bound (positions alone), against the particle codec's file for the same clip cooked with
positions and sizes alone (a FLIP liquid's sizes are constant and cost next to nothing):

- "at rest + movers as a set": a flag for each previous particle says whether a particle of this
  frame sits at exactly its place (the flag's binary entropy over the clip), and the other
  particles are sorted by Morton code and sent as gaps: each gap's bit length entropy-coded (one
  table a frame, fitted to it: optimistic), its bits below the leading one raw; and the same
  streams, the clip's flags and lengths each through the `zstd` command at level 19 as one stream
  (a real coder, which also finds what repeats; the row is left out without the command);
- "octree, previous frame as context": each occupied node sends its 8 children's occupancy as
  bits, each coded with a context of the previous frame's points in the child, in the parent and
  in the child's 26 neighbours (counts bucketed by their bit length), and the static conditional
  entropy of those bits over the whole clip (tables fitted to the clip: optimistic). That is the
  inter-frame prediction of MPEG's G-PCC in its simplest form;
- "octree + direct points": the same down to a level L, below which a node that holds one point
  sends a flag and the point's remaining bits raw (G-PCC's direct coding mode), at the best L.

The estimates are bits a particle over frames 1 on (each needs the frame before); the codec's
figure is its file's bits over all the frames it cooked, the first included. Each estimate leaves
out what a real coder adds (its tables, headers and the counts of duplicate points), so each is a
low figure for its method.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/point_set_coders.py tests/data/sims/blender_flip_pour_small.abc
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

import particlestream as ps
from particle_identity import clip_arguments, clip_grid  # bench/, beside this script

AXIS_BITS = 21  # a key holds three axes of up to 21 bits


def entropy_bits(counts):
    """The bits of a source whose symbols occur `counts` times, coded with their own frequencies."""
    counts = np.asarray([c for c in counts if c > 0], dtype=np.float64)
    return float(-(counts * np.log2(counts / counts.sum())).sum()) if len(counts) else 0.0


def spread_bits(x):
    """The bits of x, three places apart (Morton order's interleave of one axis)."""
    x = x.astype(np.uint64) & np.uint64((1 << AXIS_BITS) - 1)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def morton(q):
    return spread_bits(q[:, 0]) | (spread_bits(q[:, 1]) << np.uint64(1)) | (spread_bits(q[:, 2]) << np.uint64(2))


def cell_keys(q, shift):
    """One integer per point: its cell at `shift` bits coarser than the grid."""
    c = q >> shift
    return (c[:, 0] << (2 * AXIS_BITS)) | (c[:, 1] << AXIS_BITS) | c[:, 2]


def split_key(k):
    m = (1 << AXIS_BITS) - 1
    return k >> (2 * AXIS_BITS), (k >> AXIS_BITS) & m, k & m


def join_key(x, y, z):
    return (x << (2 * AXIS_BITS)) | (y << AXIS_BITS) | z


def lookup(keys, table_keys, table_counts):
    """The count of each key in a sorted table (0 where absent)."""
    if len(table_keys) == 0:
        return np.zeros(len(keys), dtype=np.int64)
    i = np.minimum(np.searchsorted(table_keys, keys), len(table_keys) - 1)
    return np.where(table_keys[i] == keys, table_counts[i], 0)


def bit_length_bucket(n):
    return np.minimum(np.ceil(np.log2(np.asarray(n) + 1)).astype(np.int64), 6)


def movers_as_a_set(prev, cur):
    """Bits of one frame by the first method (see the top): (flags' counts, gap bits), and its three
    streams as bytes (the flags, a byte for each gap's bit length, the gaps' bits below their
    leading ones)."""
    prev_keys = np.unique(cell_keys(prev, 0))
    cur_keys = cell_keys(cur, 0)
    at_rest = np.isin(cur_keys, prev_keys)
    flags = np.isin(prev_keys, cur_keys)
    movers = np.sort(morton(cur[~at_rest]))
    gaps = np.maximum(np.diff(np.concatenate([[np.uint64(0)], movers])).astype(np.float64), 1)
    lengths = np.floor(np.log2(gaps)).astype(np.int64)
    _, length_counts = np.unique(lengths, return_counts=True)
    below = gaps.astype(np.uint64) - (np.uint64(1) << lengths.astype(np.uint64))
    places = np.arange(max(1, int(lengths.max(initial=0))), dtype=np.uint64)
    bits = ((below[:, None] >> places[None, :]) & np.uint64(1)).astype(np.uint8)
    raw = bits[places[None, :] < lengths[:, None].astype(np.uint64)]
    streams = (np.packbits(flags).tobytes(), lengths.astype(np.uint8).tobytes(), np.packbits(raw).tobytes())
    return (int(flags.sum()), int(len(flags) - flags.sum())), entropy_bits(length_counts) + float(lengths.sum()), streams


def octree_contexts(prev, cur, depth, counts, direct):
    """Adds one frame's occupancy bits to counts[(level, contexts)] = [zeros, ones]; and to
    direct[level] = [nodes of one point, nodes of more, points under nodes of more] for the direct
    mode's estimate."""
    cur = np.unique(cur, axis=0)
    for level in range(1, depth + 1):
        shift = depth - level
        parents = np.unique(cell_keys(cur, shift + 1))
        occupied = np.unique(cell_keys(cur, shift))
        child_keys, child_counts = np.unique(cell_keys(prev, shift), return_counts=True)
        parent_keys, parent_counts = np.unique(cell_keys(prev, shift + 1), return_counts=True)
        node_keys, node_points = np.unique(cell_keys(cur, shift), return_counts=True)
        direct.setdefault(level, np.zeros(3))
        direct[level] += (np.sum(node_points == 1), np.sum(node_points > 1), node_points[node_points > 1].sum())
        px, py, pz = split_key(parents)
        in_parent = bit_length_bucket(lookup(parents, parent_keys, parent_counts))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    cx, cy, cz = 2 * px + dx, 2 * py + dy, 2 * pz + dz
                    child = join_key(cx, cy, cz)
                    bits = np.isin(child, occupied)
                    around = np.zeros(len(child), dtype=np.int64)
                    for ox in (-1, 0, 1):
                        for oy in (-1, 0, 1):
                            for oz in (-1, 0, 1):
                                if ox or oy or oz:
                                    around += lookup(join_key(cx + ox, cy + oy, cz + oz), child_keys, child_counts)
                    context = (level * 1000 + bit_length_bucket(lookup(child, child_keys, child_counts)) * 100 +
                               in_parent * 10 + bit_length_bucket(around))
                    for c, b in zip(context.tolist(), bits.tolist()):
                        counts.setdefault(c, [0, 0])[int(b)] += 1


def zstd_bytes(data):
    """The bytes of `data` through the zstd command at level 19, as one stream (a real coder's cost for
    the flags and the gaps' lengths, with its tables and what it finds between frames)."""
    run = subprocess.run(["zstd", "-19", "-c", "--no-check"], input=bytes(data), capture_output=True, check=True)
    return len(run.stdout)


def codec_bytes(path, name, error, frames):
    """The particle codec's file for the same positions (no velocity, no colours; its sizes, constant
    or not, and its ids, where the clip has them, are in it)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "positions.pstream")
        report = ps.cook(path, out, object=name, velocity=False, color_from="none", error=f"rel:{error}",
                         frames=frames)
        return report["file_bytes"], report["particles"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    clip_arguments(parser)
    parser.add_argument("--frames", type=int, default=0, help="use the first N frames (default: all)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()

    archive = ps.Archive(args.file)
    name = args.object or archive.points()[0]
    samples = archive.num_samples(name)
    if args.frames:
        samples = min(samples, args.frames)
    if samples < 2:
        sys.exit(f"{args.file}: {name}: {samples} frame(s) to use; two or more are needed")
    lo, step = clip_grid(archive, name, args.error, samples)
    positions = [archive.positions(name, t).astype(np.float64) for t in range(samples)]
    grid = [np.round((p - lo) / step).astype(np.int64) for p in positions]
    depth = max(1, max(int(g.max()) for g in grid if len(g)).bit_length())
    if depth > AXIS_BITS:
        sys.exit(f"{args.file}: the grid at bound {args.error} needs {depth} bits an axis; this script handles "
                 f"{AXIS_BITS}")

    particles, flags, gap_bits, counts, direct = 0, [0, 0], 0.0, {}, {}
    streams = [bytearray(), bytearray(), bytearray()]
    for t in range(1, samples):
        prev, cur = grid[t - 1], grid[t]
        if len(cur) == 0 or len(prev) == 0:
            continue
        particles += len(cur)
        (kept, left), bits, frame_streams = movers_as_a_set(prev, cur)
        for k in range(3):
            streams[k] += frame_streams[k]
        flags[0] += kept
        flags[1] += left
        gap_bits += bits
        octree_contexts(prev, cur, depth, counts, direct)
    if particles == 0:
        sys.exit(f"{args.file}: no frame after the first has particles")

    per_level = {}
    for context, zeros_ones in counts.items():
        per_level[context // 1000] = per_level.get(context // 1000, 0.0) + entropy_bits(zeros_ones)
    octree = sum(per_level.values())
    # Direct points below level L: the octree's bits down to L, then a flag a node at L (one point or
    # more), each single point's bits below L raw (3 an axis level), the others' nodes on down the
    # octree (their share of each lower level's bits, by points).
    best = None
    for level in range(2, depth):
        single, multi, multi_points = direct[level]
        bits = sum(per_level[k] for k in range(1, level + 1)) + entropy_bits([single, multi])
        bits += single * 3 * (depth - level)
        nodes_points = single + multi_points
        bits += sum(per_level[k] for k in range(level + 1, depth + 1)) * (multi_points / max(nodes_points, 1))
        if best is None or bits < best[1]:
            best = (level, bits)
    file_bytes, cooked = codec_bytes(args.file, name, args.error, f"0:{samples}")  # A:B stops before B
    rows = {
        "particle codec (its file: positions and sizes)": 8 * file_bytes / cooked,
        "at rest + movers as a set": (entropy_bits(flags) + gap_bits) / particles,
    }
    if shutil.which("zstd"):
        rows["the same, its flags and lengths through zstd -19"] = 8 * (
            zstd_bytes(streams[0]) + zstd_bytes(streams[1]) + len(streams[2])) / particles
    rows["octree, previous frame as context"] = octree / particles
    rows[f"octree + direct points below level {best[0]}"] = best[1] / particles
    if args.json:
        print(json.dumps({"file": args.file, "object": name, "error": args.error, "particle_frames": particles,
                          "bits_per_particle": rows}, indent=2))
        return
    print(f"{args.file} {name}: {samples} frames, grid step {step:.4g} ({args.error:g} of the diagonal), "
          f"{depth} bits an axis")
    print(f"{'method':48s} {'bits/p':>7s} {'B/p':>6s}")
    for method, bits in rows.items():
        print(f"{method:48s} {bits:7.2f} {bits / 8:6.3f}")


if __name__ == "__main__":
    main()
