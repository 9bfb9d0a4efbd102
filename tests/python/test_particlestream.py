"""The Python bindings, end to end on the fixtures in tests/data: every Alembic fixture read
through particlestream.Archive and compared with the official reader's answers
(*.expected.json: counts, position sums, bounds, ids), then cook, clip and player as numpy."""
import json
import math
import os
import pathlib
import re

import numpy as np
import pytest

import particlestream as ps

DATA = pathlib.Path(os.environ.get("PSTREAM_TEST_DATA", pathlib.Path(__file__).parents[1] / "data"))
FIXTURES = sorted(p for p in (DATA / "alembic").glob("*.abc") if p.with_suffix(".expected.json").exists())


def expected_points(abc):
    expected = json.loads(abc.with_suffix(".expected.json").read_text())
    return expected.get("points", [])


def vec_sum(a):  # float64 sums per component, as the expected files hold them
    return a.astype(np.float64).sum(axis=0) if len(a) else np.zeros(3)


@pytest.mark.parametrize("abc", FIXTURES, ids=lambda p: p.stem)
def test_every_fixture_matches_the_official_reader(abc):
    points = expected_points(abc)
    if abc.stem == "points_hdf5_backend":  # HDF5: refused with a message (our reader is Ogawa only)
        with pytest.raises(ps.Error, match="HDF5"):
            ps.Archive(abc)
        return
    archive = ps.Archive(abc)
    assert sorted(archive.points()) == sorted(p["full_name"] for p in points)
    compared = 0
    for obj in points:
        name = obj["full_name"]
        assert archive.num_samples(name) == obj["num_samples"]
        for s in obj["samples"]:
            i = s["index"]
            assert archive.count(name, i) == s["count"]
            assert archive.time(name, i) == pytest.approx(s["time"], abs=1e-12)
            p = archive.positions(name, i)
            assert p.shape == (s["count"], 3) and p.dtype == np.float32
            want = s["positions"]
            assert p.shape[0] == want["count"]
            if want["count"]:
                np.testing.assert_allclose(vec_sum(p), want["sum"], rtol=1e-9, atol=1e-9)
                np.testing.assert_array_equal(p.min(axis=0), np.float32(want["min"]))
                np.testing.assert_array_equal(p.max(axis=0), np.float32(want["max"]))
                first = np.float32(want["first"])  # the first few values, and the last
                np.testing.assert_array_equal(p[: len(first)], first)
                np.testing.assert_array_equal(p[-1], np.float32(want["last"]))
            ids = s.get("ids")
            if ids and ids["count"]:
                got = archive.ids(name, i)
                assert got.dtype == np.uint64 and len(got) == ids["count"]
                assert int(got.sum(dtype=np.uint64)) == ids["sum"] % 2**64
                assert int(got.min()) == ids["min"] and int(got.max()) == ids["max"]
                assert [int(v) for v in got[: len(ids["first"])]] == ids["first"]
                assert int(got[-1]) == ids["last"]
            compared += 1
    assert compared == sum(len(o["samples"]) for o in points)


def test_positions_view_the_mapped_file_without_a_copy():
    archive = ps.Archive(DATA / "alembic" / "points_large.abc")
    name = archive.points()[0]
    p = archive.positions(name, 0)
    assert not p.flags.owndata and not p.flags.writeable
    assert p.base is archive  # the array keeps the archive (and its mapping) alive
    again = archive.positions(name, 0)
    assert np.shares_memory(p, again)  # the same bytes of the mapping, twice
    del archive
    assert np.isfinite(p).all()  # still valid: the array holds the archive


