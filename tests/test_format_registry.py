"""The export registry is the one list of formats: what each exporter class declares (help text,
topology, size estimate, how previews read it back) is what the estimate and the previews use.

Every test iterates `EXPORTERS`, so a new format is checked here as soon as it is registered.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from meshdeform.export import EXPORTERS, ExportContext, ExportSession, FrameData
from meshdeform.mesh import Mesh, grid_mesh
from meshdeform.preview.results import no_frames_found, open_result, read_back_for, search_order
from pipeline.estimate import output_bytes
from pipeline.recipe import parse_recipe

READABLE = [name for name, cls in EXPORTERS.items() if cls.reading() is not None]


@pytest.fixture
def mesh() -> Mesh:
    return grid_mesh(5, 4)


def sag(mesh: Mesh, index: int) -> np.ndarray:
    """Frame `index` of a sheet sagging below its top row (V, 3)."""
    return mesh.positions - [0.0, 0.01 * index, 0.0] * (1.0 - mesh.positions[:, 1:2])


def write(name: str, mesh: Mesh, out: Path, count: int = 3) -> ExportContext:
    """A run of `count` frames of `sag` in format `name` into `out`: frame index 0 (the rest pose, at the
    default start frame 1) to `count`, frame index i holding sag(mesh, i)."""
    ctx = ExportContext(mesh=mesh, out_dir=out, fps=24.0, frame_count=count)
    with ExportSession([name], ctx) as session:
        for i in range(count + 1):
            session.write(FrameData(index=i, time=i / 24.0, positions=sag(mesh, i)))
    return ctx


def test_every_format_declares_its_help_its_topology_and_a_growing_size_estimate(mesh: Mesh) -> None:
    for name, cls in EXPORTERS.items():
        assert cls.name == name
        assert cls.summary and "\n" not in cls.summary
        assert isinstance(cls.supports_topology_change, bool)
        short, long = cls.estimated_bytes(mesh, 4), cls.estimated_bytes(mesh, 8)
        assert short is None or (type(short) is int and type(long) is int and 0 < short < long), name


def test_the_run_estimate_is_each_formats_own_in_the_recipes_order(mesh: Mesh) -> None:
    formats = list(reversed(EXPORTERS))
    recipe = parse_recipe(f"[simulation]\nframes = 5\n[output]\nformats = {json.dumps(formats)}\n")
    # 6 frames written (the rest pose, then 5); point caches also hold a copy for scene frame 0 (start frame 1)
    written = {n: 6 + (1 if EXPORTERS[n].pads_to_scene_frame_zero else 0) for n in formats}
    expected = {n: EXPORTERS[n].estimated_bytes(mesh, written[n]) for n in formats}
    assert output_bytes(recipe, mesh) == {n: size for n, size in expected.items() if size is not None}
    assert list(output_bytes(recipe, mesh)) == [n for n in formats if expected[n] is not None]


def test_readings_have_distinct_priorities_and_formats_writing_the_same_files_share_a_reader() -> None:
    readings = [EXPORTERS[name].reading() for name in READABLE]
    assert len({r.priority for r in readings}) == len(readings)
    for reading in readings:
        assert all(r.read is reading.read for r in readings if r.looks_for == reading.looks_for)
    order = search_order()
    assert [r.priority for r in order] == sorted(r.priority for r in order)
    assert {r.looks_for for r in order} == {r.looks_for for r in readings}
    message = str(no_frames_found(Path("result")))
    assert message.endswith(f"(looked for {', '.join(r.looks_for for r in order)})")


@pytest.mark.parametrize("name", READABLE)
def test_a_folder_in_one_format_is_read_by_that_formats_reader_as_its_read_back_says(
    name: str, mesh: Mesh, tmp_path: Path
) -> None:
    ctx = write(name, mesh, tmp_path / name)
    own = EXPORTERS[name].reading()
    for reading in search_order():  # no other kind of files is found in the folder
        found = reading.read(ctx.out_dir, mesh, None)
        assert (found is not None) == (reading.looks_for == own.looks_for), reading.looks_for
    result = open_result(ctx.out_dir, mesh=mesh)
    read_back = read_back_for([name], ctx)
    assert read_back is not None and result.source == read_back.source
    # scene frames; a point cache without the run's report also has its sample 0 (a copy of the rest pose)
    padded = EXPORTERS[name].pads_to_scene_frame_zero
    assert result.frame_numbers == ([0] if padded else []) + [1, 2, 3, 4]
    np.testing.assert_allclose(np.asarray(result.frames[0]), sag(mesh, 0), atol=1e-6)
    np.testing.assert_allclose(np.asarray(result.frames[-1]), sag(mesh, 3), atol=1e-6)
    (ctx.out_dir / "report.json").write_text(json.dumps({"start_frame": 1, "output_frames": [1, 4]}))
    assert open_result(ctx.out_dir, mesh=mesh).frame_numbers == [1, 2, 3, 4]  # from the run's first frame


@pytest.mark.parametrize("layers", ["single", "split"])
def test_a_text_usd_run_is_read_back_as_its_text_stage(layers: str, mesh: Mesh, tmp_path: Path) -> None:
    """`[output.usd] ascii = true` writes scene.usda: the run's read-back names that file, as reading
    the folder does (the preview label's source)."""
    options = {"usd": {"ascii": True, "layers": layers}}
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path / layers, fps=24.0, frame_count=3)
    with ExportSession(["usd"], ctx, options) as session:
        for i in range(4):
            session.write(FrameData(index=i, time=i / 24.0, positions=sag(mesh, i)))
    result = open_result(ctx.out_dir, mesh=mesh)
    read_back = read_back_for(["usd"], ctx, options)
    assert result.source == "scene.usda"
    assert read_back is not None and read_back.source == result.source
    assert read_back_for(["usd"], ctx).source == "scene.usdc"  # the crate file a plain run writes


