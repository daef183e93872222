"""Previews of a result folder: `meshdeform preview RESULT_DIR`, each kind of folder's frames read back
(meshdeform.preview.results), and a run's previews from its frames in memory (meshdeform.preview.live)."""

from __future__ import annotations

import json
from pathlib import Path

import pyvista as pv

pv.OFF_SCREEN = True

import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import typer  # noqa: E402
from checks import reader_kinds  # noqa: E402
from factories import command_app, grid_cloth, grid_pins, grid_sheet, slit_grid  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from meshdeform.errors import MeshLoadError  # noqa: E402
from meshdeform.export import UP_AXES, ExportContext, ExportSession, FrameData  # noqa: E402
from meshdeform.io import save  # noqa: E402
from meshdeform.mesh import Mesh  # noqa: E402
from meshdeform.preview import open_result, render_result_previews  # noqa: E402
from pipeline.commands.preview import parse_frames, parse_size, register  # noqa: E402

FRAMES = 8  # simulated frames: a run writes FRAMES + 1, the rest pose (frame index 0) first


def motion(mesh: Mesh, i: int) -> np.ndarray:
    pos = mesh.positions.copy()
    pos[:, 2] = 0.1 * np.sin(4 * pos[:, 0] + i) * (1 - pos[:, 1])
    pos[:, 1] -= 0.02 * i * (1 - pos[:, 1])
    return pos


def make_result(
    folder: Path,
    formats: list[str],
    report: bool = True,
    up_axis: str = "y",
    start_frame: int = 1,
    indices: tuple[int, int] = (0, FRAMES),
) -> Mesh:
    """A result folder as a run writes it: frame indices `indices` (first and last; 0 the rest pose)
    exported, frame index k holding motion(mesh, k) at scene frame start_frame + k, plus report.json
    naming the input and the scene frames written, as run_job writes them."""
    mesh = grid_sheet(10)
    folder.mkdir(parents=True, exist_ok=True)
    input_path = folder.parent / "input.obj"
    save(input_path, mesh)
    pinned = grid_pins(10, 10, ["top"]).astype(np.uint8)
    ctx = ExportContext(
        mesh=mesh, out_dir=folder, fps=12.0, frame_count=FRAMES, up_axis=up_axis, start_frame=start_frame
    )
    with ExportSession(formats, ctx) as session:
        for k in range(indices[0], indices[1] + 1):
            session.write(FrameData(k, k / 12.0, motion(mesh, k), point_data={"pinned": pinned}))
    if report:
        written = [start_frame + indices[0], start_frame + indices[1]]
        info = {"input": str(input_path), "fps": 12.0, "frames": FRAMES, "start_frame": start_frame}
        (folder / "report.json").write_text(json.dumps({**info, "output_frames": written}))
    return mesh


@pytest.fixture
def app() -> typer.Typer:
    return command_app(register)


def test_preview_command_renders_pngs_sheet_and_gif(app: typer.Typer, tmp_path: Path) -> None:
    result_dir = tmp_path / "out" / "flag"
    make_result(result_dir, ["obj", "vtk"])
    run = CliRunner().invoke(
        app,
        ["preview", str(result_dir), "--every", "3", "--size", "160x120", "--contact-sheet", "--video", "gif"],
    )
    assert run.exit_code == 0, run.output
    assert "3 PNGs" in run.stdout and "frames/*.obj" in run.stdout
    names = sorted(p.name for p in (result_dir / "preview").iterdir())
    assert names == ["0001.png", "0004.png", "0007.png", "contact_sheet.png"]  # every 3rd from the rest pose
    assert iio.imread(result_dir / "preview.gif", index=None).shape[0] == FRAMES + 1
    assert iio.imread(result_dir / "preview" / "0004.png").shape == (120, 160, 3)


def test_preview_command_errors_are_one_line_and_exit_2(app: typer.Typer, tmp_path: Path) -> None:
    runner = CliRunner()
    for args in (
        ["preview", str(tmp_path / "missing")],
        ["preview", str(tmp_path)],  # an empty folder: no frames
        ["preview", str(tmp_path), "--view", "below"],
        ["preview", str(tmp_path), "--size", "big"],
        ["preview", str(tmp_path), "--frames", "3-1"],
    ):
        run = runner.invoke(app, args)
        assert run.exit_code == 2, (args, run.output)
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error:"), (args, run.stderr)


