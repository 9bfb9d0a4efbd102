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
