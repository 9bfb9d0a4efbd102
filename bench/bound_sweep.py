#!/usr/bin/env python3
"""What does a cache cost at each position bound? `pstream bench codec` once per bound, one table.

The particle codec's size depends most on the position bound (`cook --error`): about 2.5 bits a
particle for each halving of it on a liquid whose particles are re-sampled every frame. This runs
`pstream bench codec FILE --error BOUND` for each bound, with the lossy peers that keep the same
bound (meshoptimizer + zstd on our grids, Draco with its bits chosen to keep it), and prints the
bytes per particle per frame of each as a Markdown table; --svg plots them against the bound, with
--target drawn as a dashed line; --json prints them as JSON instead, with each bound in scene
units.

Usage (from the repository root, after scripts/build.sh):
  python3 bench/bound_sweep.py tests/data/sims/blender_flip_pour_small.abc --target 1.6 --svg flip.svg
The pstream binary is $PSTREAM_CLI, else build/apps/pstream/pstream (--pstream to choose).
"""
import argparse
import json
import math
import os
import subprocess
import sys

CODECS = ("particle (ours)", "meshopt + zstd -3", "draco")
COLOURS = {"particle (ours)": "#c0392b", "meshopt + zstd -3": "#2471a3", "draco": "#7d3c98"}


def run(pstream, file, bound, frames):
    """One `bench codec` run at `bound`: its JSON report (bytes only matter here: one repetition)."""
    cmd = [pstream, "bench", "codec", file, "--error", bound, "--repetitions", "1", "--json"]
    if frames:
        cmd += ["--frames", str(frames)]
    for codec in CODECS:
        cmd += ["--codec", codec]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        sys.exit(f"{file}: `bench codec --error {bound}` failed: {done.stderr.strip() or done.stdout.strip()}")
    return json.loads(done.stdout[done.stdout.index("{"):])


def per_codec(reports, key):
    """Each codec's `key` from every run, in the runs' order."""
    return {c: [next(x[key] for x in r["codecs"] if x["codec"] == c) for r in reports] for c in CODECS}


