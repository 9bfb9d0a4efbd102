#!/usr/bin/env python3
"""What playing a clip backwards costs the IO worker, against playing it forwards.

A particle clip predicts each frame from the frame before, so a frame the decoder has passed must
be decoded again from its keyframe, or from one of the states the decoder saved on its way
(`saved_states`, docs/playback.md, "Going back"). This script plays the clip with a blocking
`particlestream.Player` for a number of host frames at the clip's rate (one cached frame a host
frame), from the first frame forwards and from the last backwards, once for each number of saved
states asked for, and prints the frames decoded, the stream's decode time (wall-clock time of the
IO worker's decodes: a shared machine's noise is in it) and the memory the stream holds. Then it
reads the same frames with `particlestream.Clip.read_frame`, first to last and last to first (the
Reader keeps 3 saved states once a read goes back), and prints the frames decoded and the thread's
CPU time.

Usage (from the repository root, after scripts/build.sh):
  PYTHONPATH=build/python python3 bench/reverse_playback.py out/demo/demo.pstream --states 0,2,3
  ... --json   (one object a line)
"""
import argparse
import json
import time

import numpy as np

import particlestream as ps


def play(path, states, direction, frames):
    clip = ps.Clip(path)
    player = ps.Player([path], blocking=True, loop=False, saved_states=states)
    player.seek(clip.time(0) if direction > 0 else clip.time(clip.frame_count - 1))
    player.set_speed(direction)
    player.play()
    for k in range(frames):
        player.update(0.0 if k == 0 else 1.0 / clip.fps)
    s = player.stats()
    return {"saved_states": states, "direction": "forwards" if direction > 0 else "backwards",
            "host_frames": frames, "frames_decoded": s["frames_decoded"], "decode_ms": s["decode_ms"],
            "decode_bytes": s["decode_bytes"]}


def read(path, direction, frames):
    clip = ps.Clip(path)
    frames = min(frames, clip.frame_count)
    order = range(frames) if direction > 0 else range(clip.frame_count - 1, clip.frame_count - 1 - frames, -1)
    out = np.empty(clip.max_count, clip.dtype)
    t0 = time.thread_time()
    for f in order:
        clip.read_frame(f, out=out)
    return {"reader": True, "direction": "forwards" if direction > 0 else "backwards", "frames": frames,
            "frames_decoded": clip.frames_decoded, "cpu_s": time.thread_time() - t0}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clip", help="a .pstream")
    parser.add_argument("--states", default="0,3", help="numbers of saved states to compare (default 0,3)")
    parser.add_argument("--frames", type=int, default=120, help="host frames played each way (default 120)")
    parser.add_argument("--json", action="store_true", help="one JSON object a line")
    args = parser.parse_args()
    for states in (int(x) for x in args.states.split(",")):
        for direction in (1, -1):
            r = play(args.clip, states, direction, args.frames)
            if args.json:
                print(json.dumps(r))
            else:
                print(f"{states} saved states, {r['direction']:9}: {r['frames_decoded']:6} frames decoded "
                      f"({r['frames_decoded'] / args.frames:5.1f} a host frame) in {r['decode_ms'] / 1000:6.2f} s; "
                      f"decoding holds {r['decode_bytes'] / 2**20:.1f} MiB")
    for direction in (1, -1):
        r = read(args.clip, direction, args.frames)
        if args.json:
            print(json.dumps(r))
        else:
            print(f"Clip.read_frame, {r['direction']:9}: {r['frames_decoded']:6} frames decoded "
                  f"({r['frames_decoded'] / r['frames']:5.1f} a frame read) in {r['cpu_s']:6.2f} s of CPU")


if __name__ == "__main__":
    main()