def test_cook_clip_and_player_as_numpy(tmp_path):
    abc = DATA / "alembic" / "points_varying.abc"
    calls = []
    report = ps.cook(abc, tmp_path / "v.pstream", attributes=["velocity", "id"], codec="raw",  # exact values
                     progress=lambda done, total: calls.append((done, total)))
    assert report["frames"] == 60 and report["particles"] > 0 and report["file_bytes"] > 0
    assert report["object"] == "/particles" and not report["mesh_vertices"], report
    assert calls[-1] == (60, 60)  # the records codec: one pass over the frames
    assert [d for d, _ in calls] == sorted(d for d, _ in calls) and {t for _, t in calls} == {60}
    calls.clear()
    ps.cook(abc, tmp_path / "p.pstream", progress=lambda done, total: calls.append((done, total)))
    # The particle codec reads the frames twice (statistics, then encoding): one bar that only grows.
    assert calls[-1] == (120, 120) and {t for _, t in calls} == {120}, calls
    assert [d for d, _ in calls] == sorted(d for d, _ in calls) and calls[59] == (60, 120), calls
    mesh = ps.cook(DATA / "alembic" / "mesh_vertices.abc", tmp_path / "m.pstream")  # no points: the one mesh
    assert mesh["object"] == "/grid" and mesh["mesh_vertices"] and mesh["particles"] == 24 * 400, mesh

    clip = ps.Clip(tmp_path / "v.pstream")
    assert clip.frame_count == 60
    for past_the_end in (lambda: clip.count(60), lambda: clip.time(60), lambda: clip.read_frame(60)):
        with pytest.raises(ps.Error, match=r"v.pstream: no frame 60 \(the clip's frames are 0 to 59\)"):
            past_the_end()
    assert [a[0] for a in clip.layout] == ["position", "scale", "color", "velocity", "id"]
    archive = ps.Archive(abc)
    for f in (5, 30, 59):
        records = clip.read_frame(f)
        assert records.dtype == clip.dtype and records.dtype.itemsize == clip.record_size
        ids = archive.ids("/particles", f)
        # Written in id order: the same particles, sorted by id, every value exact.
        order = np.argsort(ids, kind="stable")
        np.testing.assert_array_equal(records["id"], ids[order])
        np.testing.assert_array_equal(records["position"], archive.positions("/particles", f)[order])
        np.testing.assert_array_equal(records["velocity"], archive.velocities("/particles", f)[order])

    player = ps.Player([tmp_path / "v.pstream"], sort="back", loop=False)
    player.set_speed(0.5)
    player.play()
    seen = 0
    for k in range(100):
        stats = player.update(0.0 if k == 0 else 1 / 60)
        frame = player.frame(0)
        assert frame.dtype == clip.dtype and len(frame) == stats["particles"]
        if len(frame):  # the clip's first frames are empty
            assert not frame.flags.owndata and not frame.flags.writeable  # a view of the player's memory
            assert frame.base is player
            seen += 1
    assert seen > 50
    assert player.time(0) == pytest.approx(clip.time(0) + 99 / 60 * 0.5)
    stats = player.stats(0)
    assert stats["loads_done"] > 0 and stats["stalls"] == 0 and stats["frames_decoded"] > 0
    assert stats["cache_bytes"] > 0 and stats["decode_bytes"] > 0

    # Sorted for a camera: looking down -z from z = +10 after a turn about y, back to front means
    # view-space z ascending (farthest first).
    angle = 0.7
    view = np.array([[np.cos(angle), 0, np.sin(angle), 0], [0, 1, 0, 0],
                     [-np.sin(angle), 0, np.cos(angle), -10], [0, 0, 0, 1]], dtype=np.float32)
    player.update(1 / 60, view=view)
    frame, order = player.frame(0), player.order(0)
    assert len(order) == len(frame) > 0 and not order.flags.writeable
    assert sorted(order.tolist()) == list(range(len(frame)))
    p = frame["position"].astype(np.float64)
    z = p @ view[2, :3].astype(np.float64) + view[2, 3]
    assert np.all(np.diff(z[order]) >= -1e-4)  # farthest (most negative z) first
    with pytest.raises(ps.Error, match="4x4"):
        player.update(0, view=np.eye(3))


def test_errors_are_exceptions_with_the_librarys_message(tmp_path):
    with pytest.raises(ps.Error, match="no/such.abc"):
        ps.Archive(DATA / "no" / "such.abc")
    # The CLI's words: a source gets "cook it first", with the command.
    with pytest.raises(ps.Error, match="is an Alembic archive, not a cooked clip; cook it first: pstream cook"):
        ps.Clip(DATA / "alembic" / "points_varying.abc")
    with pytest.raises(ps.Error, match="cook it first"):
        ps.Player([DATA / "alembic" / "points_varying.abc"])
    with pytest.raises(ps.Error, match="`codec` 'gzip': expected particle"):
        ps.cook(DATA / "alembic" / "points_varying.abc", tmp_path / "x.pstream", codec="gzip")
    archive = ps.Archive(DATA / "alembic" / "points_varying.abc")
    with pytest.raises(ps.Error, match="no points object '/nothing'"):
        archive.positions("/nothing", 0)
    with pytest.raises(ps.Error, match="no sample 60"):
        archive.positions("/particles", 60)
    assert issubclass(ps.Error, RuntimeError)


def test_a_clip_of_empty_frames_plays():
    # Every frame empty, so no chunks: it once killed the interpreter (a division by zero).
    player = ps.Player([DATA / "pstream" / "empty_frames.pstream"], blocking=True, sort="back")
    player.play()
    for _ in range(20):
        assert player.update(1 / 60)["particles"] == 0


