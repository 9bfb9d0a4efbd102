"""The module over http(s):// URLs (CTest Python.OverHttp runs this under
tests/http/with_server.sh faulty, which sets PSTREAM_TEST_URL_BASE)."""
import os
import pathlib

import numpy as np
import pytest

import particlestream as ps

BASE = os.environ.get("PSTREAM_TEST_URL_BASE")
DATA = pathlib.Path(os.environ.get("PSTREAM_TEST_DATA", "tests/data"))
pytestmark = pytest.mark.skipif(not BASE, reason="needs tests/http/with_server.sh (CTest Python.OverHttp)")


def url(path, faults=""):
    return BASE + faults + str(pathlib.Path(path).resolve())


def test_clip_and_player_open_urls_and_equal_the_file():
    clip_path = DATA / "pstream" / "sparks_particle_v3.pstream"
    local, remote = ps.Clip(str(clip_path)), ps.Clip(url(clip_path, "/~fail=503x1"))
    assert remote.frame_count == local.frame_count
    for f in range(local.frame_count):
        np.testing.assert_array_equal(remote.read_frame(f), local.read_frame(f))
    player = ps.Player([url(clip_path)], blocking=True)
    player.play()
    player.update(0)
    np.testing.assert_array_equal(player.frame(0), local.read_frame(0))


def test_a_missing_url_raises_particlestream_error():
    with pytest.raises(ps.Error, match="HTTP 404"):
        ps.Clip(url(DATA / "pstream" / "no_such.pstream"))


def test_an_alembic_cache_at_a_url_reads_and_cooks_as_the_file(tmp_path):
    abc = DATA / "sims" / "blender_sparks.abc"
    local, remote = ps.Archive(str(abc)), ps.Archive(url(abc, "/~fail=503x1"))
    name = local.points()[0]
    assert remote.points() == local.points()
    assert remote.num_samples(name) == local.num_samples(name)
    for t in range(local.num_samples(name)):
        np.testing.assert_array_equal(remote.positions(name, t), local.positions(name, t))
        np.testing.assert_array_equal(remote.ids(name, t), local.ids(name, t))
    ps.cook(str(abc), str(tmp_path / "local.pstream"))
    ps.cook(url(abc), str(tmp_path / "remote.pstream"))
    assert (tmp_path / "remote.pstream").read_bytes() == (tmp_path / "local.pstream").read_bytes()
