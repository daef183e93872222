"""Point caches read for deforming colliders: a rest mesh's vertices over time, from the files pipelines export.

API (three calls and two records):

- `read_point_cache(spec, base, vertex_count) -> PointCache`: `spec` is a path relative to `base` (the
  recipe's folder) to a `.pc2`, `.mdd` or `.usd`/`.usdc`/`.usda` file, or a glob (`*`, `?`, `[...]`) of
  per-frame `.obj`/`.ply` files with the same vertex count, or a folder of them (its files of the one
  mesh suffix it holds). Every frame must have `vertex_count` points.
- `PointCache`: `positions` (F, V, 3) float64 (read-only) in the file's frame order, `fps` and
  `start_frame` (None when the file does not say), `frame_step`, `source`.
- `cache_timing(cache, sim_fps, sim_start_frame, fps=None, start_frame=None) -> CacheTiming`: where the
  cache's frames sit on the simulation's clock; `fps` / `start_frame` (the recipe's keys) override the
  file's, and when neither says, the simulation's are taken.
- `check_cache_covers(cache, timing, frames)`: MeshLoadError (one line: the cache's frames and what the
  run needs) when a run of `frames` frames would go past the cache's last frame.
- `sample(cache, timing, time, out=None) -> (V, 3)`: positions at simulation time `time` (s).

Time convention. Cache frame `i` (from 0) is at scene frame `start_frame + i * frame_step` of the
cache's own time line, `fps` scene frames a second; scene seconds are scene frame / fps, as in the MDD
times our exporter writes. The simulation's frame index `k` (0: the rest pose, at simulation time
`k / sim_fps`) is scene frame `sim_start_frame + k`, so simulation time `t` is at scene second
`sim_start_frame / sim_fps + t`, and with the same fps cache frame `i` is at simulation time
`(start_frame + i * frame_step - sim_start_frame) / fps`: every output frame meets the cache frame of
the same scene frame number, the rest state (t = 0) the one at the simulation's start frame. Between
two cache frames positions are interpolated linearly; before the first frame the first is held, past
the last the last (`check_cache_covers` refuses a run that would need it).

What each format says:

- PC2 (layout in `meshdeform.export.pc2`): no fps; `start_frame` from the header; the header's
  sample rate is the frame step between samples (1.0: one sample a frame).
- MDD (layout in `meshdeform.export.mdd`): times in seconds; when there are two or more and they are
  evenly spaced, `fps = (F - 1) / (t_last - t0)`, i.e. 1 / (t1 - t0) (snapped to an integer or an NTSC
  rate k * 1000/1001 within the float32 precision of the times) and `start_frame = t0 * fps` (snapped to
  an integer likewise). All equal times (some writers write zeros) or a single frame say nothing; uneven
  or decreasing times are refused.
- USD: the first `UsdGeom.Mesh` (in stage traversal order) with time-sampled `points` of
  `vertex_count` points; `fps` is the stage's timeCodesPerSecond (None when the layer authors neither it
  nor framesPerSecond), `start_frame` the first time code, `frame_step` the spacing of the time codes
  (uneven spacing is refused). Points are taken as authored: in the prim's own space and the stage's up
  axis, with no transform applied.
- OBJ/PLY sequences (read with `meshdeform.io.load`): a file's frame number is the last number in its
  name (`body.1001.obj`, `frame_12.ply`); files are sorted by it (frame_2 before frame_10), their
  numbers must be evenly spaced (a missing frame is refused), `start_frame` is the first number,
  `frame_step` the spacing, no fps. The faces may differ between files, only the count of vertices is
  checked.

Positions are as stored (no up-axis conversion). Every value must be finite and within
`meshdeform.mesh.MAX_COORDINATE`. A path never leads out of `base`: absolute paths, `..` that leave it
and symlinks resolving outside it are refused. Broken input raises `MeshLoadError` with one line
naming the file, the place in it (byte offset, frame or sample) and what is wrong.
"""

from __future__ import annotations

import glob
import itertools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from meshdeform.errors import MeshLoadError
from meshdeform.export.mdd import MDD_FLOAT, MDD_HEADER, mdd_bytes
from meshdeform.export.pc2 import PC2_FLOAT, PC2_HEADER, PC2_MAGIC, pc2_bytes
from meshdeform.io import MESH_SUFFIXES, load
from meshdeform.io.files import special_file_kind
from meshdeform.mesh import MAX_COORDINATE