def test_read_frame_decodes_into_its_own_array_in_any_order(tmp_path):
    # Empty frames among full ones (a particle clip: frames decode on from their keyframe). Every
    # frame, read in order, backwards and again, has the clip's count and dtype, owns its memory,
    # and holds the raw cook's particles within the position bound.
    abc = DATA / "alembic" / "points_empty_frames.abc"
    ps.cook(abc, tmp_path / "p.pstream", keyframe_interval=8, error="abs:0.001")
    ps.cook(abc, tmp_path / "r.pstream", codec="raw")
    clip, raw = ps.Clip(tmp_path / "p.pstream"), ps.Clip(tmp_path / "r.pstream")
    assert clip.frame_count == raw.frame_count == 24
    counts = [clip.count(f) for f in range(clip.frame_count)]
    assert 0 in counts and max(counts) > 0
    order = list(range(24)) + list(reversed(range(24))) + [5, 17, 3, 23, 0]
    kept = {}
    for f in order:
        records = clip.read_frame(f)
        assert records.dtype == clip.dtype and len(records) == counts[f] and records.flags.owndata
        expected = raw.read_frame(f)
        assert np.all(np.abs(np.sort(records["position"], axis=0) - np.sort(expected["position"], axis=0)) <= 0.001)
        if f in kept:
            assert np.array_equal(kept[f], records)  # the same bytes whatever came before
        kept[f] = records
    # Read last to first, a fresh clip resumes from the states its decoder saves on the way back,
    # rather than decoding each frame from its keyframe (8 + 7 + ... + 1 a group: 108; the states
    # come at the second read, so the first group's walk is paid in full: 66).
    back = ps.Clip(tmp_path / "p.pstream")
    for f in reversed(range(24)):
        assert np.array_equal(back.read_frame(f), kept[f])
    assert 24 <= back.frames_decoded <= 70
    # Into the caller's array, reused: the view out[:count] of it, the same records.
    out = np.empty(clip.max_count, clip.dtype)
    assert clip.max_count == max(counts)
    for f in order:
        view = clip.read_frame(f, out=out)
        assert len(view) == counts[f] and view.base is out and np.array_equal(view, kept[f])
    # What it cannot take: named, never converted into a copy that would be thrown away.
    big = counts.index(max(counts))
    read_only = np.empty(clip.max_count, clip.dtype)
    read_only.flags.writeable = False
    for bad, message in [(np.empty(1, clip.dtype), f"frame {big} holds {max(counts)} particles, out has room for 1"),
                         (np.empty(clip.max_count, np.float32), "out's dtype is dtype('float32'), expected clip.dtype"),
                         (out[::2], "out must be a writable, contiguous one-dimensional array"),
                         (read_only, "out must be a writable, contiguous one-dimensional array"),
                         (list(range(10)), "out must be a numpy array of the clip's dtype, not <class 'list'>")]:
        with pytest.raises(ps.Error, match=re.escape(message)):
            clip.read_frame(big, out=bad)


def test_what_the_c_api_refuses_raises_particlestream_error():
    clip = DATA / "pstream" / "empty_frames.pstream"
    player = ps.Player([clip])
    for bad in (math.nan, -1.0, math.inf):
        with pytest.raises(ps.Error, match="dt is"):
            player.update(bad)
    with pytest.raises(ps.Error, match="seek: time is nan"):
        player.seek(math.nan)
    with pytest.raises(ps.Error, match="set_speed: speed is inf"):
        player.set_speed(math.inf)
    for bad in (math.nan, -1.0, math.inf):
        with pytest.raises(ps.Error, match="cache_seconds is"):
            ps.Player([clip], cache_seconds=bad)
    # Only particlestream.Error (a RuntimeError) comes out of the library: never a raw C++ error.
    with pytest.raises(ps.Error):
        ps.Player([DATA / "alembic" / "points_varying.expected.json"])


def test_player_plays_backwards_from_saved_states(tmp_path):
    # A default cook of the sparks (one keyframe group of 48 frames), played backwards one cached
    # frame a step: every frame shown is the clip's frame, and the decoder's saved states (3 by
    # default) cut the decodes to under a third of those from the keyframe (saved_states=0).
    ps.cook(DATA / "sims" / "blender_sparks.abc", tmp_path / "s.pstream")
    clip = ps.Clip(tmp_path / "s.pstream")
    n = clip.frame_count
    decoded, memory = {}, {}
    for states in (0, 3):
        player = ps.Player([tmp_path / "s.pstream"], interpolation="none", loop=False, saved_states=states)
        player.seek(clip.time(n - 1))
        player.update(0)
        start = player.stats()["frames_decoded"]
        player.set_speed(-1)
        player.play()
        for f in range(n - 2, -1, -1):
            player.update(1 / clip.fps)
            np.testing.assert_array_equal(player.frame(0), clip.read_frame(f))
        decoded[states] = player.stats()["frames_decoded"] - start
        memory[states] = player.stats()["decode_bytes"]
    assert decoded[3] * 3 < decoded[0], decoded
    assert memory[3] > memory[0]
    with pytest.raises(ps.Error, match="saved_states is -1"):
        ps.Player([tmp_path / "s.pstream"], saved_states=-1)


