"""USD that pipelines layer: OBJ groups, objects and materials as GeomSubsets and bound placeholder
materials, the object's name, the UV set's name, and the split layers (rest.usdc, animation.usdc over it,
scene.usdc over that), checked with usd-core's own validators (`pxr.UsdValidation`), against the OBJ
text read here line by line (not the project's reader), and in Blender when MESHDEFORM_BPY_PYTHON names
a Python with bpy.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from shared_meshes import MESHES, needs_meshes

from meshdeform.errors import ExportError, RecipeError
from meshdeform.export import ExportContext, ExportSession, FrameData
from meshdeform.export.usd import UsdExporter, read_usd_result
from meshdeform.io import load
from meshdeform.mesh import Mesh

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation  # noqa: E402

FPS = 24.0
NX, NY = 5, 4  # grid vertices: 4 x 3 quads, then a triangle and a pentagon
BPY_PYTHON = os.environ.get("MESHDEFORM_BPY_PYTHON")

# statements before face k, OBJ text exactly
ONE_OBJECT = {
    0: ["o cloth", "g front", "usemtl red"],
    6: ["g back", "usemtl blue"],
    12: ["g front"],
    13: ["usemtl red"],
}
OVERLAPPING = {
    0: ["g left edge", "o part one"],
    4: ["g right", "usemtl Red Cloth.001"],
    8: ["o 2nd", "g edge", "usemtl right"],
    10: ["g 0"],
    12: ["g"],
}
ONE_MATERIAL = {0: ["usemtl silk"]}


def obj_text(statements: dict[int, list[str]], uvs: bool = True) -> str:
    """A 5 x 4 vertex grid (12 quads), then a triangle and a pentagon, with `statements` before the faces
    they are keyed by, and one UV per vertex when `uvs`."""
    lines = [f"v {i / (NX - 1):.6f} {j / (NY - 1):.6f} 0" for j in range(NY) for i in range(NX)]
    if uvs:
        lines += [f"vt {i / (NX - 1):.6f} {j / (NY - 1):.6f}" for j in range(NY) for i in range(NX)]
    faces = [
        [j * NX + i, j * NX + i + 1, (j + 1) * NX + i + 1, (j + 1) * NX + i]
        for j in range(NY - 1)
        for i in range(NX - 1)
    ]
    faces += [[0, 1, NX + 1], [1, 2, 3, NX + 3, NX + 1]]
    for k, face in enumerate(faces):
        lines += statements.get(k, [])
        lines.append("f " + " ".join(f"{v + 1}/{v + 1}" if uvs else f"{v + 1}" for v in face))
    return "\n".join(lines) + "\n"


def parse_obj_sets(text: str) -> tuple[int, dict[str, dict[str, list[int]]], list[int]]:
    """Independent of meshdeform's reader: (face count, family -> name -> faces for `g` (each name on the
    line), `o` and `usemtl` (the rest of the line), the corner count of each face)."""
    current = {"group": (), "object": (), "material": ()}
    sets: dict[str, dict[str, list[int]]] = {"group": {}, "object": {}, "material": {}}
    sizes = []
    for raw in text.splitlines():
        parts = raw.split("#")[0].split()
        if not parts:
            continue
        key = parts[0]
        if key == "g":
            current["group"] = tuple(dict.fromkeys(parts[1:]))
        elif key in ("o", "usemtl"):
            rest = " ".join(parts[1:])
            current["object" if key == "o" else "material"] = (rest,) if rest else ()
        elif key == "f":
            for family, names in current.items():
                for name in names:
                    sets[family].setdefault(name, []).append(len(sizes))
            sizes.append(len(parts) - 1)
    return len(sizes), sets, sizes


def expected_family_type(named: dict[str, list[int]], count: int) -> str:
    hits = np.zeros(count, dtype=int)
    for faces in named.values():
        np.add.at(hits, faces, 1)
    if hits.max() > 1:
        return UsdGeom.Tokens.unrestricted
    return UsdGeom.Tokens.partition if (hits == 1).all() else UsdGeom.Tokens.nonOverlapping


def wave(mesh: Mesh, k: float) -> np.ndarray:
    p = mesh.positions.copy()
    p[:, 2] += 0.05 * k * np.sin(3.0 * p[:, 0] + 0.7 * k)
    p[:, 1] -= 0.01 * k * k
    return p


def export_usd(mesh: Mesh, out: Path, frames: int = 4, subframes: bool = True, **options) -> list[Path]:
    """`frames` + 1 frames (the rest pose first) of `wave`, with two motion-blur states between each two."""
    ctx = ExportContext(mesh=mesh, out_dir=out, fps=FPS, frame_count=frames)
    with ExportSession(["usd"], ctx, {"usd": options}) as session:
        for k in range(frames + 1):
            between = (
                tuple(((k - 1 + s) / FPS, wave(mesh, k - 1 + s)) for s in (1 / 3, 2 / 3)) if subframes and k else ()
            )
            session.write(FrameData(index=k, time=k / FPS, positions=wave(mesh, k), subframes=between))
    return session.outputs["usd"]


def write_obj(folder: Path, name: str, statements: dict[int, list[str]], uvs: bool = True) -> tuple[Path, str]:
    folder.mkdir(parents=True, exist_ok=True)
    text = obj_text(statements, uvs)
    path = folder / name
    path.write_text(text)
    return path, text


def validation_errors(path: Path) -> list[str]:
    """Every error and warning of every validator usd-core registers, on the stage opened from `path`."""
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    assert len(validators) > 10
    stage = Usd.Stage.Open(str(path))
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    return [f"{e.GetName()} ({e.GetType()}): {e.GetMessage()}" for e in found if not e.HasNoError()]


_OPEN: list[Usd.Stage] = []  # stages `the_mesh` opened, kept open (a prim is invalid once its stage is gone)


def the_mesh(stage: Usd.Stage | Path) -> UsdGeom.Mesh:
    """The one UsdGeom.Mesh of a stage (or of the stage a file opens)."""
    if isinstance(stage, Path):
        stage = Usd.Stage.Open(str(stage))
        _OPEN.append(stage)
    (prim,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    return UsdGeom.Mesh(prim)


@pytest.fixture(autouse=True)
def _close_stages():
    yield
    _OPEN.clear()


def subsets_of(geom: UsdGeom.Mesh, family: str) -> dict[str, list[int]]:
    """displayName (the OBJ's name) -> face indices of the family's GeomSubsets."""
    return {
        s.GetPrim().GetDisplayName(): sorted(s.GetIndicesAttr().Get())
        for s in UsdGeom.Subset.GetGeomSubsets(geom, UsdGeom.Tokens.face, family)
    }


# -- subsets and materials --------------------------------------------------------------------


@pytest.mark.parametrize("layers", ["single", "split"])
@pytest.mark.parametrize(("statements", "file_name"), [(ONE_OBJECT, "flag.obj"), (OVERLAPPING, "two parts.obj")])
def test_groups_objects_and_materials_are_subsets_of_the_obj_faces(
    tmp_path: Path, statements: dict[int, list[str]], file_name: str, layers: str
) -> None:
    path, text = write_obj(tmp_path, file_name, statements)
    count, sets, sizes = parse_obj_sets(text)
    (scene,) = [p for p in export_usd(load(path), tmp_path / "out", layers=layers) if p.name == "scene.usdc"]
    stage = Usd.Stage.Open(str(scene))
    geom = the_mesh(stage)
    assert list(geom.GetFaceVertexCountsAttr().Get()) == sizes  # the USD face list is the OBJ's: no triangulation
    for family, key in (("group", "group"), ("object", "object"), ("materialBind", "material")):
        assert subsets_of(geom, family) == sets[key], family
        subsets = UsdGeom.Subset.GetGeomSubsets(geom, UsdGeom.Tokens.face, family)
        valid, reason = UsdGeom.Subset.ValidateSubsets(subsets, count, expected_family_type(sets[key], count))
        assert valid or not subsets, reason
        if subsets:
            assert UsdGeom.Subset.GetFamilyType(geom, family) == expected_family_type(sets[key], count), family
    # every subset prim name is valid and distinct; the OBJ name is its displayName
    names = [child.GetName() for child in geom.GetPrim().GetChildren()]
    assert len(set(names)) == len(names) and all(Sdf.Path.IsValidIdentifier(n) for n in names)
    # each face's bound material is the one its `usemtl` named (none before the first)
    by_face = {f: name for name, faces in sets["material"].items() for f in faces}
    bound = {}
    for subset in UsdGeom.Subset.GetGeomSubsets(geom, UsdGeom.Tokens.face, "materialBind"):
        material, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
        bound.update({int(f): material.GetPrim().GetDisplayName() for f in subset.GetIndicesAttr().Get()})
    assert bound == by_face
    materials = [p for p in stage.Traverse() if p.IsA(UsdShade.Material)]
    assert sorted(p.GetDisplayName() for p in materials) == sorted(sets["material"])
    assert all(str(p.GetPath()).startswith("/Root/Materials/") for p in materials)
    for path_ in [p for p in [scene, scene.with_name("rest.usdc"), scene.with_name("animation.usdc")] if p.is_file()]:
        assert validation_errors(path_) == [], path_.name


def test_the_mesh_is_named_after_its_one_object_else_the_file(tmp_path: Path) -> None:
    named = {}
    for file_name, statements in (
        ("flag.obj", ONE_OBJECT),
        ("two parts.obj", OVERLAPPING),
        ("my flag.obj", ONE_MATERIAL),
    ):
        path, _ = write_obj(tmp_path, file_name, statements)
        (scene,) = export_usd(load(path), tmp_path / "out" / file_name, frames=1)
        prim = the_mesh(scene).GetPrim()
        named[file_name] = (prim.GetName(), prim.GetDisplayName())
    assert named == {
        "flag.obj": ("cloth", "cloth"),  # `o cloth` holds every face
        "two parts.obj": ("two_parts", "two parts"),  # two objects: the file's stem
        "my flag.obj": ("my_flag", "my flag"),
    }


def test_one_material_on_every_face_is_bound_to_the_mesh(tmp_path: Path) -> None:
    path, _ = write_obj(tmp_path, "flag.obj", ONE_MATERIAL)
    (scene,) = export_usd(load(path), tmp_path / "out", frames=1)
    stage = Usd.Stage.Open(str(scene))
    geom = the_mesh(stage)
    assert not UsdGeom.Subset.GetGeomSubsets(geom, UsdGeom.Tokens.face, "materialBind")
    material, _ = UsdShade.MaterialBindingAPI(geom.GetPrim()).ComputeBoundMaterial()
    assert material.GetPrim().GetPath() == Sdf.Path("/Root/Materials/silk")
    shader = material.ComputeSurfaceSource()[0]
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    assert validation_errors(scene) == []


def test_a_mesh_without_statements_has_no_subsets_or_materials(tmp_path: Path) -> None:
    path, _ = write_obj(tmp_path, "plain.obj", {})
    (scene,) = export_usd(load(path), tmp_path / "out", frames=1)
    stage = Usd.Stage.Open(str(scene))
    assert not the_mesh(stage).GetPrim().GetChildren()
    assert not stage.GetPrimAtPath("/Root/Materials")
    assert validation_errors(scene) == []


# -- UV set -----------------------------------------------------------------------------------


def test_uv_set_names_the_uv_primvar(tmp_path: Path) -> None:
    path, _ = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    mesh = load(path)
    values = {}
    for uv_set in ("st", "UVMap"):
        (scene,) = export_usd(mesh, tmp_path / uv_set, frames=1, uv_set=uv_set)
        api = UsdGeom.PrimvarsAPI(the_mesh(scene))
        assert [p.GetPrimvarName() for p in api.GetPrimvarsWithValues()] == [uv_set]
        primvar = api.GetPrimvar(uv_set)
        assert primvar.GetTypeName() == Sdf.ValueTypeNames.TexCoord2fArray
        assert primvar.GetInterpolation() == UsdGeom.Tokens.faceVarying
        values[uv_set] = np.asarray(primvar.ComputeFlattened())
    np.testing.assert_array_equal(values["st"], values["UVMap"])
    for bad in ("1uv", "uv set", "primvars:st", ""):
        with pytest.raises(ExportError, match="uv_set"):
            UsdExporter(uv_set=bad)
    with pytest.raises(ExportError, match="layers"):
        UsdExporter(layers="both")


# -- split layers -----------------------------------------------------------------------------


def time_sampled_points(path: Path) -> dict[float, np.ndarray]:
    points = the_mesh(path).GetPointsAttr()
    return {code: np.asarray(points.Get(code)) for code in points.GetTimeSamples()}


@pytest.mark.parametrize("ascii_", [False, True])
def test_split_layers_compose_to_the_single_stage(tmp_path: Path, ascii_: bool) -> None:
    path, _ = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    mesh = load(path)
    suffix = ".usda" if ascii_ else ".usdc"
    (single,) = export_usd(mesh, tmp_path / "single", ascii=ascii_)
    split = export_usd(mesh, tmp_path / "split", ascii=ascii_, layers="split")
    assert [p.name for p in split] == [f"rest{suffix}", f"animation{suffix}", f"scene{suffix}"]
    assert sorted(p.name for p in (tmp_path / "split").iterdir()) == sorted(p.name for p in split)  # no temporaries
    rest, animation, scene = split
    layers = {p.name: Sdf.Layer.FindOrOpen(str(p)) for p in split}
    assert all(layers.values())
    assert list(layers[scene.name].subLayerPaths) == [f"./{animation.name}"]
    assert list(layers[animation.name].subLayerPaths) == [f"./{rest.name}"]
    assert list(layers[rest.name].subLayerPaths) == []

    # the composed scene (and the animation layer opened alone) has the single stage's samples
    want = time_sampled_points(single)
    assert len(want) == 5 + 4 * 2  # frames 1..5 and two motion-blur states between each two
    for stage_path in (scene, animation):
        got = time_sampled_points(stage_path)
        assert list(got) == list(want)
        for code in want:
            np.testing.assert_array_equal(got[code], want[code])
    single_stage, scene_stage = Usd.Stage.Open(str(single)), Usd.Stage.Open(str(scene))
    for getter in ("GetStartTimeCode", "GetEndTimeCode", "GetTimeCodesPerSecond", "GetFramesPerSecond"):
        assert getattr(scene_stage, getter)() == getattr(single_stage, getter)(), getter
    assert UsdGeom.GetStageUpAxis(scene_stage) == UsdGeom.GetStageUpAxis(single_stage)
    a, b = the_mesh(single_stage), the_mesh(scene_stage)
    for attr in ("faceVertexCounts", "faceVertexIndices", "primvars:st", "primvars:st:indices"):
        assert a.GetPrim().GetAttribute(attr).Get() == b.GetPrim().GetAttribute(attr).Get(), attr

    # rest: the whole asset, no time samples, the input's rest pose as the points
    rest_stage = Usd.Stage.Open(str(rest))
    assert rest_stage.GetDefaultPrim().GetPath() == Sdf.Path("/Root")
    sampled = [a.GetPath() for p in rest_stage.Traverse() for a in p.GetAttributes() if a.GetNumTimeSamples()]
    assert sampled == []
    np.testing.assert_array_equal(
        np.asarray(the_mesh(rest_stage).GetPointsAttr().Get()), mesh.positions.astype(np.float32)
    )
    assert subsets_of(the_mesh(rest_stage), "group") == subsets_of(b, "group")

    # animation: overs holding only time-sampled points, normals and extent (no topology, UVs or subsets)
    specs = []
    layers[animation.name].Traverse(Sdf.Path.absoluteRootPath, specs.append)
    prims = [layers[animation.name].GetPrimAtPath(p) for p in specs if p.IsPrimPath()]
    assert all(spec.specifier == Sdf.SpecifierOver for spec in prims)
    properties = {p.name for p in specs if p.IsPropertyPath()}
    assert properties == {"points", "normals", "extent"}
    for name in properties:
        (spec,) = [layers[animation.name].GetPropertyAtPath(p) for p in specs if p.IsPropertyPath() and p.name == name]
        assert spec.default is None and layers[animation.name].GetNumTimeSamplesForPath(spec.path) == 13

    for p in split:
        assert validation_errors(p) == [], p.name
    # the reader (previews) reads the split scene's frames as the single stage's
    frames_single, frames_split = read_usd_result(tmp_path / "single", mesh), read_usd_result(tmp_path / "split", mesh)
    assert frames_split.numbers == frames_single.numbers == [1, 2, 3, 4, 5]
    for x, y in zip(frames_single.frames, frames_split.frames, strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_torn_mesh_time_samples_its_topology_in_the_animation_layer(tmp_path: Path) -> None:
    path, _ = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    mesh = load(path)
    torn_indices = mesh.face_indices.copy()
    torn_indices[0] = mesh.vertex_count  # corner 0 on a new vertex
    from dataclasses import replace

    torn = replace(mesh, positions=np.vstack([mesh.positions, mesh.positions[:1]]), face_indices=torn_indices)
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path / "out", fps=FPS, frame_count=3)
    with ExportSession(["usd"], ctx, {"usd": {"layers": "split"}}) as session:
        session.write(FrameData(index=0, time=0.0, positions=mesh.positions))
        session.write(FrameData(index=1, time=1 / FPS, positions=mesh.positions))
        session.write(FrameData(index=2, time=2 / FPS, positions=torn.positions, mesh=torn))
    rest = the_mesh(tmp_path / "out" / "rest.usdc")
    assert list(rest.GetFaceVertexIndicesAttr().Get()) == mesh.face_indices.tolist()
    assert rest.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0
    scene = the_mesh(tmp_path / "out" / "scene.usdc")
    indices = scene.GetFaceVertexIndicesAttr()
    assert list(indices.Get(1)) == mesh.face_indices.tolist() and list(indices.Get(3)) == torn_indices.tolist()
    assert len(scene.GetPointsAttr().Get(3)) == mesh.vertex_count + 1
    assert validation_errors(tmp_path / "out" / "scene.usdc") == []


def test_a_split_set_torn_before_its_first_frame_reads_back_torn(tmp_path: Path) -> None:
    """The rest layer keeps the input's topology; the animation layer's face lists from the first frame
    on are the torn ones, and the reader takes the topology of the first frame."""
    from dataclasses import replace

    path, _ = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    mesh = load(path)
    torn_indices = mesh.face_indices.copy()
    torn_indices[0] = mesh.vertex_count
    torn = replace(mesh, positions=np.vstack([mesh.positions, mesh.positions[:1]]), face_indices=torn_indices)
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path / "out", fps=FPS, frame_count=2)
    with ExportSession(["usd"], ctx, {"usd": {"layers": "split"}}) as session:
        session.write(FrameData(index=1, time=1 / FPS, positions=torn.positions, mesh=torn))
        session.write(FrameData(index=2, time=2 / FPS, positions=torn.positions + 0.1))
    result = read_usd_result(tmp_path / "out", None)
    assert result.numbers == [2, 3]
    assert result.base.face_indices.tolist() == torn_indices.tolist()
    np.testing.assert_allclose(result.frames[1], torn.positions + 0.1, atol=1e-6)
    assert list(the_mesh(tmp_path / "out" / "rest.usdc").GetFaceVertexIndicesAttr().Get()) == mesh.face_indices.tolist()


def test_the_estimate_is_on_the_high_side_for_every_layout(tmp_path: Path) -> None:
    """Noisy frames (crate's compression gains nothing on them), normals per vertex, and every layout."""
    path, _ = write_obj(tmp_path, "flag.obj", OVERLAPPING)
    mesh = load(path)
    rng = np.random.default_rng(7)
    for options in ({}, {"layers": "split"}, {"ascii": True}, {"ascii": True, "layers": "split"}, {"normals": False}):
        ctx = ExportContext(mesh=mesh, out_dir=tmp_path / json.dumps(options), fps=FPS, frame_count=6)
        with ExportSession(["usd"], ctx, {"usd": options}) as session:
            for k in range(7):
                noise = rng.normal(scale=0.01, size=mesh.positions.shape)
                session.write(FrameData(index=k, time=k / FPS, positions=mesh.positions + noise))
        written = sum(p.stat().st_size for p in session.outputs["usd"])
        estimate = UsdExporter.estimated_bytes(mesh, 7, **options)
        assert written <= estimate < 4 * written + 65536, (options, written, estimate)


# -- the recipe -------------------------------------------------------------------------------


RECIPE = """
[simulation]
frames = 3
[[pins]]
select = { box = { min = [-1, 0.99, -1], max = [2, 2, 1] } }
[output]
formats = ["obj", "usd"]
"""


def test_output_usd_table_reaches_the_exporter_and_the_result_folder(tmp_path: Path) -> None:
    from pipeline.job import run_job
    from pipeline.output_folder import read_marker
    from pipeline.recipe import parse_recipe, recipe_hash

    path, _ = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    plain = parse_recipe(RECIPE)
    defaults = parse_recipe(RECIPE + '[output.usd]\nlayers = "single"\nuv_set = "st"\nascii = false\n')
    split = parse_recipe(RECIPE + '[output.usd]\nlayers = "split"\nuv_set = "UVMap"\n')
    assert plain.output.exporter_options == {}
    assert split.output.exporter_options == {"usd": {"layers": "split", "uv_set": "UVMap", "ascii": False}}
    assert recipe_hash(defaults) == recipe_hash(plain) != recipe_hash(split)  # the same files, the same hash
    for bad, key in (('layers = "both"', "layers"), ('uv_set = "2d"', "uv_set"), ("colour = 1", "colour")):
        with pytest.raises(RecipeError, match=key):
            parse_recipe(RECIPE + f"[output.usd]\n{bad}\n")

    out = tmp_path / "result"
    run_job(path, split, out)
    marker = read_marker(out)
    assert marker is not None and {"rest.usdc", "animation.usdc", "scene.usdc"} <= marker
    stage = Usd.Stage.Open(str(out / "scene.usdc"))
    assert UsdGeom.PrimvarsAPI(the_mesh(stage)).HasPrimvar("UVMap")
    mesh = load(path)
    frames = read_usd_result(out, mesh)
    objs = sorted((out / "frames").glob("*.obj"))
    assert frames.numbers == [1, 2, 3, 4] and len(objs) == 4
    for positions, obj in zip(frames.frames, objs, strict=True):
        np.testing.assert_allclose(positions, load(obj).positions, atol=1e-6)
    # run again over it: the split files are the result's own, replaced without complaint
    run_job(path, split, out)
    assert read_marker(out) == marker


def test_the_run_estimate_counts_motion_blur_subframes(tmp_path: Path) -> None:
    """`[output] subframes = 8` writes seven more time samples a frame: the estimate `meshdeform check`
    prints and the disk check uses stays on the high side of what the run writes."""
    from pipeline.estimate import output_bytes
    from pipeline.job import run_job
    from pipeline.recipe import parse_recipe

    path = Path(__file__).resolve().parents[1] / "samples" / "meshes" / "sheet.obj"
    mesh = load(path)
    for subframes in (1, 8):
        recipe = parse_recipe(f'[simulation]\nframes = 6\n[output]\nformats = ["usd"]\nsubframes = {subframes}\n')
        out = tmp_path / f"blur{subframes}"
        run_job(path, recipe, out)
        written = (out / "scene.usdc").stat().st_size
        estimate = output_bytes(recipe, mesh)["usd"]
        assert written <= estimate < 4 * written + 65536, (subframes, written, estimate)


# -- real meshes ------------------------------------------------------------------------------


def _real_objs_with_statements() -> list[Path]:
    if MESHES is None:
        return []
    keys = ("g", "o", "usemtl")
    return [
        p
        for p in sorted((MESHES / "real").glob("*.obj"))
        if any(line.split()[:1] and line.split()[0] in keys for line in p.read_text(errors="replace").splitlines())
    ]


@needs_meshes
@pytest.mark.parametrize("path", _real_objs_with_statements(), ids=lambda p: p.name)
def test_real_meshes_with_groups_and_materials(tmp_path: Path, path: Path) -> None:
    text = path.read_text(errors="replace")
    count, sets, sizes = parse_obj_sets(text)
    mesh = load(path)
    assert mesh.face_count == count  # (no face of these files is dropped, so the OBJ's indices hold)
    for layers in ("single", "split"):
        files = export_usd(mesh, tmp_path / layers, frames=2, subframes=False, layers=layers)
        geom = the_mesh(files[-1])
        assert list(geom.GetFaceVertexCountsAttr().Get()) == sizes
        nonempty = {family: {n: f for n, f in named.items() if f} for family, named in sets.items()}
        assert subsets_of(geom, "group") == nonempty["group"]
        assert subsets_of(geom, "object") == nonempty["object"]
        bindings = subsets_of(geom, "materialBind")
        if len(nonempty["material"]) == 1 and len(next(iter(nonempty["material"].values()))) == count:
            assert bindings == {}
            material, _ = UsdShade.MaterialBindingAPI(geom.GetPrim()).ComputeBoundMaterial()
            assert material.GetPrim().GetDisplayName() == next(iter(nonempty["material"]))
        else:
            assert bindings == nonempty["material"]
        for p in files:
            assert validation_errors(p) == [], (layers, p.name)


# -- Blender ------------------------------------------------------------------------------------


BLENDER_SCRIPT = r"""
import json, sys
import bpy
import numpy as np

scene_path, frames_path, report_path = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=scene_path)
(obj,) = [o for o in bpy.data.objects if o.type == "MESH"]
want = np.load(frames_path)
worst = 0.0
for k, number in enumerate(want["numbers"]):
    bpy.context.scene.frame_set(int(number))
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    evaluated.to_mesh_clear()
    matrix = np.array(obj.matrix_world)
    world = co.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]
    worst = max(worst, float(np.abs(world - want["positions"][k]).max()))
data = obj.data
report = {
    "object": obj.name,
    "uv_layers": [uv.name for uv in data.uv_layers],
    "materials": [m.name for m in data.materials],
    "face_materials": [data.materials[p.material_index].name for p in data.polygons],
    "worst": worst,
}
with open(report_path, "w") as handle:
    json.dump(report, handle)
"""


@pytest.mark.skipif(not BPY_PYTHON, reason="MESHDEFORM_BPY_PYTHON names no Python with bpy")
def test_blender_imports_the_split_scene_with_its_names_and_frames(tmp_path: Path) -> None:
    path, text = write_obj(tmp_path, "flag.obj", ONE_OBJECT)
    _, sets, _ = parse_obj_sets(text)
    mesh = load(path)
    export_usd(mesh, tmp_path / "out", frames=4, subframes=False, layers="split", uv_set="UVMap")
    # Blender turns a Y-up stage to its Z-up world: (x, y, z) -> (x, -z, y), as its OBJ importer does
    positions = np.stack([wave(mesh, k) for k in range(5)])
    world = np.stack([positions[..., 0], -positions[..., 2], positions[..., 1]], axis=-1)
    np.savez(tmp_path / "want.npz", numbers=np.arange(1, 6), positions=world)
    script = tmp_path / "check.py"
    script.write_text(BLENDER_SCRIPT)
    report_path = tmp_path / "report.json"
    done = subprocess.run(
        [
            BPY_PYTHON,
            str(script),
            "--",
            str(tmp_path / "out" / "scene.usdc"),
            str(tmp_path / "want.npz"),
            str(report_path),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert report["object"] == "cloth"  # the OBJ's `o`, as Blender's OBJ importer names the object
    assert report["uv_layers"] == ["UVMap"]  # as Blender's OBJ importer names the UV map
    assert sorted(report["materials"]) == ["blue", "red"]
    by_face = {f: name for name, faces in sets["material"].items() for f in faces}
    assert report["face_materials"] == [by_face[f] for f in range(len(by_face))]
    assert report["worst"] < 1e-5
