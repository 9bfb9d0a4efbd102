"""Type stubs for the `particlestream` module (python/module.cpp), so editors complete it.

Read Alembic point caches with ParticleStream's own reader, cook them to .pstream, and play them
back. Every failure of the library raises `particlestream.Error` with the library's message (the
same words as the `pstream` command line's).
"""
import os
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, os.PathLike]

class Error(RuntimeError):
    """A failure of the library: the file, offset or frame, and what was expected."""

class Archive:
    """An Alembic archive (our reader), mapped. Arrays are read-only views of the file."""
    def __init__(self, path: PathLike) -> None: ...
    @property
    def name(self) -> str: ...
    @property
    def start_end_time(self) -> Tuple[float, float]:
        """The archive's start and end times, by the official reader's rule."""
    def points(self) -> List[str]:
        """The full names of the points objects."""
    def num_samples(self, name: str) -> int: ...
    def count(self, name: str, sample: int) -> int: ...
    def time(self, name: str, sample: int) -> float: ...
    def positions(self, name: str, sample: int) -> npt.NDArray[np.float32]:
        """Positions (N, 3) float32, object space: a view of the file (no copy)."""
    def ids(self, name: str, sample: int) -> npt.NDArray[np.uint64]:
        """Ids (N,) uint64 (empty when the object has none)."""
    def velocities(self, name: str, sample: int) -> npt.NDArray[np.float32]:
        """Velocities (N, 3) float32 (empty when the object has none)."""
    def attributes(self, name: str) -> List[str]:
        """The object's geometry parameters: .widths, then its arbGeomParams (Cd, age, ...)."""
    def attribute(
        self, name: str, attribute: str, sample: int, expand: bool = True
    ) -> Union[np.ndarray, List[str]]:
        """A geometry parameter at a sample, as the official reader gives it: numpy (N, extent) or
        (N,), or a list of str. 'widths' names .widths. expand=False: indexed values as stored."""

class Clip:
    """A .pstream read directly (every frame decodes on request)."""
    def __init__(self, path: PathLike) -> None: ...
    @property
    def frame_count(self) -> int: ...
    @property
    def fps(self) -> float: ...
    @property
    def record_size(self) -> int: ...
    @property
    def max_count(self) -> int:
        """The most particles in any frame: room enough for `read_frame(f, out=...)`."""
    @property
    def layout(self) -> List[Tuple[str, str, int, int]]:
        """[(name, type, components, offset)] of the record's attributes."""
    @property
    def dtype(self) -> np.dtype:
        """The numpy structured dtype of a record: one field per attribute."""
    @property
    def frames_decoded(self) -> int:
        """The frames `read_frame` has decoded so far, those decoded on the way to the ones asked
        for included: read in order, one a frame; read going back, a few a frame (the first read
        back keeps 3 saved decoder states from then on)."""
    def count(self, frame: int) -> int: ...
    def time(self, frame: int) -> float: ...
    def read_frame(self, frame: int, out: Optional[np.ndarray] = None) -> np.ndarray:
        """Frame `frame`'s records as a structured array of `dtype`: a new array, or, with `out` (a
        writable, contiguous 1-D array of `dtype` with room for the frame, e.g.
        `numpy.empty(clip.max_count, clip.dtype)`), the view `out[:count]` of it, so that a loop
        over frames allocates no records."""

class Player:
    """Playback of one or more clips (the C++ playback::Player): fixed memory, frames decoded on
    an IO worker, interpolated between cached frames."""
    def __init__(
        self,
        paths: Sequence[PathLike],
        interpolation: str = "hermite",
        blocking: bool = True,
        loop: bool = True,
        sort: str = "none",
        cache_seconds: float = 1.0,
        saved_states: int = 3,
    ) -> None:
        """saved_states: decoder states kept for playing backwards (and seeking back) within a
        keyframe group, about 8 bytes per particle and coded word each; 0 decodes every frame
        shown backwards from its keyframe (docs/playback.md, "Going back")."""
    @property
    def clip_count(self) -> int: ...
    def play(self) -> None: ...
    def pause(self) -> None: ...
    def seek(self, time: float) -> None: ...
    def set_speed(self, speed: float) -> None:
        """0 holds, 0.25 is slow motion, negative plays backwards."""
    def set_loop(self, loop: bool) -> None: ...
    def set_range(self, start: float, end: float) -> None: ...
    def update(self, dt: float, view: Optional[npt.NDArray[np.float32]] = None) -> dict:
        """One host frame: advances every clip by dt seconds (and sorts for the 4x4 `view`)."""
    def frame(self, clip: int = 0) -> np.ndarray:
        """The clip's current (interpolated) records, valid until the next update()."""
    def order(self, clip: int = 0) -> npt.NDArray[np.uint32]:
        """The draw order of frame()'s records (empty: stored order)."""
    def time(self, clip: int = 0) -> float: ...
    def stats(self, clip: int = 0) -> dict: ...

