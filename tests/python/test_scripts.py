"""The scripts beside the library, run on the shared fixtures through the Python bindings: the
analyses in bench/ that docs/compression-experiments.md quotes, each checked for what it finds and
for its errors, and tests/python/spec_reader.py, a reader written from docs/format.md alone,
against the library on every version and codec. Kept apart from test_particlestream.py, the
bindings' own suite, which tests/python/pip_install.sh runs again against an installed copy."""
import json
import os
import pathlib

import pytest

import particlestream as ps

DATA = pathlib.Path(os.environ.get("PSTREAM_TEST_DATA", pathlib.Path(__file__).parents[1] / "data"))


def run_bench_script(script, *args):
    """Runs bench/SCRIPT with ARGS under this Python; returns the finished process (output as text)."""
    import subprocess
    import sys
    path = pathlib.Path(__file__).parents[2] / "bench" / script
    # No bench/__pycache__ from the scripts that import one another: the tests leave the tree as it was.
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, str(path), *map(str, args)], capture_output=True, text=True, env=env)


def bench_script_json(script, *args):
    """Runs bench/SCRIPT with ARGS and --json, which must succeed; returns its report."""
    done = run_bench_script(script, *args, "--json")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_particle_identity_tells_persisting_particles_from_a_resampled_liquid():
    # bench/particle_identity.py (docs/compression-experiments.md, "Where the FLIP pour's bytes
    # go"): a spark moved on by its velocity lands near itself, a FLIP particle no nearer than
    # unmoved.
    found = {}
    for clip in ("blender_sparks", "blender_flip_pour_small"):
        report = bench_script_json("particle_identity.py", DATA / "sims" / f"{clip}.abc", "--frames", "32",
                                   "--sample", "600")
        assert report["grid_step"] > 0
        (row,) = report["frames"]
        assert row["frame"] == 32 and row["particles"] > 1000
        found[clip] = row
    sparks, flip = found["blender_sparks"], found["blender_flip_pour_small"]
    assert sparks["nearest_moved_one_step"] < 0.3 * sparks["nearest_previous"]
    assert flip["nearest_moved_one_step"] > 0.9 * flip["nearest_previous"]
    assert flip["nearest_previous"] < flip["spacing"] < flip["velocity_step"]
    # No fraction of a frame's velocity brings the liquid's particles nearer (velocities in other
    # units would): the sparks' is 1, the liquid's none.
    assert sparks["best_fraction"] == 1.0 and sparks["nearest_moved_best"] == sparks["nearest_moved_one_step"]
    assert flip["nearest_moved_best"] > 0.95 * flip["nearest_previous"]
    # Nor does gravity's half step: a spark moved along one frame's parabola lands on itself (0.0001
    # mm), a FLIP particle no nearer than unmoved.
    assert sparks["nearest_moved_ballistic"] < 0.01 * sparks["nearest_moved_one_step"]
    assert flip["nearest_moved_ballistic"] > 0.9 * flip["nearest_previous"]
    # A fresh set of points at the default bound: about 17-19 bits a particle on both.
    for row in (sparks, flip):
        assert 15 < row["set_bits_per_particle"] < 21
    # Unknown frames are refused with the file named.
    bad = run_bench_script("particle_identity.py", DATA / "sims" / "blender_sparks.abc", "--frames", "999")
    assert bad.returncode != 0 and "blender_sparks.abc: frame 999" in bad.stderr