def test_formats_previews_cannot_read_have_no_read_back(mesh: Mesh, tmp_path: Path) -> None:
    for name in set(EXPORTERS) - set(READABLE):
        ctx = ExportContext(mesh=mesh, out_dir=tmp_path, fps=24.0)
        assert read_back_for([name], ctx) is None


def test_the_format_table_of_the_export_package_is_the_registrys() -> None:
    import meshdeform.export

    rows = [line.split("|")[1:-1] for line in (meshdeform.export.__doc__ or "").splitlines() if line.startswith("| ")]
    table = {cells[0].strip(): cells[2].strip() for cells in rows[1:]}  # below the header row
    assert list(table) == list(EXPORTERS)
    for name, cls in EXPORTERS.items():
        assert table[name].startswith("refused") != cls.supports_topology_change, name


@pytest.mark.parametrize("name", list(EXPORTERS))
def test_a_runs_preview_from_memory_is_the_one_read_back_from_its_files(name: str, tmp_path: Path) -> None:
    """`RunPreview` (a run's previews from its frames) renders the same bytes, or raises the same error,
    as rendering the folder the run wrote in that one format, read with the frame range of the report
    the run writes after its previews (`start_frame`, `output_frames`; written here by hand)."""
    from meshdeform.model import SpringModel
    from meshdeform.preview.live import RunPreview
    from meshdeform.preview.results import render_result_previews

    mesh = grid_mesh(6, 6)
    model = SpringModel.from_mesh(mesh, pinned_input=mesh.positions[:, 1] > 0.99)
    options = {"frames": [3], "size": [64, 48]}
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path / "run", fps=24.0, frame_count=3)
    live = RunPreview(options, ctx, [name], model)
    with ExportSession([name], ctx) as session:
        for i in range(4):  # the rest pose, then 3 frames: scene frames 1 to 4
            frame = FrameData(index=i, time=i / 24.0, positions=sag(mesh, i))
            session.write(frame)
            live.add(frame)
    (ctx.out_dir / "report.json").write_text(json.dumps({"start_frame": 1, "output_frames": [1, 4]}))

    def outcome(render) -> dict[str, bytes] | str:
        try:
            files = render()
        except Exception as exc:
            return f"{type(exc).__name__}: {exc}"
        return {p.name: p.read_bytes() for p in files}

    read_back = outcome(
        lambda: render_result_previews(ctx.out_dir, options, mesh=mesh, model=model, out_dir=ctx.out_dir)
    )
    in_memory = outcome(lambda: live.render(ctx.out_dir).files)
    assert in_memory == read_back
    assert isinstance(read_back, dict) == (name in READABLE), read_back


def test_a_fixed_topology_format_refusing_a_torn_frame_names_the_registrys_formats_that_follow(
    mesh: Mesh, tmp_path: Path
) -> None:
    from meshdeform.errors import ExportError

    following = [name for name, cls in EXPORTERS.items() if cls.supports_topology_change]
    names = f"{', '.join(following[:-1])} or {following[-1]}"
    torn = grid_mesh(6, 4)
    for name in [name for name, cls in EXPORTERS.items() if not cls.supports_topology_change]:
        ctx = ExportContext(mesh=mesh, out_dir=tmp_path / name, fps=24.0)
        with pytest.raises(ExportError) as info, ExportSession([name], ctx) as session:
            session.write(FrameData(index=1, time=0.0, positions=mesh.positions))
            session.write(FrameData(index=2, time=0.1, positions=torn.positions, mesh=torn))
        assert str(info.value).endswith(f"(tearing). Export {names} instead, or turn tearing off"), name


def test_the_format_lists_of_the_readme_and_the_recipe_reference_are_the_registrys() -> None:
    repo = Path(__file__).resolve().parents[1]
    readme = (repo / "README.md").read_text(encoding="utf-8")
    assert f"# formats = {json.dumps(list(EXPORTERS))};" in readme
    recipes = (repo / "docs" / "recipes.md").read_text(encoding="utf-8")
    assert f"any of {', '.join(f'`{name}`' for name in EXPORTERS)};" in recipes