def cook(
    input: PathLike,
    output: PathLike,
    fps: float = 0.0,
    codec: str = "particle",
    attributes: List[str] = ...,
    object: str = "",
    interpolate: bool = False,
    progress: Optional[Callable[[int, int], None]] = None,
    error: str = "1e-4",
    scale_error: str = "1%",
    attribute_error: str = "1e-3",
    frames: str = "",
    merge: bool = False,
    scale_from: str = "widths",
    color_from: str = "auto",
    velocity: bool = True,
    keyframe_interval: int = 64,
    drop_invalid: bool = False,
    store_velocity: bool = False,
) -> dict:
    """Cooks an Alembic archive (or a PLY sequence) into a .pstream with the options of
    `pstream cook`; returns the report (frames, particles, file_bytes, seconds, object: what was
    cooked, mesh_vertices: whether it is a mesh's vertices, as an archive without points objects
    and with one mesh cooks). progress(done, total) follows the whole cook: each frame counts once
    for each pass over the frames (twice with the particle codec, whose first pass gathers the
    statistics its grids need), so done only grows and ends at total."""

class FrameSpool:
    """Frames added one at a time and kept on disk (an unnamed temporary file in `folder`) until
    cook_particles(spool, ...) cooks them: for simulations larger than memory."""
    def __init__(self, name: str = "particles", folder: Optional[PathLike] = None) -> None: ...
    def add_frame(self, frame: Dict[str, Any]) -> None: ...
    def drop_ids(self) -> None: ...
    @property
    def frames(self) -> int: ...
    @property
    def bytes(self) -> int: ...
    def close(self) -> None: ...
    def __enter__(self) -> "FrameSpool": ...
    def __exit__(self, *args: Any) -> None: ...

def cook_particles(
    frames: Union[FrameSpool, Sequence[Dict[str, Any]]],
    output: PathLike,
    fps: float = 24.0,
    name: str = "particles",
    object: str = "",
    codec: str = "particle",
    attributes: List[str] = ...,
    progress: Optional[Callable[[int, int], None]] = None,
    error: str = "1e-4",
    scale_error: str = "1%",
    attribute_error: str = "1e-3",
    frame_range: str = "",
    scale_from: str = "widths",
    color_from: str = "auto",
    velocity: bool = True,
    keyframe_interval: int = 64,
    drop_invalid: bool = False,
    store_velocity: bool = False,
) -> dict:
    """Cooks particles held in memory into a .pstream, as cook() cooks a file. Each frame is a dict
    with 'time' (seconds) and 'position' (N x 3), and optionally 'width' (N diameters), 'velocity'
    (N x 3, per second), 'id' (N, stable) and 'color' (N x 4, linear RGBA in 0..1). Returns the
    report (frames, particles, file_bytes, seconds, object, mesh_vertices); progress(done, total)
    as cook()'s."""

def describe_ply(file: PathLike) -> dict:
    """Describes the numbered PLY sequence `file` belongs to, as `pstream info frame.0001.ply`
    does: encoding, first_number, files (each {file, count}), bytes, properties ((name, type)
    pairs) and what a cook takes (scale_from, scale_is_diameter, color, velocity, ids)."""

def export(
    clip: str,
    output: PathLike,
    progress: Optional[Callable[[int, int], None]] = None,
    frames: str = "",
) -> dict:
    """Writes a .pstream (a path or URL) back out for a DCC, as `pstream export` does: NAME.abc an
    Alembic points cache, NAME.ply a binary PLY sequence (NAME.0001.ply ...); frames 'A:B' exports
    the clip's frames from A up to but not including B, 'N' frame N alone. Returns the report:
    format ('alembic' or 'ply'), frames, first (the file or the sequence's first), bytes_written."""

def verify(clip: str, against: str = "") -> dict:
    """Checks a .pstream as `pstream verify` does (and with `against`, each attribute against the
    source within its own bound; a derived velocity reports its rms_error); returns the report:
    ok, frames, chunks_verified, errors, source, frames_compared, particles_compared, attributes
    (each with name, max_error, bound, relative, exact, ok, and but for positions distinct_clip,
    distinct_source, distinct_counted_up_to and kept_apart: how many of the source's values the
    bound keeps distinct)."""