def test_default_cook_is_the_particle_codec_with_its_bounds(tmp_path):
    abc = DATA / "sims" / "blender_sparks.abc"
    calls = []
    ps.cook(abc, tmp_path / "d.pstream", progress=lambda done, total: calls.append((done, total)))
    # Two passes (scan, write) over the clip's 48 frames, as one count that only grows.
    assert calls[-1] == (96, 96) and {total for _, total in calls} == {96}
    clip = ps.Clip(tmp_path / "d.pstream")
    names = [a[0] for a in clip.layout]
    assert "velocity" in names  # the source's velocities are kept by default
    raw = tmp_path / "r.pstream"
    ps.cook(abc, raw, codec="raw")
    assert (tmp_path / "d.pstream").stat().st_size * 4 < raw.stat().st_size
    # Each scale within 2 % of its own value (the bound set here); positions within their bound.
    ps.cook(abc, tmp_path / "s.pstream", scale_error="2%", error="abs:0.001")
    a, b = ps.Clip(tmp_path / "s.pstream"), ps.Clip(raw)
    for f in (0, 20, 47):
        x, y = a.read_frame(f), b.read_frame(f)
        assert len(x) == len(y)
        xs, ys = np.sort(x["scale"]), np.sort(y["scale"])
        assert np.all(np.abs(xs - ys) <= 0.02 * ys + 1e-12)
    with pytest.raises(ps.Error, match="scale_error '70%'"):
        ps.cook(abc, tmp_path / "bad.pstream", scale_error="70%")
    with pytest.raises(ps.Error, match="error 'rel:2'"):
        ps.cook(abc, tmp_path / "bad.pstream", error="rel:2")


def test_verify_reports_each_attribute_and_the_derived_velocity(tmp_path):
    abc = DATA / "sims" / "blender_sparks.abc"
    clip = tmp_path / "d.pstream"
    ps.cook(abc, clip)  # the default: particle codec, velocity derived from the particles' ids
    plain = ps.verify(str(clip))
    assert plain["ok"] and plain["frames"] == 48 and plain["attributes"] == [] and plain["errors"] == []
    r = ps.verify(str(clip), str(abc))
    assert r["ok"] and r["frames_compared"] == 48 and r["particles_compared"] > 100000
    by_name = {a["name"]: a for a in r["attributes"]}
    assert set(by_name) == {"position", "scale", "color", "velocity"}
    assert by_name["scale"]["relative"] and by_name["scale"]["max_error"] <= by_name["scale"]["bound"] == pytest.approx(0.01)
    assert by_name["color"]["exact"] and by_name["color"]["max_error"] == 0
    # Distinct values, but for positions: the sizes the 1 % bound keeps apart all stay distinct, and
    # an exact attribute keeps every value.
    assert "distinct_clip" not in by_name["position"]
    scale = by_name["scale"]
    assert 40 <= scale["kept_apart"] < scale["distinct_source"] and scale["distinct_clip"] >= scale["kept_apart"]
    assert by_name["color"]["distinct_clip"] == by_name["color"]["kept_apart"] == by_name["color"]["distinct_source"]
    v = by_name["velocity"]
    assert v["derived"] and v["in_source"] and 0 < v["rms_error"] < 0.15 * v["rms_source"]
    # The same report as the command line's.
    cli_path = os.environ.get("PSTREAM_CLI")
    if cli_path:
        import subprocess
        out = subprocess.run([cli_path, "verify", str(clip), "--against", str(abc), "--json"], capture_output=True,
                             text=True)
        cli = json.loads(out.stdout)
        assert cli["ok"] == r["ok"]
        for a in cli["against"]["attributes"]:
            assert by_name[a["name"]]["max_error"] == pytest.approx(a["max_error"])
            for key in ("distinct_clip", "distinct_source", "distinct_counted_up_to", "kept_apart"):
                assert by_name[a["name"]].get(key) == a.get(key), (a["name"], key)
    # A corrupted clip: not ok, and the error names the chunk.
    data = bytearray(clip.read_bytes())
    data[300] ^= 0xFF
    bad = tmp_path / "bad.pstream"
    bad.write_bytes(bytes(data))
    broken = ps.verify(str(bad))
    assert not broken["ok"] and any("chunk" in e or "checksum" in e for e in broken["errors"])