__all__ = [
    "CACHE_SUFFIXES",
    "CacheTiming",
    "PointCache",
    "cache_timing",
    "check_cache_covers",
    "read_point_cache",
    "sample",
]

#: suffixes of single-file caches (any case); anything with a glob character is a frame sequence
CACHE_SUFFIXES = (".pc2", ".mdd", ".usd", ".usdc", ".usda")
_GLOB_CHARACTERS = frozenset("*?[")
_FLOAT32_EPS = float(np.finfo(np.float32).eps)
# a fractional cache index this close to an integer is that integer (time = k * dt rounding)
_INDEX_SNAP = 1e-9
# float32 values read at a time (16 MB) when a cache's floats are converted to float64
_CHUNK_VALUES = 1 << 22


@dataclass(frozen=True, eq=False)
class PointCache:
    """A vertex animation read from a file.

    positions: (F, V, 3) float64, read-only, F >= 1 frames in the file's order.
    fps: scene frames per second of the cache's time line, None when the file does not say.
    start_frame: scene frame of cache frame 0, None when the file does not say.
    frame_step: scene frames between consecutive cache frames (PC2's sample rate; 1.0 for most).
    source: the file read (for a sequence, the first frame's file).

    Compared and hashed by identity (the positions are an array).
    """

    positions: np.ndarray
    fps: float | None
    start_frame: float | None
    source: Path
    frame_step: float = 1.0

    @property
    def frame_count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[1])


@dataclass(frozen=True)
class CacheTiming:
    """Where a cache's frames sit on a simulation's clock (module docstring: time convention).

    fps, start_frame, frame_step: the cache's, resolved (recipe, else file, else the simulation's).
    sim_fps, sim_start_frame: the simulation's frames per second and the scene frame of its rest pose.
    """

    fps: float
    start_frame: float
    frame_step: float
    sim_fps: float
    sim_start_frame: float

    def scene_frame(self, time: float) -> float:
        """The scene frame (in the cache's fps) at simulation time `time` (s)."""
        return (self.sim_start_frame + float(time) * self.sim_fps) * (self.fps / self.sim_fps)

    def index(self, time: float) -> float:
        """The fractional cache frame index at simulation time `time` (s), not clamped; within 1e-9 of an
        integer it is that integer, so that a frame's time gives that cache frame exactly."""
        index = (self.scene_frame(time) - self.start_frame) / self.frame_step
        nearest = round(index)
        return float(nearest) if abs(index - nearest) <= _INDEX_SNAP else index