def test_parsers() -> None:
    assert parse_frames("1,5,10-12") == (1, 5, 10, 11, 12)
    assert parse_size("640x480") == (640, 480)


@pytest.mark.parametrize(
    ("formats", "up_axis"),
    [pytest.param([name], up, id=f"{name}-{up}") for _, kind in reader_kinds() for name in kind for up in UP_AXES],
)
def test_open_result_reads_each_kind_of_folder(tmp_path: Path, formats: list[str], up_axis: str) -> None:
    mesh = make_result(tmp_path / "r", formats, up_axis=up_axis)
    seq = open_result(tmp_path / "r")
    assert list((tmp_path / "r").glob(seq.source))  # it names the files it read
    assert seq.frame_numbers == list(range(1, FRAMES + 2))  # the rest pose at the default start frame 1
    assert seq.start_frame == 1
    assert seq.fps == 12.0
    assert seq.mesh.face_count == mesh.face_count
    np.testing.assert_allclose(seq.rest_positions, mesh.positions)
    for k in (0, 1, FRAMES):
        np.testing.assert_allclose(np.asarray(seq.frames[k]), motion(mesh, k), atol=1e-6)
    if formats in (["npz"], ["vtk"]):  # these carry the pinned flags
        np.testing.assert_array_equal(seq.pinned, mesh.positions[:, 1] > 0.99)


ONE_OF_EACH_KIND = [kind[0] for _, kind in reader_kinds()]  # a format of each kind of files previews read


@pytest.mark.parametrize(("start_frame", "indices"), [(0, (0, FRAMES)), (3, (0, FRAMES)), (1, (2, 6))])
def test_every_kind_of_folder_gives_the_scene_frames_the_run_wrote(
    tmp_path: Path, start_frame: int, indices: tuple[int, int]
) -> None:
    """Frame index k (0: the rest pose) is scene frame start_frame + k in every format; a point cache's
    copies of its first frame for the scene frames before it (sample k is scene frame k) are dropped by
    the report's first frame written, and kept without a report."""
    expected = list(range(start_frame + indices[0], start_frame + indices[1] + 1))
    for name in ONE_OF_EACH_KIND:
        mesh = make_result(tmp_path / name, [name], start_frame=start_frame, indices=indices)
        seq = open_result(tmp_path / name)
        assert (seq.frame_numbers, seq.start_frame) == (expected, start_frame), name
        assert len(seq.frames) == len(expected)
        for k, number in enumerate(expected):
            np.testing.assert_allclose(np.asarray(seq.frames[k]), motion(mesh, number - start_frame), atol=1e-6)
    for name in ("pc2", "mdd"):
        (tmp_path / name / "report.json").unlink()
        seq = open_result(tmp_path / name, mesh=mesh)
        assert seq.frame_numbers == list(range(expected[-1] + 1)), name
        assert seq.start_frame == 0  # unknown without the report: the first sample's
        for k in range(expected[0] + 1):  # the copies, then the first frame written
            np.testing.assert_allclose(np.asarray(seq.frames[k]), motion(mesh, indices[0]), atol=1e-6)


def test_point_caches_say_the_scene_frame_of_their_first_sample(tmp_path: Path) -> None:
    """A cache written elsewhere (or before the rest pose came first) whose first sample is scene frame 5:
    a PC2 header's start frame, an MDD's first time (s) times its fps."""
    from meshdeform.export.mdd import MDD_FLOAT, MDD_HEADER
    from meshdeform.export.pc2 import PC2_FLOAT, pc2_header

    mesh = grid_sheet(4)
    samples = np.stack([motion(mesh, k) for k in range(3)]).astype(np.float32)
    for name in ("pc2", "mdd"):
        (tmp_path / name).mkdir()
    (tmp_path / "pc2" / "cache.pc2").write_bytes(
        pc2_header(mesh.vertex_count, 5.0, 3) + samples.astype(PC2_FLOAT).tobytes()
    )
    times = np.array([5, 6, 7], dtype=np.float64) / 24.0
    (tmp_path / "mdd" / "cache.mdd").write_bytes(
        MDD_HEADER.pack(3, mesh.vertex_count) + times.astype(MDD_FLOAT).tobytes() + samples.astype(MDD_FLOAT).tobytes()
    )
    for name in ("pc2", "mdd"):
        seq = open_result(tmp_path / name, mesh=mesh, up_axis="y")
        assert seq.frame_numbers == [5, 6, 7], name
        np.testing.assert_allclose(np.asarray(seq.frames[1]), motion(mesh, 1), atol=1e-6)