def test_flow_prediction_finds_the_sparks_motion_and_none_in_the_liquid():
    # bench/flow_prediction.py (docs/compression-experiments.md, "Where the FLIP pour's bytes
    # go"): moved along their stored velocities the sparks' particles pair with themselves and cost a fifth of what
    # they cost unmoved; no prediction, not even the flow of the stored velocities, makes the FLIP
    # pour's frames more than a few percent cheaper, and its particles' own velocities make them dearer.
    found = {}
    for clip in ("blender_sparks", "blender_flip_pour_small"):
        report = bench_script_json("flow_prediction.py", DATA / "sims" / f"{clip}.abc", "--from-frame", "30",
                                   "--to-frame", "31")
        assert report["grid_step"] > 0
        found[clip] = {k: v["bits_per_particle"] for k, v in report["predictions"].items()}
        for v in report["predictions"].values():
            assert 0 <= v["unpaired_share"] <= 1 and v["paired_bits"] > 0
    sparks, flip = found["blender_sparks"], found["blender_flip_pour_small"]
    assert sparks["stored velocity"] < 0.3 * sparks["previous"]
    assert sparks["flow of stored velocity"] < 0.7 * sparks["previous"]
    for prediction, bits in flip.items():
        assert bits > 0.95 * flip["previous"], prediction
    assert flip["stored velocity"] > 1.05 * flip["previous"]
    # Frames outside the clip are refused with the file named.
    bad = run_bench_script("flow_prediction.py", DATA / "sims" / "blender_sparks.abc", "--to-frame", "999")
    assert bad.returncode != 0 and "blender_sparks.abc: frames 8 to 999" in bad.stderr


def test_point_set_coders_lose_to_the_pairing_where_particles_persist_and_gain_little_where_not():
    # bench/point_set_coders.py (docs/compression-experiments.md, "Frames coded as sets of
    # points"): where particles persist (the sparks) the codec's pairing costs under half of any set
    # coder's estimate; on the re-sampled FLIP pour a set coder comes within a few per cent of it at
    # best, and none reaches 1.6 bytes a particle.
    found = {}
    for clip in ("blender_sparks", "blender_flip_pour_small"):
        report = bench_script_json("point_set_coders.py", DATA / "sims" / f"{clip}.abc", "--frames", "24")
        assert report["error"] == 1e-4 and report["particle_frames"] > 10000
        found[clip] = report["bits_per_particle"]
        assert len(found[clip]) == 5
    codec = "particle codec (its file: positions and sizes)"
    for clip, rows in found.items():
        sets = {method: bits for method, bits in rows.items() if method != codec}
        assert all(bits > 0 for bits in sets.values()), clip
        if clip == "blender_sparks":
            assert rows[codec] < 0.5 * min(sets.values())
        else:
            assert 0.9 * rows[codec] < min(sets.values()) < 1.1 * rows[codec]
            assert min(sets.values()) > 8 * 1.6
            assert max(sets.values()) < 1.5 * rows[codec]
    # Too few frames are refused with the file named.
    bad = run_bench_script("point_set_coders.py", DATA / "sims" / "blender_sparks.abc", "--frames", "1")
    assert bad.returncode != 0 and "blender_sparks.abc: /Emitter/Sparks: 1 frame(s) to use" in bad.stderr


def test_halfway_tangents_ranks_stored_central_backward_and_straight_lines():
    # bench/halfway_tangents.py (docs/compression.md, "Backward, not central, differences"): on the
    # sparks taken every other frame, Hermite through the stored velocities puts the left-out frames
    # back closest, then central differences, then the backward ones the decoder derives, then lines.
    report = bench_script_json("halfway_tangents.py", DATA / "sims" / "blender_sparks.abc")
    assert report["compared"] > 50000
    rms = report["rms"]
    assert 0 < rms["stored"] < rms["central"] < rms["central_start"] < rms["backward"] < rms["linear"]
    assert rms["backward"] < 0.8 * rms["linear"]
    # A clip without ids has nothing to pair by: refused, with the file named.
    bad = run_bench_script("halfway_tangents.py", DATA / "sims" / "blender_flip_pour_small.abc")
    assert bad.returncode != 0 and "blender_flip_pour_small.abc" in bad.stderr and "no ids" in bad.stderr