def cache_timing(
    cache: PointCache,
    sim_fps: float,
    sim_start_frame: float,
    fps: float | None = None,
    start_frame: float | None = None,
) -> CacheTiming:
    """The cache's timing on a simulation at `sim_fps` whose rest pose is scene frame `sim_start_frame`.

    `fps` / `start_frame` (the recipe's) override the file's; where neither says, the simulation's are
    taken. ValueError for a non-positive or non-finite fps.
    """
    resolved_fps = fps if fps is not None else cache.fps if cache.fps is not None else sim_fps
    start = start_frame if start_frame is not None else cache.start_frame
    start = sim_start_frame if start is None else start
    for name, value in (("fps", resolved_fps), ("sim_fps", sim_fps)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, not {value!r}")
    return CacheTiming(
        float(resolved_fps), float(start), float(cache.frame_step), float(sim_fps), float(sim_start_frame)
    )


def check_cache_covers(cache: PointCache, timing: CacheTiming, frames: int) -> None:
    """MeshLoadError (one line) when a run of `frames` output frames goes past the cache's last frame.

    The run's last substep ends at simulation time `frames / sim_fps`; a cache that starts after the
    run's start is accepted (its first frame is held).
    """
    needed = timing.index(frames / timing.sim_fps)
    last = cache.frame_count - 1
    if needed > last:
        first_frame = timing.start_frame
        last_frame = timing.start_frame + last * timing.frame_step
        raise MeshLoadError(
            f"{cache.source}: {cache.frame_count} frames (scene frames {first_frame:g} to {last_frame:g} at "
            f"{timing.fps:g} fps), but the run's {frames} frames at {timing.sim_fps:g} fps from frame "
            f"{timing.sim_start_frame:g} need it up to scene frame {timing.scene_frame(frames / timing.sim_fps):g}"
        )


def sample(cache: PointCache, timing: CacheTiming, time: float, out: np.ndarray | None = None) -> np.ndarray:
    """Positions (V, 3) float64 at simulation time `time` (s): linear between the two neighbouring cache
    frames, the first frame before it, the last after it. Written into `out` (V, 3) when given."""
    positions = cache.positions
    last = positions.shape[0] - 1
    index = timing.index(time)
    if out is None:
        out = np.empty(positions.shape[1:], dtype=np.float64)
    if index <= 0.0 or last == 0:
        np.copyto(out, positions[0])
        return out
    if index >= last:
        np.copyto(out, positions[last])
        return out
    i0 = math.floor(index)
    weight = index - i0
    if weight == 0.0:
        np.copyto(out, positions[i0])
        return out
    np.subtract(positions[i0 + 1], positions[i0], out=out)
    out *= weight
    out += positions[i0]
    return out


# --- reading -------------------------------------------------------------------------------------------


def read_point_cache(spec: str, base: Path, vertex_count: int) -> PointCache:
    """Read the cache `spec` (relative to the folder `base`) of a rest mesh with `vertex_count` vertices.

    MeshLoadError (one line naming the file) when the path leaves `base`, the file is missing or not a
    regular file, or it cannot be read exactly, is empty, or a frame does not have `vertex_count` points.
    """
    base = Path(base)
    if not spec:
        raise MeshLoadError(f"{base}: the point cache's path is empty")
    if Path(spec).is_absolute():
        raise MeshLoadError(
            f"{spec}: an absolute path; a point cache is named relative to the recipe's folder {base.resolve()}"
        )
    if _GLOB_CHARACTERS.intersection(spec):
        return _read_sequence(spec, base, vertex_count)
    path = base / spec
    _check_inside(path, base, spec)
    if path.is_dir() and path.suffix.lower() not in CACHE_SUFFIXES:
        # a folder of per-frame files: its .obj (or .ply) files, as a glob would name them
        kinds = sorted({f.suffix for f in path.iterdir() if f.suffix.lower() in MESH_SUFFIXES})
        if len(kinds) != 1:
            found = "both .obj and .ply files" if kinds else "no .obj or .ply files"
            raise MeshLoadError(f"{path}: a point-cache folder needs per-frame .obj or .ply files; it holds {found}")
        return _read_sequence(f"{glob.escape(spec.rstrip('/'))}/*{kinds[0]}", base, vertex_count)
    suffix = path.suffix.lower()
    if suffix not in CACHE_SUFFIXES:
        shown = f"'{path.suffix}'" if path.suffix else "no extension"
        raise MeshLoadError(
            f"{path}: unknown point cache extension ({shown}); expected .pc2, .mdd, .usd, .usdc, .usda "
            "or a glob of .obj/.ply frames such as frame_*.obj"
        )
    _check_regular_file(path)
    if suffix == ".pc2":
        return _read_pc2(path, vertex_count)
    if suffix == ".mdd":
        return _read_mdd(path, vertex_count)
    return _read_usd(path, vertex_count)


def cache_files(spec: str, base: Path) -> list[Path]:
    """The files the cache `spec` (relative to the folder `base`) is read from, in a fixed order: the
    file itself, or the .obj/.ply files a glob or a folder names, sorted by name; only those inside
    `base` (what `read_point_cache` reads, without reading them). For deciding whether a result made
    with the cache is still up to date: a changed cache is another run."""
    base = Path(base)
    if not spec or Path(spec).is_absolute():
        return []
    root = base.resolve()
    if _GLOB_CHARACTERS.intersection(spec):
        try:
            found = sorted(base.glob(spec))
        except (ValueError, NotImplementedError):
            return []
    elif (base / spec).is_dir() and (base / spec).suffix.lower() not in CACHE_SUFFIXES:
        found = sorted(f for f in (base / spec).iterdir() if f.suffix.lower() in MESH_SUFFIXES)
    else:
        found = [base / spec]
    return [path for path in found if path.is_file() and path.resolve().is_relative_to(root)]


def _check_inside(path: Path, base: Path, spec: str) -> None:
    """Refuse a path that resolves (`..`, symlinks) outside `base`."""
    root = base.resolve()
    if not path.resolve().is_relative_to(root):
        raise MeshLoadError(f"{path}: leaves the recipe's folder {root} ('{spec}'); a point cache must be inside it")


def _check_regular_file(path: Path) -> None:
    if (kind := special_file_kind(path)) is not None:
        raise MeshLoadError(f"{path}: is {kind}, not a point cache file")
    if path.is_dir():
        raise MeshLoadError(f"{path}: is a directory, not a point cache file")
    if not path.is_file():
        raise MeshLoadError(f"{path}: no such file")


def _first_bad(positions: np.ndarray) -> tuple[int, int] | None:
    """(frame, vertex) of the first non-finite value or value beyond MAX_COORDINATE in (F, V, 3), or None."""
    if not positions.size or (positions.max() <= MAX_COORDINATE and positions.min() >= -MAX_COORDINATE):
        return None  # NaN fails both comparisons: only then is the array searched
    bad = ~np.isfinite(positions) | (np.abs(positions) > MAX_COORDINATE)
    frame, vertex, _ = np.unravel_index(int(np.argmax(bad)), bad.shape)
    return int(frame), int(vertex)


def _bad_value(value: np.ndarray) -> str:
    if not np.isfinite(value).all():
        return "a non-finite position"
    return f"position {value.tolist()} beyond the limit of {MAX_COORDINATE:g} for a coordinate"


def _read_frames(path: Path, dtype: str, offset: int, frames: int, points: int, place: str) -> np.ndarray:
    """(frames, points, 3) float64 (read-only) from the float32 x y z at byte `offset`, read a few frames
    at a time (no second copy of the whole cache); non-finite or huge values are refused, `place`
    ("sample", "frame") naming the frame."""
    positions = np.empty((frames, points, 3), dtype=np.float64)
    chunk = max(1, _CHUNK_VALUES // max(1, 3 * points))
    with open(path, "rb") as handle:
        handle.seek(offset)
        for first in range(0, frames, chunk):
            count = min(chunk, frames - first)
            values = np.fromfile(handle, dtype=dtype, count=count * points * 3)
            if values.size != count * points * 3:  # the file changed since its size was checked
                raise MeshLoadError(f"{path}: byte {offset}: the file ends early (truncated while read?)")
            positions[first : first + count] = values.reshape(count, points, 3)
    if (bad := _first_bad(positions)) is not None:
        frame, vertex = bad
        raise MeshLoadError(
            f"{path}: byte {offset + (frame * points + vertex) * 12}: {place} {frame}, vertex {vertex}: "
            f"{_bad_value(positions[frame, vertex])}"
        )
    positions.flags.writeable = False
    return positions


def _size_message(path: Path, size: int, expected: int, what: str) -> MeshLoadError:
    kind = "truncated" if size < expected else "trailing bytes"
    return MeshLoadError(f"{path}: byte {min(size, expected)}: {size} bytes, {what} make {expected} ({kind})")


def _read_pc2(path: Path, vertex_count: int) -> PointCache:
    size = path.stat().st_size
    if size < PC2_HEADER.size:
        raise MeshLoadError(f"{path}: byte {size}: {size} bytes, too short for the {PC2_HEADER.size}-byte PC2 header")
    with open(path, "rb") as handle:
        head = handle.read(PC2_HEADER.size)
    magic, version, points, start, rate, samples = PC2_HEADER.unpack(head)
    if magic != PC2_MAGIC:
        raise MeshLoadError(f"{path}: byte 0: no POINTCACHE2 signature, not a PC2 point cache")
    if version != 1:
        raise MeshLoadError(f"{path}: byte 12: PC2 version {version}, only version 1 is read")
    if points != vertex_count:
        raise MeshLoadError(f"{path}: byte 16: {points} points, the rest mesh has {vertex_count} vertices")
    if not math.isfinite(start):
        raise MeshLoadError(f"{path}: byte 20: start frame {start}, not a finite number")
    if not (math.isfinite(rate) and rate > 0):
        raise MeshLoadError(f"{path}: byte 24: sample rate {rate} (frames between samples), not a positive number")
    if samples <= 0:
        raise MeshLoadError(f"{path}: byte 28: {samples} samples, a point cache needs at least one")
    expected = pc2_bytes(samples, points)
    if size != expected:
        raise _size_message(path, size, expected, f"the header's {samples} samples of {points} points")
    positions = _read_frames(path, PC2_FLOAT, PC2_HEADER.size, samples, points, "sample")
    return PointCache(positions, fps=None, start_frame=float(start), source=path, frame_step=float(rate))


def _read_mdd(path: Path, vertex_count: int) -> PointCache:
    size = path.stat().st_size
    if size < MDD_HEADER.size:
        raise MeshLoadError(f"{path}: byte {size}: {size} bytes, too short for the {MDD_HEADER.size}-byte MDD header")
    with open(path, "rb") as handle:
        frames, points = MDD_HEADER.unpack(handle.read(MDD_HEADER.size))
    if frames <= 0:
        raise MeshLoadError(f"{path}: byte 0: {frames} frames, a point cache needs at least one")
    if points != vertex_count:
        raise MeshLoadError(f"{path}: byte 4: {points} points, the rest mesh has {vertex_count} vertices")
    expected = mdd_bytes(frames, points)
    if size != expected:
        raise _size_message(path, size, expected, f"the header's {frames} frames of {points} points")
    times = np.fromfile(path, dtype=MDD_FLOAT, count=frames, offset=MDD_HEADER.size).astype(np.float64)
    offset = MDD_HEADER.size + 4 * frames
    if not np.isfinite(times).all():
        bad = int(np.argmin(np.isfinite(times)))
        raise MeshLoadError(f"{path}: byte {MDD_HEADER.size + 4 * bad}: frame {bad}: time {times[bad]}, not finite")
    fps, start = _mdd_timing(path, times)
    positions = _read_frames(path, MDD_FLOAT, offset, frames, points, "frame")
    return PointCache(positions, fps=fps, start_frame=start, source=path)


def _snap(value: float, candidates: tuple[float, ...], tolerance: float) -> float:
    """The candidate nearest `value` when it is within `tolerance`, else `value`."""
    nearest = min(candidates, key=lambda c: abs(c - value))
    return nearest if abs(nearest - value) <= tolerance else value


def _mdd_timing(path: Path, times: np.ndarray) -> tuple[float | None, float | None]:
    """(fps, start_frame) from an MDD's times in seconds (float64 of the float32 read): module docstring."""
    if times.size < 2 or np.all(times == times[0]):
        return None, None
    steps = np.diff(times)
    if np.any(steps <= 0):
        bad = int(np.argmax(steps <= 0)) + 1
        raise MeshLoadError(
            f"{path}: byte {MDD_HEADER.size + 4 * bad}: frame {bad}: time {times[bad]:g} s after {times[bad - 1]:g} s; "
            "MDD times must increase"
        )
    span = float(times[-1] - times[0])
    # a float32 time is within half a unit in the last place: allow one unit at the largest time
    grain = _FLOAT32_EPS * float(np.abs(times).max())
    even = times[0] + np.arange(times.size) * (span / (times.size - 1))
    off = np.abs(times - even)
    if np.any(off > 2 * grain):
        bad = int(np.argmax(off))
        raise MeshLoadError(
            f"{path}: byte {MDD_HEADER.size + 4 * bad}: frame {bad}: time {times[bad]:g} s, the times are not "
            f"evenly spaced (frame 0 at {times[0]:g} s, frame {times.size - 1} at {times[-1]:g} s)"
        )
    fps = (times.size - 1) / span
    relative = 2 * grain / span
    fps = _snap(fps, (float(round(fps)), round(fps * 1.001) * 1000.0 / 1001.0), fps * relative)
    start = float(times[0]) * fps
    start = _snap(start, (float(round(start)),), 2 * grain * fps + abs(start) * relative)
    return fps, start


def _read_usd(path: Path, vertex_count: int) -> PointCache:
    from meshdeform.export.usd import start_usd

    start_usd()
    from pxr import Usd, UsdGeom

    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr raises Tf.ErrorException with USD's own text
        text = str(exc).strip().splitlines()
        raise MeshLoadError(
            f"{path}: cannot open the USD stage: {text[-1].strip() if text else 'unknown error'}"
        ) from None
    if stage is None:
        raise MeshLoadError(f"{path}: cannot open the USD stage")
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    if not meshes:
        raise MeshLoadError(f"{path}: no UsdGeom.Mesh in the stage")
    animated = [(m, m.GetPointsAttr().GetTimeSamples()) for m in meshes]
    animated = [(m, codes) for m, codes in animated if codes]
    if not animated:
        raise MeshLoadError(f"{path}: no UsdGeom.Mesh with time-sampled points (a stage without animation)")
    chosen = None
    counts = []
    for geom, codes in animated:
        first = geom.GetPointsAttr().Get(codes[0])
        count = 0 if first is None else len(first)
        counts.append(f"{geom.GetPath()} {count}")
        if count == vertex_count:
            chosen = geom, codes
            break
    if chosen is None:
        raise MeshLoadError(
            f"{path}: no time-sampled UsdGeom.Mesh has {vertex_count} points, the rest mesh's vertex count "
            f"({'; '.join(counts)})"
        )
    geom, codes = chosen
    prim = geom.GetPath()
    codes = [float(c) for c in codes]
    step = codes[1] - codes[0] if len(codes) > 1 else 1.0
    tolerance = 1e-9 * max(1.0, abs(codes[0]), abs(codes[-1]))
    for i in range(2, len(codes)):
        if abs(codes[i] - codes[i - 1] - step) > tolerance:
            raise MeshLoadError(
                f"{path}: {prim}.points: time sample {i} at time code {codes[i]:g} after {codes[i - 1]:g}, the "
                f"time samples are not evenly spaced (they start {codes[0]:g}, {codes[1]:g})"
            )
    attr = geom.GetPointsAttr()
    positions = np.empty((len(codes), vertex_count, 3), dtype=np.float64)
    for i, code in enumerate(codes):
        points = attr.Get(code)
        values = np.asarray(points if points is not None else [], dtype=np.float64)
        if values.shape != (vertex_count, 3):
            raise MeshLoadError(
                f"{path}: {prim}.points: time sample {i} (time code {code:g}): {len(values)} points, "
                f"the rest mesh has {vertex_count} vertices"
            )
        positions[i] = values
    if (bad := _first_bad(positions)) is not None:
        frame, vertex = bad
        raise MeshLoadError(
            f"{path}: {prim}.points: time sample {frame} (time code {codes[frame]:g}), point {vertex}: "
            f"{_bad_value(positions[frame, vertex])}"
        )
    positions.flags.writeable = False
    layer = stage.GetRootLayer()
    says_fps = layer.HasTimeCodesPerSecond() or layer.HasFramesPerSecond()
    fps = float(stage.GetTimeCodesPerSecond()) if says_fps else None
    return PointCache(positions, fps=fps, start_frame=codes[0], source=path, frame_step=float(step))


# --- OBJ/PLY frame sequences ------------------------------------------------------------------------------

_NUMBER = re.compile(r"\d+")


def _read_sequence(spec: str, base: Path, vertex_count: int) -> PointCache:
    pattern = base / spec
    root = base.resolve()
    try:
        matches = sorted(base.glob(spec))
    except (ValueError, NotImplementedError) as exc:
        raise MeshLoadError(f"{pattern}: not a usable glob pattern ({exc})") from None
    if not matches:
        raise MeshLoadError(f"{pattern}: the pattern matches no file")
    numbered: list[tuple[int, Path]] = []
    for match in matches:
        if not match.resolve().is_relative_to(root):
            raise MeshLoadError(
                f"{match}: leaves the recipe's folder {root} (pattern '{spec}'); a point cache must be inside it"
            )
        if match.suffix.lower() not in MESH_SUFFIXES:
            raise MeshLoadError(
                f"{match}: matched by '{spec}' but not an .obj or .ply file; end the pattern with .obj or .ply"
            )
        numbers = _NUMBER.findall(match.name)
        if not numbers:
            raise MeshLoadError(f"{match}: matched by '{spec}' but its name has no frame number")
        numbered.append((int(numbers[-1]), match))
    numbered.sort(key=lambda item: item[0])
    for (a, first), (b, second) in itertools.pairwise(numbered):
        if a == b:
            raise MeshLoadError(f"{second}: frame {b} again (also {first.name}); one file a frame")
    step = numbered[1][0] - numbered[0][0] if len(numbered) > 1 else 1
    for (a, _), (b, second) in itertools.pairwise(numbered):
        if b - a != step:
            raise MeshLoadError(
                f"{second}: frame {b} after frame {a}, the frames of '{spec}' go by {step} (a missing frame?)"
            )
    positions = np.empty((len(numbered), vertex_count, 3), dtype=np.float64)
    for i, (number, path) in enumerate(numbered):
        mesh = load(path)
        if mesh.vertex_count != vertex_count:
            raise MeshLoadError(
                f"{path}: frame {number}: {mesh.vertex_count} vertices, the rest mesh has {vertex_count}"
            )
        positions[i] = mesh.positions
    positions.flags.writeable = False
    return PointCache(
        positions, fps=None, start_frame=float(numbered[0][0]), source=numbered[0][1], frame_step=float(step)
    )