def test_usd_samples_between_whole_time_codes_are_not_frames(tmp_path: Path) -> None:
    """Motion-blur subframes are authored between the frames' time codes: the frames are the whole ones."""
    from pxr import Usd, UsdGeom

    mesh = make_result(tmp_path / "r", ["usd"])
    stage = Usd.Stage.Open(str(tmp_path / "r" / "scene.usdc"))
    geom = UsdGeom.Mesh(next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)))
    geom.GetPointsAttr().Set(geom.GetPointsAttr().Get(2.0), 2.5)
    stage.Save()
    seq = open_result(tmp_path / "r")
    assert seq.frame_numbers == list(range(1, FRAMES + 2))
    np.testing.assert_allclose(np.asarray(seq.frames[2]), motion(mesh, 2), atol=1e-6)


def test_pngs_are_named_by_scene_frame_and_every_counts_from_the_rest_pose(tmp_path: Path) -> None:
    for name in ("obj", "pc2"):
        make_result(tmp_path / name, [name], start_frame=0)
        files = render_result_previews(tmp_path / name, {"every": 4, "size": [64, 48]})
        assert [p.name for p in files] == ["0000.png", "0004.png", "0008.png"], name
    make_result(tmp_path / "late", ["npz"], start_frame=10)
    files = render_result_previews(tmp_path / "late", {"every": 4, "size": [64, 48]})
    assert [p.name for p in files] == ["0010.png", "0014.png", "0018.png"]
    files = render_result_previews(tmp_path / "late", {"frames": [9, 10, 18], "size": [64, 48]})
    assert [p.name for p in files] == ["0010.png", "0018.png"]


def test_open_result_without_report_uses_the_first_frame_as_rest(tmp_path: Path) -> None:
    make_result(tmp_path / "r", ["obj"], report=False)
    seq = open_result(tmp_path / "r")
    np.testing.assert_allclose(seq.rest_positions, motion(grid_sheet(10), 0))
    with pytest.raises(MeshLoadError, match="no frames found"):
        open_result(tmp_path)  # the parent holds only input.obj


def test_render_result_previews_returns_the_files(tmp_path: Path) -> None:
    make_result(tmp_path / "r", ["npz"])
    files = render_result_previews(tmp_path / "r", {"every": 4, "size": [96, 72], "video": "mp4"})
    assert sorted(p.name for p in files) == ["0001.png", "0005.png", "0009.png", "preview.mp4"]
    assert all(p.is_file() for p in files)


def test_preview_never_replaces_a_preview_file_meshdeform_did_not_write(app: typer.Typer, tmp_path: Path) -> None:
    """A folder of someone's frames with their own preview/0001.png: refused, their file kept; a preview
    written into a fresh --out is recorded in its marker, so rendering it again is allowed."""
    runner = CliRunner()
    theirs = tmp_path / "theirs"
    make_result(theirs, ["obj"], report=False)
    (theirs / "preview").mkdir()
    (theirs / "preview" / "0001.png").write_bytes(b"my picture")
    run = runner.invoke(app, ["preview", str(theirs), "--video", "none"])
    assert run.exit_code == 2
    assert run.stderr.strip() == (
        f"error: {theirs}: 'preview' is there and meshdeform did not write it; previews would replace it, "
        "choose another --out"
    )
    assert (theirs / "preview" / "0001.png").read_bytes() == b"my picture"
    fresh = tmp_path / "fresh"
    for _ in range(2):
        run = runner.invoke(app, ["preview", str(theirs), "-o", str(fresh), "--video", "none"])
        assert run.exit_code == 0, run.output
    listed = json.loads((fresh / ".meshdeform.json").read_text())["files"]
    assert listed and listed == sorted(p.relative_to(fresh).as_posix() for p in (fresh / "preview").iterdir())


# ---------------------------------------------------------------------------------------------
# a run's previews from its frames in memory: the same bytes as from its files read back


