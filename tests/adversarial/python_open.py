"""The adversarial tree's Python host: one hostile input through the module, as a pipeline
script would use it. Every call must succeed or raise particlestream.Error; any other exception
(or a crash, which the tree's runner sees) is a failure: exit 2.

    python_open.py FILE
"""
import sys

import particlestream as ps


def attempt(what, call):
    try:
        return call()
    except ps.Error as e:
        print(f"{what}: Error: {e}")
    except Exception as e:  # anything else is a defect the tree reports
        print(f"{what}: {type(e).__name__} (not particlestream.Error): {e}")
        sys.exit(2)
    return None


def main():
    path = sys.argv[1]

    def read_clip():
        clip = ps.Clip(path)
        clip.layout
        clip.dtype
        for f in range(min(clip.frame_count, 3)):
            clip.count(f)
            clip.time(f)
            if clip.count(f) * clip.record_size <= 64 << 20:
                clip.read_frame(f)

    def play():
        player = ps.Player([path], blocking=True, sort="back")
        player.play()
        for _ in range(4):
            player.update(1 / 30)
            player.frame(0)
            player.order(0)
        player.seek(0.5)
        player.set_speed(-1)
        player.update(1 / 30)

    def archive():
        archive = ps.Archive(path)
        for name in archive.points()[:4]:
            for sample in range(min(archive.num_samples(name), 2)):
                archive.positions(name, sample)
                archive.ids(name, sample)
                archive.velocities(name, sample)
            for attribute in archive.attributes(name)[:8]:
                archive.attribute(name, attribute, 0)

    attempt("Clip", read_clip)
    attempt("Player", play)
    attempt("Archive", archive)


if __name__ == "__main__":
    main()