def _same(got, want):
    if isinstance(want, str):
        return got == want
    if isinstance(want, list):
        return len(got) == len(want) and all(_same(g, w) for g, w in zip(got, want))
    return math.isclose(float(got), float(want), rel_tol=1e-9, abs_tol=1e-12)


def test_export_writes_the_clip_back_as_alembic_and_ply(tmp_path):
    """export() writes every decoded value of a default cook of the Blender sparks (colours, derived
    velocity, births and deaths) into an Alembic cache our reader reads back exactly, and
    into a PLY sequence whose every file holds its frame's records."""
    clip_path = tmp_path / "sparks.pstream"
    ps.cook(DATA / "sims" / "blender_sparks.abc", clip_path)
    clip = ps.Clip(clip_path)
    calls = []
    r = ps.export(str(clip_path), tmp_path / "back.abc", progress=lambda d, t: calls.append((d, t)))
    assert r["format"] == "alembic" and r["frames"] == clip.frame_count
    assert r["first"] == str(tmp_path / "back.abc") and r["bytes_written"] == (tmp_path / "back.abc").stat().st_size
    assert calls[-1] == (clip.frame_count, clip.frame_count) and len(calls) == clip.frame_count
    archive = ps.Archive(tmp_path / "back.abc")
    (name,) = archive.points()
    assert "Cd" in archive.attributes(name)
    for f in range(clip.frame_count):
        records = clip.read_frame(f)
        assert archive.count(name, f) == len(records)
        np.testing.assert_array_equal(archive.positions(name, f), records["position"])
        np.testing.assert_array_equal(archive.velocities(name, f), records["velocity"])
        widths = archive.attribute(name, ".widths", f)
        np.testing.assert_array_equal(np.asarray(widths, dtype=np.float32).ravel(), 2 * records["scale"])
        cd = np.asarray(archive.attribute(name, "Cd", f), dtype=np.float32).reshape(len(records), -1)
        np.testing.assert_array_equal(np.rint(cd * 255), records["color"][:, :cd.shape[1]])

    # The default cook matches by id but keeps none: the exported ids follow the codec's matching.
    # The same cook keeping the ids orders every frame the same way (by id), so each exported id
    # must stand for one source id in every frame it is in, and the clip (48 frames: one keyframe
    # group of the default 64) gets as many ids as the source has particles.
    ps.cook(DATA / "sims" / "blender_sparks.abc", tmp_path / "ids.pstream", attributes=["id"])
    with_ids = ps.Clip(tmp_path / "ids.pstream")
    source_of = {}
    for f in range(clip.frame_count):
        exported = archive.ids(name, f)
        real = with_ids.read_frame(f)["id"]
        assert len(exported) == len(real) and len(set(exported.tolist())) == len(exported)
        for e, r in zip(exported.tolist(), real.tolist()):
            assert source_of.setdefault(e, r) == r, (f, e, r)
    assert len(source_of) == len(set(source_of.values()))
    assert len(source_of) == len({int(i) for f in range(clip.frame_count) for i in with_ids.read_frame(f)["id"]})

    r = ps.export(str(clip_path), tmp_path / "seq" / "sparks.ply")
    assert r["format"] == "ply" and r["first"] == str(tmp_path / "seq" / "sparks.0001.ply")
    files = sorted((tmp_path / "seq").iterdir())
    assert [p.name for p in files] == [f"sparks.{f + 1:04}.ply" for f in range(clip.frame_count)]
    assert r["bytes_written"] == sum(p.stat().st_size for p in files)
    assert [a[0] for a in clip.layout] == ["position", "scale", "color", "velocity"]
    # The PLY sequence gets the same ids as the Alembic export: the clip's particles were matched by
    # the source's ids.
    vertex = np.dtype([("position", "<f4", 3), ("scale", "<f4"), ("velocity", "<f4", 3), ("color", "u1", 4),
                       ("id", "<u4")])
    for f in (0, clip.frame_count // 2, clip.frame_count - 1):
        data = files[f].read_bytes()
        head, body = data.split(b"end_header\n", 1)
        records = clip.read_frame(f)
        assert f"element vertex {len(records)}\n".encode() in head and b"property uint id\n" in head
        got = np.frombuffer(body, dtype=vertex)
        for field in ("position", "scale", "velocity", "color"):
            np.testing.assert_array_equal(got[field], records[field])
        np.testing.assert_array_equal(got["id"], archive.ids(name, f))
    # A part of the clip: its frames, at their times; PLY files keep their frames' numbers.
    r = ps.export(str(clip_path), tmp_path / "part.abc", frames="10:20")
    assert r["frames"] == 10
    part = ps.Archive(tmp_path / "part.abc")
    assert part.num_samples(name) == 10
    for k in (0, 9):
        assert part.time(name, k) == pytest.approx(clip.time(10 + k), abs=1e-9)
        np.testing.assert_array_equal(part.positions(name, k), clip.read_frame(10 + k)["position"])
    r = ps.export(str(clip_path), tmp_path / "tail" / "t.ply", frames="40:")
    assert r["frames"] == clip.frame_count - 40 and r["first"] == str(tmp_path / "tail" / "t.0041.ply")
    assert sorted(p.name for p in (tmp_path / "tail").iterdir()) == [f"t.{f + 1:04}.ply" for f in range(40, 48)]
    # describe_ply(): the sequence export wrote, as the cook will read it.
    d = ps.describe_ply(tmp_path / "seq" / "sparks.0007.ply")
    assert d["encoding"] == "binary_little_endian" and d["first_number"] == 1
    assert [f["count"] for f in d["files"]] == [clip.count(f) for f in range(clip.frame_count)]
    assert d["bytes"] == sum(p.stat().st_size for p in files)
    assert [p[0] for p in d["properties"]][:4] == ["x", "y", "z", "pscale"]
    assert (d["scale_from"], d["color"], d["velocity"], d["ids"]) == ("pscale", True, True, True)
    (tmp_path / "tail" / "t.0042.ply").unlink()
    with pytest.raises(ps.Error, match="frame 42 is missing"):
        ps.describe_ply(tmp_path / "tail" / "t.0041.ply")
    with pytest.raises(ps.Error, match="select none; the clip has 48"):
        ps.export(str(clip_path), tmp_path / "none.abc", frames="60:70")
    assert not (tmp_path / "none.abc").exists()
    with pytest.raises(ps.Error, match="the extension chooses the format"):
        ps.export(str(clip_path), tmp_path / "x.txt")
    assert not (tmp_path / "x.txt").exists()


def test_archive_reads_every_attribute_as_the_official_reader(tmp_path):
    """Widths, colours, age, mass, strings (indexed too) of every Alembic fixture, at every
    sample the official reader's answers cover: count, first values, last, sum, min, max."""
    checked = 0
    for expected_file in sorted((DATA / "alembic").glob("*.expected.json")):
        expected = json.loads(expected_file.read_text())
        abc = expected_file.with_name(expected_file.name.replace(".expected.json", ".abc"))
        if "points" not in expected or not abc.exists():
            continue
        if "hdf5" in abc.name:  # the legacy backend, refused by design (test_errors covers it)
            continue
        archive = ps.Archive(abc)
        for obj in expected["points"]:
            name = obj["full_name"]
            listed = archive.attributes(name)
            want_names = ([".widths"] if obj["has_widths"] else []) + obj["arb_geom_param_names"]
            assert listed == want_names, (abc.name, name)
            for sample in obj["samples"]:
                params = ([sample["widths"]] if sample.get("widths") else []) + sample["arb_geom_params"]
                for param in params:
                    vals = param["vals"]
                    got = archive.attribute(name, param["name"], sample["index"], expand=False)
                    flat = list(got) if isinstance(got, list) else got.tolist()
                    assert len(flat) == vals["count"], (abc.name, name, param["name"])
                    if vals["count"] == 0:
                        continue
                    first = vals["first"]
                    assert _same(flat[:len(first)], first), (abc.name, name, param["name"], sample["index"])
                    assert _same(flat[-1], vals["last"]), (abc.name, name, param["name"])
                    if vals["sum"] is not None:
                        s = np.asarray(flat, dtype=np.float64).sum(axis=0).tolist()
                        want = vals["sum"]
                        assert _same(s if isinstance(want, list) else float(np.sum(flat)), want)
                    checked += 1
    assert checked > 100
    # Indexed values expand to one a particle; a missing attribute names the ones there are.
    archive = ps.Archive(DATA / "alembic" / "strings_attributes.abc")
    name = archive.points()[0]
    assert len(archive.attribute(name, "group", 0)) == archive.count(name, 0)
    with pytest.raises(ps.Error, match="no attribute 'nope' \\(it has: "):
        archive.attribute(name, "nope", 0)


def test_cook_takes_every_option_of_the_cli_with_its_messages(tmp_path):
    import subprocess
    abc = DATA / "alembic" / "points_varying.abc"
    out = tmp_path / "o.pstream"
    ps.cook(abc, out, codec="raw", frames="10:20", scale_from="constant:0.5", color_from="none", velocity=False,
            attributes=["id"])
    clip = ps.Clip(out)
    assert clip.frame_count == 10
    assert [a[0] for a in clip.layout] == ["position", "scale", "id"]
    assert np.all(clip.read_frame(0)["scale"] == 0.5)
    ps.cook(abc, out, keyframe_interval=8, error="abs:0.001", attribute_error="1e-2", merge=True, drop_invalid=True)
    assert "keyframe_interval=8" in json.loads(
        subprocess.run([os.environ.get("PSTREAM_CLI", "pstream"), "info", "--json", str(out)],
                       capture_output=True, text=True, check=True).stdout)["cooked_with"]
    # The same words as the command line's, after the option's name.
    cli = os.environ.get("PSTREAM_CLI")
    for kwargs, flag_args, tail in [
        ({"frames": "7-9"}, ["--frames", "7-9"], "or N for frame N alone (a range takes a colon, not a dash)"),
        ({"scale_from": "wdths"}, ["--scale-from", "wdths"], "'wdths': expected widths, constant:X or attr:NAME"),
        ({"scale_error": "0"}, ["--scale-error", "0"], "'0': expected the bound on each particle's scale"),
    ]:
        with pytest.raises(ps.Error) as e:
            ps.cook(abc, tmp_path / "bad.pstream", **kwargs)
        assert tail in str(e.value)
        if cli:
            r = subprocess.run([cli, "cook", str(abc), "-o", str(tmp_path / "bad.pstream"), *flag_args],
                               capture_output=True, text=True)
            assert r.returncode != 0 and tail in r.stderr, r.stderr


def test_type_stubs_describe_the_module():
    """particlestream.pyi lies beside the module and names exactly its public classes, methods,
    properties and functions, with the runtime's argument names."""
    import ast
    import inspect
    stub = pathlib.Path(ps.__file__).with_name("particlestream.pyi")
    assert stub.exists(), stub
    tree = ast.parse(stub.read_text())
    stubbed = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            stubbed[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
        elif isinstance(node, ast.FunctionDef):
            stubbed[node.name] = None
    public = {n for n in dir(ps) if not n.startswith("_")}
    assert public == set(stubbed), public ^ set(stubbed)
    for name, members in stubbed.items():
        if members is None or name == "Error":
            continue
        cls = getattr(ps, name)
        runtime = {m for m in dir(cls) if not m.startswith("_")} | {"__init__"}
        runtime |= {m for m in ("__enter__", "__exit__") if hasattr(cls, m)}  # a context manager's
        assert runtime == members, (name, runtime ^ members)
        for node in next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name).body:
            if not isinstance(node, ast.FunctionDef) or node.decorator_list or node.name == "__init__":
                continue
            doc = getattr(cls, node.name).__doc__.split("\n")[0]
            for arg in node.args.args[1:]:
                assert f"{arg.arg}:" in doc, (name, node.name, arg.arg, doc)
    cook_doc = ps.cook.__doc__.split("\n")[0]
    for arg in next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "cook").args.args:
        assert f"{arg.arg}:" in cook_doc, arg.arg


