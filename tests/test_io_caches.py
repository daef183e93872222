"""Point caches for deforming colliders (meshdeform/io/caches.py): PC2, MDD, USD and OBJ/PLY sequences.

PC2 and MDD files are written here with struct from the published byte layouts (not with the project's
layout constants), USD stages with pxr directly, and frame sequences with meshdeform.io's writers; a
run exported by the project's own exporters is read back as a cache to check the time convention
end to end. Positions are multiples of 1/8, exact in float32.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest
from factories import grid_sheet
from shared_meshes import MESHES, needs_meshes

from meshdeform.errors import MeshLoadError
from meshdeform.export import ExportContext, ExportSession, FrameData
from meshdeform.io import save
from meshdeform.io.caches import cache_timing, check_cache_covers, read_point_cache, sample
from meshdeform.mesh import Mesh

FRAMES = 5


@pytest.fixture
def mesh() -> Mesh:
    return grid_sheet(3, 2)  # 6 vertices


def animation(mesh: Mesh, frames: int = FRAMES) -> np.ndarray:
    """(F, V, 3): frame i moves vertex j by (i, j, -i) / 8 from the rest."""
    i, j = np.meshgrid(
        np.arange(frames, dtype=np.float64), np.arange(mesh.vertex_count, dtype=np.float64), indexing="ij"
    )
    step = np.stack([i, j, -i], axis=2) / 8.0
    return mesh.positions[None] + step


def pc2_bytes(positions: np.ndarray, start: float = 1.0, rate: float = 1.0, version: int = 1) -> bytes:
    """PC2 from its published layout: 'POINTCACHE2\\0', int32 version, int32 points, float32 start,
    float32 sample rate, int32 samples, then little-endian float32 x y z."""
    samples, points = positions.shape[:2]
    head = struct.pack("<12siiffi", b"POINTCACHE2\0", version, points, start, rate, samples)
    return head + positions.astype("<f4").tobytes()


def mdd_bytes(positions: np.ndarray, times: np.ndarray) -> bytes:
    """MDD from its published layout: big-endian int32 frames, int32 points, float32 times, float32 x y z."""
    frames, points = positions.shape[:2]
    return struct.pack(">ii", frames, points) + np.asarray(times, ">f4").tobytes() + positions.astype(">f4").tobytes()


def write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def load_error(spec: str, base: Path, vertex_count: int) -> str:
    """The one-line message of the MeshLoadError reading `spec` raises."""
    with pytest.raises(MeshLoadError) as info:
        read_point_cache(spec, base, vertex_count)
    message = str(info.value)
    assert "\n" not in message
    return message


# --- reading -------------------------------------------------------------------------------------------


def test_pc2_reads_positions_start_and_sample_rate(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    write(tmp_path / "body.pc2", pc2_bytes(positions, start=1001.0, rate=2.0))
    cache = read_point_cache("body.pc2", tmp_path, mesh.vertex_count)
    assert cache.positions.dtype == np.float64 and cache.positions.shape == (FRAMES, 6, 3)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.fps is None  # PC2 has a frame step, not a rate
    assert cache.start_frame == 1001.0 and cache.frame_step == 2.0
    assert cache.source == tmp_path / "body.pc2"
    assert not cache.positions.flags.writeable


def test_mdd_reads_fps_and_start_from_its_times(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    times = (1001 + np.arange(FRAMES)) / 24.0
    write(tmp_path / "a.mdd", mdd_bytes(positions, times))
    cache = read_point_cache("a.mdd", tmp_path, mesh.vertex_count)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.fps == 24.0 and cache.start_frame == 1001.0 and cache.frame_step == 1.0
    # an NTSC rate is recognised through the float32 rounding of the times
    ntsc = 24000 / 1001
    write(tmp_path / "b.mdd", mdd_bytes(positions, np.arange(FRAMES) / ntsc))
    cache = read_point_cache("b.mdd", tmp_path, mesh.vertex_count)
    assert cache.fps == ntsc and cache.start_frame == 0.0
    # a long shot: the float32 times' rounding grows with them, the rates are still told apart
    for rate in (24.0, ntsc, 25.0, 30000 / 1001, 30.0, 60.0):
        long = np.repeat(positions[:1], 250, axis=0)
        write(tmp_path / "c.mdd", mdd_bytes(long, (1001 + np.arange(250)) / rate))
        cache = read_point_cache("c.mdd", tmp_path, mesh.vertex_count)
        assert (cache.fps, cache.start_frame) == (rate, 1001.0)


def test_read_a_frame_at_a_time(tmp_path: Path, mesh: Mesh, monkeypatch: pytest.MonkeyPatch) -> None:
    """Big caches are converted to float64 a few frames at a time: the same values as in one go."""
    import meshdeform.io.caches as caches

    positions = animation(mesh)
    write(tmp_path / "a.pc2", pc2_bytes(positions))
    write(tmp_path / "a.mdd", mdd_bytes(positions, np.arange(FRAMES) / 24.0))
    for chunk in (1, 40, 100):  # 18 values a frame: one frame a read, two, five
        monkeypatch.setattr(caches, "_CHUNK_VALUES", chunk)
        for name in ("a.pc2", "a.mdd"):
            np.testing.assert_array_equal(read_point_cache(name, tmp_path, mesh.vertex_count).positions, positions)


def test_mdd_without_timing(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    write(tmp_path / "zeros.mdd", mdd_bytes(positions, np.zeros(FRAMES)))
    cache = read_point_cache("zeros.mdd", tmp_path, mesh.vertex_count)
    assert cache.fps is None and cache.start_frame is None
    write(tmp_path / "one.mdd", mdd_bytes(positions[:1], [0.5]))
    cache = read_point_cache("one.mdd", tmp_path, mesh.vertex_count)
    assert cache.fps is None and cache.frame_count == 1


def test_mdd_uneven_or_decreasing_times_refused(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    write(tmp_path / "uneven.mdd", mdd_bytes(positions, [0.0, 0.1, 0.2, 0.35, 0.4]))
    message = load_error("uneven.mdd", tmp_path, mesh.vertex_count)
    assert "uneven.mdd" in message and "frame 3" in message and "evenly spaced" in message
    write(tmp_path / "back.mdd", mdd_bytes(positions, [0.0, 0.1, 0.05, 0.3, 0.4]))
    message = load_error("back.mdd", tmp_path, mesh.vertex_count)
    assert "back.mdd" in message and "frame 2" in message and "increase" in message


def usd_stage(path: Path, meshes: dict[str, np.ndarray], codes: list[float], tcps: float | None = 30.0) -> Path:
    """A stage with one UsdGeom.Mesh per entry, `points` sampled at `codes` ((F, V, 3) each)."""
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    if tcps is not None:
        stage.SetTimeCodesPerSecond(tcps)
    for name, positions in meshes.items():
        geom = UsdGeom.Mesh.Define(stage, f"/Root/{name}")
        geom.GetFaceVertexCountsAttr().Set(Vt.IntArray([3]))
        geom.GetFaceVertexIndicesAttr().Set(Vt.IntArray([0, 1, 2]))
        attr = geom.GetPointsAttr()
        for code, frame in zip(codes, positions, strict=True):
            attr.Set(Vt.Vec3fArray.FromNumpy(frame.astype(np.float32)), code)
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_usd_reads_the_mesh_with_the_rest_vertex_count(tmp_path: Path, mesh: Mesh, suffix: str) -> None:
    positions = animation(mesh)
    other = animation(grid_sheet(2, 2))  # 4 points: traversed first, not the rest mesh's count
    codes = [1001.0, 1003.0, 1005.0, 1007.0, 1009.0]
    usd_stage(tmp_path / f"s{suffix}", {"A_other": other, "B_body": positions}, codes)
    cache = read_point_cache(f"s{suffix}", tmp_path, mesh.vertex_count)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.fps == 30.0 and cache.start_frame == 1001.0 and cache.frame_step == 2.0


def test_usd_without_fps_or_samples(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    usd_stage(tmp_path / "nofps.usda", {"body": positions}, [1.0, 2.0, 3.0, 4.0, 5.0], tcps=None)
    assert read_point_cache("nofps.usda", tmp_path, mesh.vertex_count).fps is None
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(tmp_path / "static.usda"))
    UsdGeom.Mesh.Define(stage, "/Root/body").GetPointsAttr().Set(positions[0].astype(np.float32).tolist())
    stage.GetRootLayer().Save()
    message = load_error("static.usda", tmp_path, mesh.vertex_count)
    assert "static.usda" in message and "time-sampled" in message
    usd_stage(tmp_path / "uneven.usda", {"body": positions}, [1.0, 2.0, 3.0, 5.0, 6.0])
    message = load_error("uneven.usda", tmp_path, mesh.vertex_count)
    assert "uneven.usda" in message and "time sample 3 at time code 5 after 3" in message and "evenly" in message
    bad = positions.copy()
    bad[2, 5, 0] = np.nan
    usd_stage(tmp_path / "nan.usdc", {"body": bad}, [1.0, 2.0, 3.0, 4.0, 5.0])
    message = load_error("nan.usdc", tmp_path, mesh.vertex_count)
    assert "nan.usdc" in message and "time sample 2 (time code 3), point 5: a non-finite position" in message
    from pxr import Vt

    stage = Usd.Stage.CreateNew(str(tmp_path / "grows.usda"))
    points = UsdGeom.Mesh.Define(stage, "/Root/body").GetPointsAttr()
    points.Set(Vt.Vec3fArray.FromNumpy(positions[0].astype(np.float32)), 1.0)
    points.Set(Vt.Vec3fArray.FromNumpy(np.zeros((7, 3), np.float32)), 2.0)
    stage.GetRootLayer().Save()
    message = load_error("grows.usda", tmp_path, mesh.vertex_count)
    assert "grows.usda" in message and "time sample 1 (time code 2): 7 points, the rest mesh has 6" in message
    message = load_error("uneven.usda", tmp_path, 7)
    assert "uneven.usda" in message and "7 points" in message and "/Root/body 6" in message


def test_frame_sequence_in_natural_order(tmp_path: Path, mesh: Mesh) -> None:
    """frame_2 before frame_10; OBJ and PLY mixed; faces may differ, only the vertex count matters."""
    positions = animation(mesh, 12)
    folder = tmp_path / "body"
    folder.mkdir()
    for i, frame in enumerate(positions):
        suffix = ".ply" if i % 3 == 0 else ".obj"
        save(folder / f"frame_{i + 1}{suffix}", mesh, frame)
    triangles = grid_sheet(3, 2, triangles=True)
    save(folder / "frame_8.obj", triangles, positions[7])
    cache = read_point_cache("body/frame_*.[op][bl][jy]", tmp_path, mesh.vertex_count)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.fps is None and cache.start_frame == 1.0 and cache.frame_step == 1.0
    assert cache.source == folder / "frame_1.ply"


def test_a_folder_of_frames_is_its_sequence(tmp_path: Path, mesh: Mesh) -> None:
    """A folder names the sequence of its .obj (or .ply) files; their .mtl neighbours do not count."""
    positions = animation(mesh, 5)
    folder = tmp_path / "body frames"
    folder.mkdir()
    for i, frame in enumerate(positions):
        save(folder / f"body.{1001 + i}.obj", mesh, frame)
    (folder / "body.mtl").write_text("newmtl skin\n")
    cache = read_point_cache("body frames", tmp_path, mesh.vertex_count)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.start_frame == 1001.0
    save(folder / "body.1006.ply", mesh, positions[0])
    with pytest.raises(MeshLoadError, match=r"both \.obj and \.ply"):
        read_point_cache("body frames", tmp_path, mesh.vertex_count)
    (tmp_path / "empty").mkdir()
    with pytest.raises(MeshLoadError, match=r"no \.obj or \.ply"):
        read_point_cache("empty", tmp_path, mesh.vertex_count)


def test_frame_sequence_numbered_in_steps(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh, 3)
    for number, frame in zip((1000, 1002, 1004), positions, strict=True):
        save(tmp_path / f"body_v2.{number:04d}.obj", mesh, frame)
    cache = read_point_cache("body_v2.*.obj", tmp_path, mesh.vertex_count)
    np.testing.assert_array_equal(cache.positions, positions)
    assert cache.start_frame == 1000.0 and cache.frame_step == 2.0


def test_frame_sequence_refusals(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh, 4)
    for number in (1, 2, 4):
        save(tmp_path / f"f_{number}.obj", mesh, positions[number - 1])
    message = load_error("f_*.obj", tmp_path, mesh.vertex_count)
    assert "f_4.obj" in message and "frame 4 after frame 2" in message
    save(tmp_path / "f_3.obj", mesh, positions[2])
    save(tmp_path / "f_03.obj", mesh, positions[2])
    message = load_error("f_*.obj", tmp_path, mesh.vertex_count)
    assert "f_3.obj" in message and "f_03.obj" in message and "frame 3 again" in message
    (tmp_path / "f_03.obj").unlink()
    assert read_point_cache("f_*.obj", tmp_path, mesh.vertex_count).frame_count == 4
    message = load_error("f_*.obj", tmp_path, 7)
    assert "f_1.obj" in message and "6 vertices" in message and "7" in message
    (tmp_path / "f_1.mtl").write_text("newmtl a\n")
    message = load_error("f_*", tmp_path, mesh.vertex_count)
    assert "f_1.mtl" in message and "not an .obj or .ply" in message
    save(tmp_path / "g_a.obj", mesh)
    message = load_error("g_*.obj", tmp_path, mesh.vertex_count)
    assert "g_a.obj" in message and "no frame number" in message
    message = load_error("nothing_*.obj", tmp_path, mesh.vertex_count)
    assert "nothing_*.obj" in message and "matches no file" in message
    (tmp_path / "h_1.obj").write_text("v 0 0 0\nv nan 0 0\n")
    message = load_error("h_*.obj", tmp_path, mesh.vertex_count)
    assert "h_1.obj" in message


def test_paths_never_leave_the_folder(tmp_path: Path, mesh: Mesh) -> None:
    recipe_dir = tmp_path / "shot"
    recipe_dir.mkdir()
    (recipe_dir / "inner").mkdir()
    outside = write(tmp_path / "body.pc2", pc2_bytes(animation(mesh)))
    for i in range(2):
        save(tmp_path / f"out_{i}.obj", mesh)
    vc = mesh.vertex_count
    message = load_error(str(outside), recipe_dir, vc)
    assert str(outside) in message and "absolute" in message
    message = load_error("../body.pc2", recipe_dir, vc)
    assert "body.pc2" in message and "leaves the recipe's folder" in message
    message = load_error("inner/../../body.pc2", recipe_dir, vc)
    assert "leaves the recipe's folder" in message
    message = load_error("../out_*.obj", recipe_dir, vc)
    assert "out_0.obj" in message and "leaves the recipe's folder" in message
    message = load_error(str(tmp_path / "out_*.obj"), recipe_dir, vc)
    assert "absolute" in message
    os.symlink(outside, recipe_dir / "link.pc2")
    message = load_error("link.pc2", recipe_dir, vc)
    assert "link.pc2" in message and "leaves the recipe's folder" in message
    os.symlink(tmp_path, recipe_dir / "up")
    message = load_error("up/out_*.obj", recipe_dir, vc)
    assert "out_0.obj" in message and "leaves the recipe's folder" in message
    # inside the folder, `..` that comes back is fine
    write(recipe_dir / "body.pc2", pc2_bytes(animation(mesh)))
    assert read_point_cache("inner/../body.pc2", recipe_dir, vc).frame_count == FRAMES


def test_pc2_refusals(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    vc = mesh.vertex_count
    good = pc2_bytes(positions)
    cases = {
        "magic.pc2": (b"POINTCACHE3\0" + good[12:], "byte 0: no POINTCACHE2 signature"),
        "version.pc2": (pc2_bytes(positions, version=2), "byte 12: PC2 version 2"),
        "rate.pc2": (pc2_bytes(positions, rate=0.0), "byte 24: sample rate 0.0"),
        "short.pc2": (good[:20], "byte 20: 20 bytes, too short for the 32-byte PC2 header"),
        "truncated.pc2": (good[:-5], f"{len(good) - 5} bytes, the header's 5 samples of 6 points make {len(good)}"),
        "trailing.pc2": (good + b"\0" * 4, f"{len(good) + 4} bytes"),
        "empty.pc2": (pc2_bytes(positions[:0]), "byte 28: 0 samples"),
        "start.pc2": (pc2_bytes(positions, start=float("nan")), "byte 20: start frame nan"),
    }
    for name, (data, expected) in cases.items():
        write(tmp_path / name, data)
        message = load_error(name, tmp_path, vc)
        assert str(tmp_path / name) in message and expected in message, message
    assert "truncated" in load_error("truncated.pc2", tmp_path, vc)
    message = load_error("magic.pc2", tmp_path, vc)
    write(tmp_path / "count.pc2", good)
    message = load_error("count.pc2", tmp_path, vc + 1)
    assert "byte 16: 6 points, the rest mesh has 7 vertices" in message
    bad = positions.copy()
    bad[3, 4, 1] = np.inf
    write(tmp_path / "inf.pc2", pc2_bytes(bad))
    message = load_error("inf.pc2", tmp_path, vc)
    assert f"byte {32 + 3 * 6 * 12 + 4 * 12}: sample 3, vertex 4: a non-finite position" in message
    bad[3, 4, 1] = 1e20
    write(tmp_path / "huge.pc2", pc2_bytes(bad))
    assert "sample 3, vertex 4: position" in load_error("huge.pc2", tmp_path, vc)


def test_mdd_refusals(tmp_path: Path, mesh: Mesh) -> None:
    positions = animation(mesh)
    vc = mesh.vertex_count
    good = mdd_bytes(positions, np.arange(FRAMES) / 24.0)
    cases = {
        "short.mdd": (good[:6], "byte 6: 6 bytes, too short for the 8-byte MDD header"),
        "truncated.mdd": (good[:-1], f"{len(good) - 1} bytes, the header's 5 frames of 6 points make {len(good)}"),
        "none.mdd": (struct.pack(">ii", 0, vc), "byte 0: 0 frames"),
        "count.mdd": (good, "byte 4: 6 points, the rest mesh has 5 vertices"),
        "nan.mdd": (mdd_bytes(positions, [0.0, 0.1, np.nan, 0.3, 0.4]), "byte 16: frame 2: time nan"),
    }
    for name, (data, expected) in cases.items():
        write(tmp_path / name, data)
        message = load_error(name, tmp_path, vc - 1 if name == "count.mdd" else vc)
        assert str(tmp_path / name) in message and expected in message, message


def test_file_refusals(tmp_path: Path, mesh: Mesh) -> None:
    vc = mesh.vertex_count
    message = load_error("missing.pc2", tmp_path, vc)
    assert str(tmp_path / "missing.pc2") in message and "no such file" in message
    (tmp_path / "dir.mdd").mkdir()
    assert "is a directory" in load_error("dir.mdd", tmp_path, vc)
    save(tmp_path / "body.obj", mesh)
    message = load_error("body.obj", tmp_path, vc)
    assert "body.obj" in message and "unknown point cache extension ('.obj')" in message
    os.mkfifo(tmp_path / "pipe.pc2")
    assert "named pipe" in load_error("pipe.pc2", tmp_path, vc)
    (tmp_path / "bad.usda").write_text('#usda 1.0\ndef Mesh "m" {\n  point3f[] points.timeSamples = {1: [(0,\n')
    message = load_error("bad.usda", tmp_path, vc)
    assert "bad.usda" in message and "cannot open the USD stage" in message
    assert "empty" in load_error("", tmp_path, vc)


@needs_meshes
def test_broken_shared_files_as_caches(tmp_path: Path) -> None:
    """None of the shared broken meshes is a point cache: their bytes under cache names are refused in one
    line, and as a one-file sequence each is read by the mesh readers or refused by them."""
    files = sorted((MESHES / "broken").iterdir())
    assert files
    for source in files:
        data = source.read_bytes()
        for suffix in (".pc2", ".mdd", ".usda"):
            write(tmp_path / f"x{suffix}", data)
            message = load_error(f"x{suffix}", tmp_path, 8)
            assert str(tmp_path / f"x{suffix}") in message
        folder = tmp_path / "seq"
        folder.mkdir(exist_ok=True)
        for old in folder.iterdir():
            old.unlink()
        write(folder / f"frame_1{source.suffix}", data)
        try:
            cache = read_point_cache(f"seq/frame_*{source.suffix}", tmp_path, 8)
        except MeshLoadError as err:
            assert "\n" not in str(err) and "frame_1" in str(err)
        else:
            assert cache.vertex_count == 8 and np.isfinite(cache.positions).all()


# --- timing and sampling ---------------------------------------------------------------------------------


def cache_of(tmp_path: Path, values: list[float], start: float = 1.0, rate: float = 1.0):
    """A PC2 cache of one vertex whose x takes `values`, frame by frame."""
    positions = np.zeros((len(values), 1, 3))
    positions[:, 0, 0] = values
    write(tmp_path / "c.pc2", pc2_bytes(positions, start=start, rate=rate))
    return read_point_cache("c.pc2", tmp_path, 1)


def test_sample_interpolates_between_neighbouring_frames(tmp_path: Path) -> None:
    cache = cache_of(tmp_path, [0.0, 2.0, 6.0])
    timing = cache_timing(cache, sim_fps=24.0, sim_start_frame=1)
    # the rest state (t = 0) is scene frame 1 = cache frame 0, frame k (t = k/24) scene frame 1 + k
    x = [sample(cache, timing, t / 24.0)[0, 0] for t in (0.0, 0.5, 1.0, 1.25, 2.0, 3.0)]
    assert x == [0.0, 1.0, 2.0, 3.0, 6.0, 6.0]
    out = np.full((1, 3), 9.0)
    assert sample(cache, timing, 0.75 / 24.0, out=out) is out
    np.testing.assert_array_equal(out, [[1.5, 0.0, 0.0]])
    # the cache starting later than the run holds its first frame until it starts
    later = cache_timing(cache, sim_fps=24.0, sim_start_frame=1, start_frame=3)
    assert [sample(cache, later, t / 24.0)[0, 0] for t in (1.0, 2.0, 2.5, 3.0)] == [0.0, 0.0, 1.0, 2.0]


def test_sample_with_other_fps_start_and_step(tmp_path: Path) -> None:
    # samples every 2 scene frames from frame 1000, at 48 fps; the run at 24 fps from frame 500
    cache = cache_of(tmp_path, [0.0, 4.0, 8.0, 16.0], start=1000.0, rate=2.0)
    timing = cache_timing(cache, sim_fps=24.0, sim_start_frame=500, fps=48.0)
    # simulation time t is scene second 500/24 + t = scene frame (at 48 fps) 1000 + 48 t
    # t = 1/24: frame 1002 = cache frame 1 (4); t = 1.5/24: frame 1003 = halfway 1 -> 2 (6);
    # t = 2.25/24: frame 1004.5 = cache frame 2.25 (8 + 0.25 * 8 = 10)
    x = [sample(cache, timing, t / 24.0)[0, 0] for t in (0.0, 1.0, 1.5, 2.25, 8.0)]
    np.testing.assert_allclose(x, [0.0, 4.0, 6.0, 10.0, 16.0], rtol=1e-12, atol=0)


def test_timing_resolution_order(tmp_path: Path, mesh: Mesh) -> None:
    write(tmp_path / "a.mdd", mdd_bytes(animation(mesh), (10 + np.arange(FRAMES)) / 30.0))
    cache = read_point_cache("a.mdd", tmp_path, mesh.vertex_count)
    from_file = cache_timing(cache, sim_fps=24.0, sim_start_frame=1)
    assert (from_file.fps, from_file.start_frame) == (30.0, 10.0)
    override = cache_timing(cache, sim_fps=24.0, sim_start_frame=1, fps=25.0, start_frame=3)
    assert (override.fps, override.start_frame) == (25.0, 3.0)
    write(tmp_path / "z.mdd", mdd_bytes(animation(mesh), np.zeros(FRAMES)))
    silent = cache_timing(read_point_cache("z.mdd", tmp_path, mesh.vertex_count), sim_fps=24.0, sim_start_frame=7)
    assert (silent.fps, silent.start_frame, silent.frame_step) == (24.0, 7.0, 1.0)
    with pytest.raises(ValueError, match="fps"):
        cache_timing(cache, sim_fps=24.0, sim_start_frame=1, fps=0.0)


def test_check_cache_covers(tmp_path: Path) -> None:
    cache = cache_of(tmp_path, [float(i) for i in range(10)])
    timing = cache_timing(cache, sim_fps=24.0, sim_start_frame=1)
    check_cache_covers(cache, timing, 9)  # the rest pose and frames 1..9: scene frames 1..10 = cache frames 0..9
    with pytest.raises(MeshLoadError) as info:
        check_cache_covers(cache, timing, 10)
    message = str(info.value)
    assert "\n" not in message and str(tmp_path / "c.pc2") in message
    assert "10 frames (scene frames 1 to 10 at 24 fps)" in message and "10 frames at 24 fps" in message
    assert "up to scene frame 11" in message
    # at half the simulation's rate the same cache covers about twice the frames
    slow = cache_timing(cache, sim_fps=24.0, sim_start_frame=1, fps=12.0)
    check_cache_covers(cache, slow, 19)
    with pytest.raises(MeshLoadError, match=r"scene frame 10\.5"):
        check_cache_covers(cache, slow, 20)


@pytest.mark.parametrize("fmt", ["pc2", "mdd", "usd"])
def test_exported_run_read_back_as_a_cache_lines_up_frame_for_frame(tmp_path: Path, mesh: Mesh, fmt: str) -> None:
    """A run exported by the project's exporters, read as a collider cache of a run with the same fps and
    start frame, gives frame k's positions at frame k's time (k = 0: the rest pose, at the start frame)."""
    fps, start = 25.0, 1001
    positions = animation(mesh)
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path, fps=fps, frame_count=FRAMES, start_frame=start)
    with ExportSession([fmt], ctx) as session:
        for k in range(FRAMES):
            session.write(FrameData(index=k, time=k / fps, positions=positions[k]))
    name = {"pc2": "cache.pc2", "mdd": "cache.mdd", "usd": "scene.usdc"}[fmt]
    cache = read_point_cache(name, tmp_path, mesh.vertex_count)
    timing = cache_timing(cache, sim_fps=fps, sim_start_frame=start)
    check_cache_covers(cache, timing, FRAMES - 1)
    for k in range(FRAMES):
        np.testing.assert_array_equal(sample(cache, timing, k / fps), positions[k].astype(np.float32))