def svg(title, bounds, scene_bounds, sizes, target):
    """Bytes per particle (linear) against the bound in scene units (logarithmic; each tick labelled
    with its --error), one line per codec."""
    w, h, left, right, top, bottom = 560, 340, 60, 150, 34, 46
    xs = [math.log(b) for b in scene_bounds]
    top_b = max(max(v) for v in sizes.values())
    top_b = max(top_b, target or 0) * 1.08
    x0, x1 = min(xs), max(xs)
    if x1 == x0:
        x1 = x0 + 1

    def px(i):
        return left + (xs[i] - x0) / (x1 - x0) * (w - left - right)

    def py(v):
        return h - bottom - v / top_b * (h - top - bottom)

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">',
           f'<rect width="{w}" height="{h}" fill="white"/>',
           f'<text x="{left}" y="18" font-size="12">{title}</text>',
           f'<line x1="{left}" y1="{h - bottom}" x2="{w - right}" y2="{h - bottom}" stroke="#333"/>',
           f'<line x1="{left}" y1="{top}" x2="{left}" y2="{h - bottom}" stroke="#333"/>',
           f'<text x="{(left + w - right) / 2:.0f}" y="{h - 10}" text-anchor="middle">'
           'position bound (--error; log scale)</text>',
           f'<text x="14" y="{(top + h - bottom) / 2:.0f}" text-anchor="middle" '
           f'transform="rotate(-90 14 {(top + h - bottom) / 2:.0f})">bytes / particle / frame</text>']
    for i, b in enumerate(bounds):
        out.append(f'<line x1="{px(i):.1f}" y1="{h - bottom}" x2="{px(i):.1f}" y2="{h - bottom + 4}" stroke="#333"/>')
        out.append(f'<text x="{px(i):.1f}" y="{h - bottom + 16}" text-anchor="middle">{b}</text>')
    step = 0.5 if top_b <= 5 else 1.0
    v = 0.0
    while v <= top_b:
        out.append(f'<line x1="{left - 4}" y1="{py(v):.1f}" x2="{w - right}" y2="{py(v):.1f}" stroke="#eee"/>')
        out.append(f'<text x="{left - 7}" y="{py(v) + 4:.1f}" text-anchor="end">{v:g}</text>')
        v += step
    if target:
        out.append(f'<line x1="{left}" y1="{py(target):.1f}" x2="{w - right}" y2="{py(target):.1f}" '
                   'stroke="#555" stroke-dasharray="5,4"/>')
        out.append(f'<text x="{w - right + 6}" y="{py(target) + 4:.1f}">target {target:g}</text>')
    for codec, values in sizes.items():
        pts = " ".join(f"{px(i):.1f},{py(v):.1f}" for i, v in enumerate(values))
        c = COLOURS.get(codec, "#333")
        out.append(f'<polyline points="{pts}" fill="none" stroke="{c}" stroke-width="2"/>')
        for i, v in enumerate(values):
            out.append(f'<circle cx="{px(i):.1f}" cy="{py(v):.1f}" r="3" fill="{c}"/>')
        # The label beside the last point, nudged apart from the target's.
        y = py(values[-1]) + 4
        if target and abs(y - py(target) - 4) < 12:
            y += 12 if y > py(target) + 4 else -12
        out.append(f'<text x="{w - right + 6}" y="{y:.1f}" fill="{c}">{codec}</text>')
    out.append("</svg>\n")
    return "\n".join(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", help="an Alembic file (or PLY sequence) that `pstream bench codec` reads")
    parser.add_argument("--bounds", default="1e-4,2e-4,3e-4,4e-4",
                        help="comma-separated --error values (default: 1e-4,2e-4,3e-4,4e-4 of the diagonal)")
    parser.add_argument("--frames", type=int, default=0, help="only the first N frames (default: all)")
    parser.add_argument("--target", type=float, default=0.0, help="draw this many bytes per particle as a line")
    parser.add_argument("--svg", help="write the plot here")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")
    parser.add_argument("--pstream",
                        default=os.environ.get("PSTREAM_CLI", os.path.join("build", "apps", "pstream", "pstream")),
                        help="the pstream binary (default: $PSTREAM_CLI, else build/apps/pstream/pstream)")
    args = parser.parse_args()
    bounds = [b.strip() for b in args.bounds.split(",") if b.strip()]
    if not bounds:
        sys.exit("--bounds: expected at least one bound, such as 1e-4")
    reports = []
    for i, b in enumerate(bounds):
        print(f"[{i + 1}/{len(bounds)}] bench codec --error {b}", file=sys.stderr, flush=True)
        reports.append(run(args.pstream, args.file, b, args.frames))
    sizes = per_codec(reports, "bytes_per_particle")
    name = os.path.basename(args.file)
    if args.svg:
        with open(args.svg, "w", encoding="utf-8") as f:
            f.write(svg(f"{name}: size against the position bound ([x y z scale])", bounds,
                        [r["error_bound"] for r in reports], sizes, args.target))
    if args.json:
        print(json.dumps({"file": name, "frames": reports[0]["frames"], "particles": reports[0]["particles"],
                          "ids": reports[0]["ids"], "bounds": bounds,
                          "error_bound": [r["error_bound"] for r in reports],
                          "max_error_position": per_codec(reports, "max_error_position"),
                          "bytes_per_particle": sizes}, indent=1))
        return
    print(f"{name}: {reports[0]['frames']} frames, {reports[0]['particles']} particles, [x y z scale], "
          "bytes per particle per frame")
    print()
    print("| --error | bound (scene units) | " + " | ".join(CODECS) + " |")
    print("|---|---:|" + "---:|" * len(CODECS))
    for i, b in enumerate(bounds):
        print(f"| {b} | {reports[i]['error_bound']:.3g} | " + " | ".join(f"{sizes[c][i]:.3f}" for c in CODECS) + " |")


if __name__ == "__main__":
    main()