def test_bound_sweep_costs_fewer_bytes_at_each_looser_bound_within_each_bound(tmp_path):
    # bench/bound_sweep.py (docs/compression.md, "Size against the bound"): `pstream bench codec
    # --error` at each bound; every lossy codec keeps the bound it was given, and ours costs less
    # at each looser one. The plot has a line per codec and the target's line.
    svg = tmp_path / "bounds.svg"
    report = bench_script_json("bound_sweep.py", DATA / "sims" / "blender_flip_pour_small.abc", "--frames", "12",
                               "--bounds", "1e-4,4e-4,abs:0.002", "--target", "1.6", "--svg", svg)
    assert report["bounds"] == ["1e-4", "4e-4", "abs:0.002"] and report["frames"] == 12 and not report["ids"]
    bound = report["error_bound"]
    assert bound[2] == pytest.approx(0.002) and bound[1] == pytest.approx(4 * bound[0], rel=1e-6)
    for codec, errors in report["max_error_position"].items():
        assert all(0 < e <= b for e, b in zip(errors, bound)), (codec, errors, bound)
    ours = report["bytes_per_particle"]["particle (ours)"]
    assert ours[0] > ours[1] > ours[2] > 0
    for peer in ("meshopt + zstd -3", "draco"):
        assert all(o < p for o, p in zip(ours, report["bytes_per_particle"][peer])), peer
    text = svg.read_text()
    assert text.count("<polyline") == 3 and "target 1.6" in text and "stroke-dasharray" in text
    # A bound bench codec refuses stops the sweep, naming the file and the bound.
    bad = run_bench_script("bound_sweep.py", DATA / "sims" / "blender_flip_pour_small.abc", "--bounds", "2")
    assert bad.returncode != 0 and "blender_flip_pour_small.abc" in bad.stderr and "--error 2" in bad.stderr


def test_a_reader_written_from_the_spec_decodes_every_frame_as_the_library_does(tmp_path):
    # tests/python/spec_reader.py decodes .pstream files from docs/format.md alone (no code shared
    # with the library): every version, both frame codecs, every word coding, nibbles, keyframes
    # with prior steps and links, derived and stored velocity, ids, chunk codecs. Each frame's records must be
    # the library's, byte for byte.
    from spec_reader import SpecReader

    sparks, flip = DATA / "sims" / "blender_sparks.abc", DATA / "sims" / "blender_flip_pour_small.abc"
    varying = DATA / "alembic" / "points_varying.abc"
    cooks = {
        "sparks": (sparks, {}),  # relative scale, colours, derived velocity, nibbles
        "sparks_k8": (sparks, dict(keyframe_interval=8, attributes=["id", "age"])),  # ids, priors, links
        "sparks_stored": (sparks, dict(store_velocity=True, attributes=["id32"])),
        "flip": (flip, {}),  # matched order, stored velocity
        "flip_k5": (flip, dict(keyframe_interval=5)),
        "lossless": (sparks, dict(codec="particle-lossless")),
        "lossless_ids": (sparks, dict(codec="particle-lossless", attributes=["id", "velocity"])),  # ids exact
        "varying_ids": (varying, dict(attributes=["velocity", "id"])),
        "zstd": (varying, dict(codec="zstd")),
        "lz4": (varying, dict(codec="lz4")),
        "empty_frames": (DATA / "alembic" / "points_empty_frames.abc", {}),  # frames of no particles
    }
    clips = [DATA / "pstream_v1" / "points_varying_lz4.pstream"] + sorted((DATA / "pstream").glob("*.pstream"))
    for name, (source, options) in cooks.items():
        ps.cook(source, tmp_path / f"{name}.pstream", **options)
        clips.append(tmp_path / f"{name}.pstream")
    seen = set()
    for path in clips:
        reader, clip = SpecReader(path), ps.Clip(path)
        seen.add((reader.version, reader.frame_codec))
        frames = 0
        for f, records in reader.frames_records():
            assert records == clip.read_frame(f).tobytes(), (path.name, f)
            frames += 1
        assert frames == clip.frame_count > 0, path.name
    assert {(1, 0), (2, 0), (2, 1), (3, 1), (4, 1), (5, 1), (6, 0), (6, 1)} <= seen