def run_frames(mesh: Mesh, tear_at: int | None) -> list[FrameData]:
    """Frames as a run hands them to its exporters, frame index 0 (the rest pose) to FRAMES; from index
    `tear_at` on the cloth is torn (the copies drift apart), the torn mesh given with that frame only.
    The tear: the 10 x 10 grid cut along column 5 over its lowest three rows of quads, four vertices
    copied (the tip's too)."""
    torn, copies = slit_grid(mesh, 10, column=5, quad_rows=3, open_tip=True)
    out = []
    for i in range(0, FRAMES + 1):
        pos = motion(mesh, i)
        topology = None
        if tear_at is not None and i >= tear_at:
            pos = np.vstack([pos, pos[copies] + [0.01 * (i - tear_at + 1), 0.0, 0.0]])
            topology = torn if i == tear_at else None
        n = pos.shape[0]
        point_data = {
            "strain": 1.0 + 0.05 * np.sin(np.arange(n) + i),
            "pinned": (np.arange(n) >= 90).astype(np.uint8) * (np.arange(n) < 100),
        }
        out.append(FrameData(i, i / 12.0, pos, mesh=topology, point_data=point_data))
    return out


LIVE_OPTIONS = {"every": 3, "size": [96, 72], "video": "gif", "contact_sheet": True, "highlight_tears": True}


@pytest.mark.parametrize(
    ("formats", "up_axis", "tear_at", "options"),
    [
        (["obj"], "y", None, LIVE_OPTIONS),
        (["ply"], "y", None, {**LIVE_OPTIONS, "color": "displacement"}),
        (["npz"], "y", None, LIVE_OPTIONS),
        (["usd"], "z", None, LIVE_OPTIONS),
        (["vtk"], "y", None, {**LIVE_OPTIONS, "video": "mp4"}),
        (["pc2"], "z", None, LIVE_OPTIONS),
        (["mdd"], "y", None, LIVE_OPTIONS),
        (["ply", "obj", "vtk", "npz"], "y", None, {"frames": [2, 8], "size": [96, 72]}),
        (["obj"], "y", 4, LIVE_OPTIONS),
        (["ply", "vtk"], "y", 0, LIVE_OPTIONS),  # torn from the first frame: the base is the file's mesh
        (["vtk"], "y", 0, LIVE_OPTIONS),
        (["vtk"], "y", 4, LIVE_OPTIONS),
        (["usd"], "y", 0, LIVE_OPTIONS),
        (["usd", "vtk"], "y", 4, LIVE_OPTIONS),  # the stage's vertex count changes: an error
        (["xdmf", "pc2"], "y", None, LIVE_OPTIONS),
        (["xdmf"], "y", None, LIVE_OPTIONS),  # nothing a preview reads: an error
    ],
)
def test_a_runs_previews_from_memory_are_those_read_back_from_its_files(
    tmp_path: Path, formats: list[str], up_axis: str, tear_at: int | None, options: dict
) -> None:
    """`RunPreview` (what run_job renders) gives the same files, byte for byte, and the same errors as
    rendering the folder the run wrote, read back with the frame range of its report.json."""
    assert_live_previews_are_read_back(tmp_path, formats, up_axis, tear_at, options)


@pytest.mark.parametrize(
    ("formats", "start_frame", "indices", "options"),
    [
        (["pc2"], 3, (0, FRAMES), LIVE_OPTIONS),  # three copies of the rest pose before it in the cache
        (["mdd"], 0, (0, FRAMES), LIVE_OPTIONS),
        (["mdd"], 2, (3, 7), LIVE_OPTIONS),  # [output] frames = [5, 9]
        (["obj", "pc2"], 0, (1, FRAMES), {"frames": [0, 1, 5], "size": [96, 72]}),
        (["usd"], 5, (2, 6), LIVE_OPTIONS),
        (["npz"], 0, (0, FRAMES), {**LIVE_OPTIONS, "every": 2}),
    ],
)
def test_a_runs_previews_from_memory_at_any_start_frame_and_frame_range_are_those_read_back(
    tmp_path: Path, formats: list[str], start_frame: int, indices: tuple[int, int], options: dict
) -> None:
    """As above, for runs whose rest pose is not at scene frame 1 or that write a range of frames: the
    PNGs are named by scene frame, every Nth counted from the first frame written."""
    files = assert_live_previews_are_read_back(tmp_path, formats, "y", None, options, start_frame, indices)
    written = list(range(start_frame + indices[0], start_frame + indices[1] + 1))
    numbers = [n for n in written if n in options["frames"]] if "frames" in options else written[:: options["every"]]
    assert sorted(n for n in files if n.endswith(".png") and "sheet" not in n) == [
        f"preview/{n:04d}.png" for n in numbers
    ]