def test_cook_particles_cooks_arrays_as_a_file_and_names_what_is_wrong(tmp_path):
    """cook_particles: frames as dicts of numpy arrays (what the Blender add-on hands over) cook
    into a clip whose records equal them (raw codec), births and deaths included; a bad frame is
    refused naming the frame and the array, and nothing is written."""
    frames = []
    for f in range(10):
        ids = np.arange(f * 3, f * 3 + 40, dtype=np.uint64)
        pos = np.stack([np.cos(ids * 0.3), np.sin(ids * 0.3) + f * 0.01, ids * 0.001], axis=1).astype(np.float32)
        frames.append({"time": (f + 1) / 24, "position": pos, "id": ids, "width": np.full(len(ids), 0.04),
                       "velocity": np.tile([0.0, 0.24, 0.0], (len(ids), 1)),
                       "color": np.tile([1.0, 0.5, 0.0, 1.0], (len(ids), 1))})
    out = tmp_path / "arrays.pstream"
    seen = []
    report = ps.cook_particles(frames, out, fps=24, name="arrays", codec="raw", attributes=["id"],
                               progress=lambda done, total: seen.append((done, total)))
    assert report["frames"] == 10 and seen[-1] == (10, 10)
    clip = ps.Clip(out)
    for f, frame in enumerate(frames):
        records = clip.read_frame(f)
        assert np.array_equal(records["id"], frame["id"])
        assert np.array_equal(records["position"], frame["position"])
        assert np.allclose(records["scale"], 0.02)
        assert (records["color"] == [255, 128, 0, 255]).all()
    # Float attributes ride along in 'attributes' and are stored when `attributes` names them.
    for f, frame in enumerate(frames):
        frame["attributes"] = {"age": np.full(len(frame["id"]), f / 24, np.float32),
                               "uvw": np.tile([0.5, f, -1.0], (len(frame["id"]), 1)).astype(np.float32)}
    ps.cook_particles(frames, tmp_path / "floats.pstream", fps=24, codec="raw", attributes=["age", "uvw"])
    floats = ps.Clip(tmp_path / "floats.pstream")
    for f, frame in enumerate(frames):
        records = floats.read_frame(f)
        assert np.array_equal(records["age"], frame["attributes"]["age"])
        assert np.array_equal(records["uvw"], frame["attributes"]["uvw"])
    with pytest.raises(ps.Error, match="attribute 'age' is not an array of numbers"):
        ps.cook_particles([dict(frames[0], attributes={"age": "old"})], tmp_path / "bad.pstream")
    bad = [dict(frames[0]), dict(frames[1])]
    bad[1]["id"] = bad[1]["id"][:5]
    with pytest.raises(ps.Error, match="arrays: frame 1: the id array holds 5 values, expected 40"):
        ps.cook_particles(bad, tmp_path / "bad.pstream", name="arrays")
    assert not (tmp_path / "bad.pstream").exists()
    with pytest.raises(ps.Error, match="frame 0 needs 'time'"):
        ps.cook_particles([{"position": frames[0]["position"]}], tmp_path / "bad.pstream")


