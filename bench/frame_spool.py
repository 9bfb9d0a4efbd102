#!/usr/bin/env python3
"""What handing a simulation over frame by frame costs in memory: a list of frames for
`particlestream.cook_particles` against a `particlestream.FrameSpool`, which writes each frame to
an unnamed temporary file as it comes (docs/blender.md, "Export").

Each way runs in a process of its own: it makes the frames one at a time (a particle cloud moving
along a curl of sines, ids, widths and velocities: 40 bytes a particle a frame), hands them over,
cooks them with the default particle codec, and reports its peak memory (anonymous: what it holds;
and all resident pages, a mapping's file pages included), its CPU time and the clip's size. Both clips must be the same bytes.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/frame_spool.py --particles 100000 --frames 120
  ... --json   (one object a line)
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


def frame(k, n, fps):
    import numpy as np
    ids = np.arange(n, dtype=np.uint64)
    a = ids.astype(np.float32) * np.float32(0.001)
    t = np.float32(k / fps)
    position = np.stack([np.sin(a + t) * 2, np.cos(a * 1.3 - t) * 2, np.sin(a * 0.7 + 2 * t)], axis=1)
    velocity = np.stack([np.cos(a + t) * 2, np.sin(a * 1.3 - t) * 2, 2 * np.cos(a * 0.7 + 2 * t)], axis=1)
    return {"time": k / fps, "position": position.astype(np.float32), "velocity": velocity.astype(np.float32),
            "width": np.full(n, 0.01, np.float32), "id": ids}


class PeakMemory:
    """The process's peak anonymous resident memory (RssAnon: what it holds, not the file pages of
    a mapping, which the kernel can drop and read again) and resident memory in all (VmHWM),
    sampled every 5 ms on a thread."""

    def __init__(self):
        import threading
        self.anon = 0
        self.running = True
        self.thread = threading.Thread(target=self.sample, daemon=True)
        self.thread.start()

    def sample(self):
        while self.running:
            self.anon = max(self.anon, self.read("RssAnon:"))
            time.sleep(0.005)

    @staticmethod
    def read(key):
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
        return 0

    def stop(self):
        self.running = False
        self.thread.join()
        return self.anon, self.read("VmHWM:")


def child(way, n, frames, out, folder):
    import particlestream as ps
    fps = 24.0
    peak = PeakMemory()
    start = time.process_time()
    if way == "list":
        report = ps.cook_particles([frame(k, n, fps) for k in range(frames)], out, fps=fps, name="bench")
    else:
        with ps.FrameSpool("bench", folder) as spool:
            for k in range(frames):
                spool.add_frame(frame(k, n, fps))
            report = ps.cook_particles(spool, out, fps=fps, name="bench")
    cpu = time.process_time() - start
    anon, hwm = peak.stop()
    print(json.dumps({"way": way, "particles": n, "frames": frames, "peak_anon_mb": anon / 1e6, "peak_rss_mb": hwm / 1e6,
                      "cpu_s": cpu, "file_bytes": report["file_bytes"],
                      "arrays_mb": 40 * n * frames / 1e6}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, default=100000)
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--json", action="store_true", help="one JSON object a line")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--folder", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.particles, args.frames, args.out, args.folder)
        return
    rows = []
    with tempfile.TemporaryDirectory(prefix="pstream-spool-bench.") as work:
        for way in ("list", "spool"):
            done = subprocess.run([sys.executable, __file__, "--child", way, "--particles", str(args.particles),
                                   "--frames", str(args.frames), "--out", os.path.join(work, way + ".pstream"),
                                   "--folder", work], capture_output=True, text=True)
            if done.returncode != 0:
                sys.exit(f"frame_spool.py: the {way} run failed:\n{done.stderr}")
            rows.append(json.loads(done.stdout))
        with open(os.path.join(work, "list.pstream"), "rb") as a, open(os.path.join(work, "spool.pstream"), "rb") as b:
            same = a.read() == b.read()
        left = sorted(set(os.listdir(work)) - {"list.pstream", "spool.pstream"})
    for r in rows:
        r["same_bytes"] = same
        r["left_behind"] = left
    if args.json:
        for r in rows:
            print(json.dumps(r))
        return
    print(f"{args.particles:,} particles x {args.frames} frames ({rows[0]['arrays_mb']:.0f} MB of arrays), "
          f"default cook; the clips are {'the same bytes' if same else 'DIFFERENT'}; files left: {left or 'none'}")
    print("| handed over as | peak memory held (anonymous) | peak resident, file pages included | CPU time | clip |")
    print("|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {'a list of frames' if r['way'] == 'list' else 'a FrameSpool'} | {r['peak_anon_mb']:,.0f} MB | "
              f"{r['peak_rss_mb']:,.0f} MB | {r['cpu_s']:.1f} s | {r['file_bytes'] / 1e6:.1f} MB |")
    if not same or left:
        sys.exit(1)


if __name__ == "__main__":
    main()