@pytest.mark.parametrize(
    ("formats", "tear_at", "options"),
    [
        (["obj"], None, LIVE_OPTIONS),
        (["obj"], 4, LIVE_OPTIONS),  # torn: the meshes stay in memory, the positions go to the file
        (["vtk"], 4, {**LIVE_OPTIONS, "video": "mp4"}),  # the files' strain goes to the file too
        (["pc2"], None, LIVE_OPTIONS),
    ],
)
@pytest.mark.parametrize("memory_budget", [0, 3000])
def test_a_runs_previews_past_their_memory_budget_are_still_those_read_back(
    tmp_path: Path, formats: list[str], tear_at: int | None, options: dict, memory_budget: int
) -> None:
    """Frames kept past `memory_budget` bytes (none, or the first few frames, in memory) wait in a scratch
    file in the run's folder: the same files, and the scratch file gone once they are rendered."""
    assert_live_previews_are_read_back(tmp_path, formats, "y", tear_at, options, memory_budget=memory_budget)


def assert_live_previews_are_read_back(
    tmp_path: Path,
    formats: list[str],
    up_axis: str,
    tear_at: int | None,
    options: dict,
    start_frame: int = 1,
    indices: tuple[int, int] = (0, FRAMES),
    memory_budget: int | None = None,
) -> dict[str, bytes] | str:
    """A run of `run_frames` written in `formats` from frame index indices[0] to indices[1], its previews
    from memory (`RunPreview`) against those of its folder read back with the report's frame range
    (`fps`, `start_frame`, `output_frames`: the keys run_job writes that `open_result` reads the frames by; the
    run's report.json is written after its previews, so it is written here by hand). Returns the files
    read back (relative name -> bytes), or the error both raised. memory_budget: the bytes of kept frames
    `RunPreview` holds in memory (the rest in its scratch file; default its own)."""
    from meshdeform.preview.live import RunPreview

    mesh, model, _ = grid_cloth(10, pins=("top",))
    ctx = ExportContext(
        mesh=mesh,
        out_dir=tmp_path / "run",
        fps=12.0,
        frame_count=FRAMES,
        up_axis=up_axis,
        start_frame=start_frame,
    )
    budget = {} if memory_budget is None else {"memory_budget": memory_budget}
    live = RunPreview(options, ctx, formats, model, **budget)
    with ExportSession(formats, ctx) as session:
        for frame in run_frames(mesh, tear_at)[indices[0] : indices[1] + 1]:
            session.write(frame)
            live.add(frame)
    written = [ctx.scene_frame(indices[0]), ctx.scene_frame(indices[1])]
    report = {"fps": ctx.fps, "start_frame": start_frame, "output_frames": written}
    (ctx.out_dir / "report.json").write_text(json.dumps(report))

    def outcome(render) -> dict[str, bytes] | str:
        try:
            files = render()
        except Exception as exc:
            return f"{type(exc).__name__}: {exc}"
        root = files[0].parents[1] if files[0].parent.name == "preview" else files[0].parent
        return {p.relative_to(root).as_posix(): p.read_bytes() for p in files}

    read_back = outcome(
        lambda: render_result_previews(ctx.out_dir, options, mesh=mesh, model=model, out_dir=tmp_path / "read")
    )
    if memory_budget is not None:
        assert live.spool.path is not None and live.spool.path.parent == ctx.out_dir
        assert live.spool.file_bytes > 0 and live.spool.memory_bytes <= memory_budget
    in_memory = outcome(lambda: live.render(tmp_path / "live").files)
    assert not list(ctx.out_dir.glob(".preview-spool-*"))  # the scratch file is gone
    if isinstance(read_back, dict):
        assert sorted(read_back) == sorted(in_memory)
        assert [n for n in read_back if read_back[n] != in_memory[n]] == []
    else:
        assert in_memory == read_back
        assert ("topology changes" in read_back) == (formats == ["usd", "vtk"])
    return read_back