def test_frame_spool_cooks_the_same_clip_and_leaves_no_file(tmp_path):
    """FrameSpool: frames added one at a time go to disk, not memory, and cook_particles(spool)
    writes the very bytes cook_particles(list) writes from the same frames; nothing appears in
    the spool's folder while it lives or after; a bad frame is refused by name and the spool goes
    on; drop_ids() cooks without the ids."""
    frames = []
    for f in range(10):
        ids = np.arange(f * 3, f * 3 + 40, dtype=np.uint64)
        pos = np.stack([np.cos(ids * 0.3), np.sin(ids * 0.3) + f * 0.01, ids * 0.001], axis=1).astype(np.float32)
        frames.append({"time": (f + 1) / 24, "position": pos, "id": ids, "width": np.full(len(ids), 0.04),
                       "velocity": np.tile([0.0, 0.24, 0.0], (len(ids), 1))})
    folder = tmp_path / "spool"
    folder.mkdir()
    ps.cook_particles(frames, tmp_path / "list.pstream", fps=24, name="sim", attributes=["id"])
    with ps.FrameSpool("sim", folder) as spool:
        for frame in frames:
            spool.add_frame(frame)
        assert spool.frames == 10
        # position, width and velocity as float32, ids as uint64, each padded to 8 bytes
        assert spool.bytes == sum(40 * 12 + 40 * 4 + 40 * 12 + 40 * 8 for _ in frames)
        assert list(folder.iterdir()) == []
        report = ps.cook_particles(spool, tmp_path / "spool.pstream", fps=24, name="sim", attributes=["id"])
        assert report["frames"] == 10
        assert (tmp_path / "spool.pstream").read_bytes() == (tmp_path / "list.pstream").read_bytes()
        late = dict(frames[-1], time=0.0)
        with pytest.raises(ps.Error, match="sim: frame 10 is at time 0 s, after frame 9 at"):
            spool.add_frame(late)
        no_width = dict(frames[-1], time=1.0)
        del no_width["width"]
        with pytest.raises(ps.Error, match="sim: frame 10 has no width array, but other frames have one"):
            spool.add_frame(no_width)
        assert spool.frames == 10
        # Ids not stored still order the frames and give the velocity; dropped, they do neither.
        ps.cook_particles(spool, tmp_path / "ids.pstream", fps=24, name="sim")
        spool.drop_ids()
        ps.cook_particles(spool, tmp_path / "no_ids.pstream", fps=24, name="sim")
        assert (tmp_path / "no_ids.pstream").read_bytes() != (tmp_path / "ids.pstream").read_bytes()
        ps.cook_particles([{k: v for k, v in f.items() if k != "id"} for f in frames], tmp_path / "list_no_ids.pstream",
                          fps=24, name="sim")
        assert (tmp_path / "no_ids.pstream").read_bytes() == (tmp_path / "list_no_ids.pstream").read_bytes()
    assert list(folder.iterdir()) == []
    with pytest.raises(ps.Error, match="closed"):
        spool.add_frame(frames[0])
    with pytest.raises(ps.Error, match="cannot make the frame spool's temporary file there"):
        ps.FrameSpool("sim", tmp_path / "missing")
