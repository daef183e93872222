"""USD export (usd-core): a stage `scene.usdc` (or `scene.usda`) for Blender, Houdini, Maya, Omniverse.

`/Root` (default prim, Xform, kind "component") holds a `UsdGeom.Mesh` with the topology authored once
(faceVertexCounts / faceVertexIndices, quads stay quads, subdivisionScheme "none"), time-sampled
`points`, `normals` (per vertex; per corner, faceVarying, when the input's normals have hard edges:
`meshdeform.geometry.normal_layout`) and `extent`, and the UVs as an indexed faceVarying primvar named
`uv_set` ("st") when the input has them. Polylines (OBJ `l`) go to a linear `UsdGeom.BasisCurves` beside
it. The mesh is named as Blender's OBJ importer names the object (the one OBJ object holding every face,
else the file's stem), made a valid prim name with the name itself as `displayName`; OBJ groups, objects
and materials become GeomSubsets and placeholder materials bound to the faces (`usd_faces`).
The stage's `timeCodesPerSecond` and `framesPerSecond` are the fps, frame index k (0: the
rest pose) sits at time code `start_frame + k`, and `upAxis` is `ExportContext.up_axis` (the
input's unless `[output] up_axis` says otherwise: the points then turned into that world,
`ExportContext.to_output_world`). When the topology changes (tearing) the face lists and UV
indices become time-sampled too, from that frame on. States between frames (`FrameData.subframes`,
`[output] subframes`: motion blur) are time samples at their fractional time codes
(start_frame + time * fps).

`layers = "split"` writes the same stage as three layers with the same prim paths: `rest.usdc`, the
asset (everything but time samples: topology, UVs, subsets, materials, and the input's rest pose as the
points', normals' and extent's defaults), `animation.usdc` (`over`s holding only the time samples, and
the face lists' after a tear; it sublayers `./rest.usdc`) and `scene.usdc`, the stage to open, which
sublayers `./animation.usdc`. Each layer carries the stage metadata, so each opens as a stage of its own.

Samples are authored as the frames come, through an edit target on the layer they belong to; the layers
live in memory until they are saved at close and renamed into place (`meshdeform.atomic`), rest first.
`read_usd_result` reads the frames back from `scene.usdc`, composed (`meshdeform.export.results`).
"""

from __future__ import annotations

import contextlib
import re
import threading
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_path
from meshdeform.errors import ExportError, MeshLoadError
from meshdeform.export.base import BaseExporter, ExportContext, FrameData
from meshdeform.export.results import (
    FrameItem,
    ReadBack,
    ResultFrames,
    ResultReading,
    detect_turns,
    prefer_input,
    restore_input_world,
)
from meshdeform.export.usd_faces import author_face_sets, face_sets, mesh_name, prim_identifier
from meshdeform.geometry import normal_layout, surface_normals, vertex_normals
from meshdeform.mesh import Mesh

ROOT = "/Root"

_USD_START = threading.Lock()
_usd_started = False


def start_usd() -> None:
    """Create USD's plugin registry and asset resolver once, in one thread.

    USD builds them on first use; two Python threads doing that at once (two jobs in one Dask
    worker) deadlock: one waits for the GIL inside the registry's construction while the other,
    holding the GIL, waits for the resolver's C++ static initialisation held by the first. Here
    the second thread waits on a Python lock instead, which releases the GIL.
    """
    global _usd_started
    if _usd_started:
        return
    with _USD_START:
        if not _usd_started:
            from pxr import Usd

            Usd.Stage.CreateInMemory()
            _usd_started = True


LAYERS = ("single", "split")
#: the UV primvar's default name, USD's convention (`uv_set`: Blender's USD importer names the UV map after it)
DEFAULT_UV_SET = "st"
#: the names `uv_set` takes: a primvar name without namespaces
UV_SET_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: bytes per value of an ascii layer (usda) against 4 of usdc: a float32 printed shortest, with its separator
_ASCII_FACTOR = 4


def usd_prim_name(mesh: Mesh) -> str:
    """The mesh prim's name: `usd_faces.mesh_name` (the one OBJ object holding every face, else the file's
    stem, "mesh" without a file) made a valid prim name (`usd_faces.prim_identifier`)."""
    return prim_identifier(mesh_name(mesh))


class UsdExporter(BaseExporter):
    """Authors time samples as frames come and saves the stage (its layers) at close.

    ascii: write `.usda` text layers instead of `.usdc` (crate). normals: write normals.
    layers: "single" (one `scene.usdc`) or "split" (`rest.usdc`, `animation.usdc`, `scene.usdc`).
    uv_set: the UV primvar's name ("st", USD's convention; "UVMap" as Blender names an OBJ's UV map).
    """

    name: ClassVar[str] = "usd"
    summary: ClassVar[str] = "USD stage with time samples"
    writes_subframes: ClassVar[bool] = True
    supports_topology_change: ClassVar[bool] = True

    def __init__(
        self,
        *,
        ascii: bool = False,
        normals: bool = True,
        layers: str = "single",
        uv_set: str = DEFAULT_UV_SET,
        **options: Any,
    ) -> None:
        super().__init__(**options)
        if layers not in LAYERS:
            raise ExportError(f"usd: layers must be one of {', '.join(map(repr, LAYERS))}, not {layers!r}")
        if not isinstance(uv_set, str) or not UV_SET_PATTERN.fullmatch(uv_set):
            raise ExportError(
                f"usd: uv_set must be a name of letters, digits and '_' (not starting with a digit), not {uv_set!r}"
            )
        self.ascii = bool(ascii)
        self.normals = bool(normals)
        self.layers = layers
        self.uv_set = uv_set

    @classmethod
    def estimated_bytes(
        cls,
        mesh: Mesh,
        frames: int,
        *,
        ascii: bool = False,
        layers: str = "single",
        normals: bool = True,
        **options: Any,
    ) -> int | None:
        """float32 points and normals (per corner at hard edges, else per vertex) per frame, int32 topology
        once, UVs once, subsets, and the stage's own; with `layers = "split"` the rest pose once more
        (rest.usdc) and two more layers' own; the data of text layers (`ascii`) at `_ASCII_FACTOR` times the
        crate's."""
        corners = int(mesh.face_indices.shape[0])
        uvs = 0 if mesh.uvs is None else 8 * int(mesh.uvs.shape[0]) + 4 * corners
        layout = normal_layout(mesh)
        per_corner = layout is not None and layout.hard_edges
        normal_bytes = 0 if not normals else 12 * (corners if per_corner else mesh.vertex_count)
        per_frame = 12 * mesh.vertex_count + normal_bytes + 24 + 64  # points, normals, extent, sample records
        listed = sum(int(np.size(f)) for f in mesh.groups.values()) + mesh.face_count  # groups, objects, materials
        subsets = 4 * listed + 512 * len(mesh.statements)
        data = per_frame * frames + 4 * (corners + mesh.face_count) + uvs + subsets
        own = 8192  # each layer's header, metadata and prim specs
        if layers == "split":
            data += per_frame
            own *= 3
        return int(own + data * (_ASCII_FACTOR if ascii else 1))

    @classmethod
    def reading(cls, *, ascii: bool = False, **options: Any) -> ResultReading | None:
        """`scene.usdc` (or the `.usda` a run with `ascii` writes: what its read-back names)."""
        stage_name = "scene.usda" if ascii else "scene.usdc"
        return ResultReading(
            priority=40,
            looks_for="scene.usdc",
            read=read_usd_result,
            read_back=lambda ctx: UsdReadBack(ctx, stage_name),
        )

    @property
    def suffix(self) -> str:
        return ".usda" if self.ascii else ".usdc"

    @property
    def file_name(self) -> str:
        """The stage users open: `scene.usdc` (`scene.usda` with ascii)."""
        return f"scene{self.suffix}"

    @property
    def file_names(self) -> tuple[str, ...]:
        """Every file written, in the order they are finished: the rest and animation layers, then the scene."""
        if self.layers == "split":
            return (f"rest{self.suffix}", f"animation{self.suffix}", self.file_name)
        return (self.file_name,)

    def _open(self, ctx: ExportContext) -> None:
        mesh = ctx.mesh
        if mesh.face_count == 0 and mesh.line_count == 0:
            raise ExportError("usd: the mesh has neither polygons nor polylines")
        start_usd()
        from pxr import Sdf, Usd, UsdGeom

        self._files: dict[str, tuple[Path, Any, Path]] = {}
        for name in self.file_names:  # target, its atomic_path context, the temporary file it writes
            target = ctx.out_dir / name
            atomic = atomic_path(target)
            tmp = atomic.__enter__()
            self._files[name] = (target, atomic, tmp)
            tmp.unlink()  # USD refuses to create a layer over an existing file
        self._layers: dict[str, Any] = {}  # held here: a stage holds its layers weakly once it is dropped
        for name in self.file_names[:2] if self.layers == "split" else (self.file_name,):
            layer = Sdf.Layer.CreateNew(str(self._files[name][2]))
            if layer is None:
                raise OSError(f"USD could not create {self._files[name][2]}")
            layer.timeCodesPerSecond = layer.framesPerSecond = float(ctx.fps)  # no time scaling between layers
            self._layers[name] = layer
        if self.layers == "split":  # a stage over both: the rest pose authored in one, the frames in the other
            stage = Usd.Stage.CreateInMemory()
            stage.GetRootLayer().timeCodesPerSecond = float(ctx.fps)
            rest, animation = (self._layers[n] for n in self.file_names[:2])
            stage.GetRootLayer().subLayerPaths = [animation.identifier, rest.identifier]
            self._rest_target = stage.GetEditTargetForLocalLayer(rest)
            self._animation_target = stage.GetEditTargetForLocalLayer(animation)
        else:
            stage = Usd.Stage.Open(self._layers[self.file_name])
            self._rest_target = self._animation_target = stage.GetEditTarget()
        self._stage = stage
        self._geom: Any = None
        self._curves: Any = None
        self._st: Any = None
        self._topology_sampled = False
        self._first_code: float | None = None
        self._last_code: float | None = None
        sets = face_sets(mesh)
        display = mesh_name(mesh, sets)
        name = prim_identifier(display)
        with Usd.EditContext(stage, self._rest_target):
            root = UsdGeom.Xform.Define(stage, ROOT)
            Usd.ModelAPI(root).SetKind("component")
            if mesh.face_count:
                self._geom = UsdGeom.Mesh.Define(stage, f"{ROOT}/{name}")
                self._geom.GetPrim().SetDisplayName(display)
                self._geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
                self._geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
                self._geom.CreateDoubleSidedAttr(True)
            if mesh.line_count:
                self._curves = UsdGeom.BasisCurves.Define(stage, f"{ROOT}/{name}_lines")
                self._curves.GetPrim().SetDisplayName(f"{display} lines")
                self._curves.CreateTypeAttr(UsdGeom.Tokens.linear)
            if self._geom is not None:
                author_face_sets(stage, self._geom, ROOT, sets, mesh.face_count)
            if self.layers == "split":  # the rest asset: the input's topology and rest pose as defaults
                self._author_topology(mesh, Usd.TimeCode.Default())
                self._author_points(ctx, mesh, np.asarray(mesh.positions, dtype=np.float64), Usd.TimeCode.Default())
        # one layer: the face lists of the first frame written (torn ones when a run tore before it)
        self._topology_mesh: Mesh | None = mesh if self.layers == "split" else None

    def _author_topology(self, mesh: Mesh, code: Any) -> None:
        """Face lists, UV primvar and curve counts, as defaults or (after tearing) time samples."""
        from pxr import Sdf, UsdGeom, Vt

        if self._geom is not None:
            counts = Vt.IntArray.FromNumpy(np.asarray(mesh.face_sizes, dtype=np.int32))
            indices = Vt.IntArray.FromNumpy(np.asarray(mesh.face_indices, dtype=np.int32))
            self._geom.GetFaceVertexCountsAttr().Set(counts, code)
            self._geom.GetFaceVertexIndicesAttr().Set(indices, code)
            uv_ok = (
                mesh.uvs is not None
                and mesh.face_uv_indices is not None
                and mesh.face_uv_indices.shape == mesh.face_indices.shape
                and bool((mesh.face_uv_indices >= 0).all())
            )
            if uv_ok:
                if self._st is None:
                    api = UsdGeom.PrimvarsAPI(self._geom)
                    self._st = api.CreatePrimvar(
                        self.uv_set, Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
                    )
                uvs = np.ascontiguousarray(np.asarray(mesh.uvs)[:, :2], dtype=np.float32)
                self._st.Set(Vt.Vec2fArray.FromNumpy(uvs), code)
                self._st.SetIndices(Vt.IntArray.FromNumpy(np.asarray(mesh.face_uv_indices, dtype=np.int32)), code)
        if self._curves is not None:
            counts = np.diff(mesh.line_offsets).astype(np.int32)
            self._curves.GetCurveVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts), code)

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        from pxr import Usd

        code = float(ctx.scene_frame(frame.index))
        if self._topology_mesh is None:
            self._author_topology(mesh, Usd.TimeCode.Default())
            self._topology_mesh = mesh
        with Usd.EditContext(self._stage, self._animation_target):
            if mesh is not self._topology_mesh:  # tearing: the face lists become time samples
                if not self._topology_sampled and self._first_code is not None:  # the first up to this frame
                    self._author_topology(self._topology_mesh, Usd.TimeCode(self._first_code))
                self._topology_sampled = True
                self._author_topology(mesh, Usd.TimeCode(code))
                self._topology_mesh = mesh
            if self._first_code is not None:  # motion blur: the states between the frame before and this one
                for when, between in frame.subframes:
                    time = Usd.TimeCode(ctx.start_frame + when * ctx.fps)
                    self._author_points(ctx, mesh, np.asarray(between, dtype=np.float64), time)
            if self._first_code is None:
                self._first_code = code
            self._last_code = code
            self._author_points(ctx, mesh, positions, Usd.TimeCode(code))

    def _author_points(self, ctx: ExportContext, mesh: Mesh, positions: np.ndarray, time: Any) -> None:
        """Points, extent and normals (and the polylines' points) at `time` (a Usd.TimeCode)."""
        from pxr import Vt

        points = ctx.to_output_world(np.asarray(positions, dtype=np.float64))
        points32 = np.ascontiguousarray(points, dtype=np.float32)
        lo, hi = points32.min(axis=0), points32.max(axis=0)
        extent = Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32))
        if self._geom is not None:
            self._geom.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points32), time)
            self._geom.GetExtentAttr().Set(extent, time)
            if self.normals:
                layout = normal_layout(mesh)
                if layout is not None and layout.hard_edges:  # per corner, split at the hard edges
                    normals = surface_normals(mesh, positions)[layout.corner_normal]
                    interpolation = "faceVarying"
                else:
                    normals = vertex_normals(mesh, positions)
                    interpolation = "vertex"
                normals = ctx.to_output_world(normals)
                self._geom.GetNormalsAttr().Set(
                    Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals, dtype=np.float32)), time
                )
                authored = self._geom.GetNormalsAttr().HasAuthoredMetadata("interpolation")
                if not authored or self._geom.GetNormalsInterpolation() != interpolation:
                    self._geom.SetNormalsInterpolation(interpolation)  # once (the rest layer's, when split)
        if self._curves is not None:
            curve_points = np.ascontiguousarray(points32[mesh.line_indices])
            self._curves.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(curve_points), time)
            self._curves.GetExtentAttr().Set(
                Vt.Vec3fArray.FromNumpy(np.stack([curve_points.min(axis=0), curve_points.max(axis=0)])), time
            )

    def _stage_metadata(self, ctx: ExportContext, layer: Any, timed: bool) -> None:
        """The stage metadata every layer carries (so each opens as a stage of its own): default prim, up
        axis, metres per unit, time codes and frames per second, and (`timed`) the first and last time code."""
        layer.defaultPrim = ROOT.lstrip("/")
        layer.pseudoRoot.SetInfo("upAxis", "Z" if ctx.up_axis == "z" else "Y")
        layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
        layer.timeCodesPerSecond = layer.framesPerSecond = float(ctx.fps)
        if timed:
            layer.startTimeCode = float(self._first_code)
            layer.endTimeCode = float(self._last_code)

    def _finish(self, name: str) -> Path:
        """Rename a saved layer into place; `abort()` removes it again if a later one fails."""
        target, atomic, _ = self._files.pop(name)
        atomic.__exit__(None, None, None)
        self._written.append(target)
        return target

    def _close(self, ctx: ExportContext) -> list[Path]:
        from pxr import Sdf

        self._release_stage()
        if self.layers == "single":
            layer = self._layers[self.file_name]
            self._stage_metadata(ctx, layer, timed=True)
            if not layer.Save():
                raise OSError(f"USD could not save {self._files[self.file_name][2]}")
            finished = [self._finish(self.file_name)]
        else:
            rest_name, animation_name, scene_name = self.file_names
            finished = []
            for name, below in ((rest_name, None), (animation_name, rest_name)):
                layer = self._layers[name]
                self._stage_metadata(ctx, layer, timed=below is not None)
                if below is not None:  # set now that rest.usdc is in place, so it resolves
                    layer.subLayerPaths = [f"./{below}"]
                if not layer.Save():
                    raise OSError(f"USD could not save {self._files[name][2]}")
                finished.append(self._finish(name))
            scene = Sdf.Layer.CreateNew(str(self._files[scene_name][2]))
            if scene is None:
                raise OSError(f"USD could not create {self._files[scene_name][2]}")
            self._layers[scene_name] = scene
            self._stage_metadata(ctx, scene, timed=True)
            scene.subLayerPaths = [f"./{animation_name}"]
            if not scene.Save():
                raise OSError(f"USD could not save {self._files[scene_name][2]}")
            finished.append(self._finish(scene_name))
        self._layers = {}
        return finished

    def _release_stage(self) -> None:
        self._geom = None
        self._curves = None
        self._st = None
        self._rest_target = self._animation_target = None
        self._stage = None

    def _abort(self) -> None:
        self._release_stage()
        self._layers = {}
        err = RuntimeError("export aborted")
        for _, atomic, _ in getattr(self, "_files", {}).values():
            with contextlib.suppress(Exception):
                atomic.__exit__(type(err), err, None)
        self._files = {}


def read_usd_frames(
    path: Path, turns: int | None = None, rest: np.ndarray | None = None
) -> tuple[Mesh, np.ndarray, list[int], float]:
    """A stage's first `UsdGeom.Mesh`: (mesh at its first frame's topology and points, positions (F, V, 3)
    in the input's coordinates, frame numbers: the time codes, scene frames as ours are written (a
    stage without time samples: its start time code, else 1), time codes per second). Samples between
    whole time codes (motion-blur subframes) are not frames, unless the stage has no others.
    MeshLoadError when it cannot be opened, has no mesh or its vertex count changes over time.

    The points are turned back by `turns` quarter turns (`ExportContext.output_turns`); None: the
    ones that bring the first sample closest to `rest` (V, 3), the input's rest pose, when given
    with the stage's vertex count, else those of a Y-up input (a Z-up stage turned back to Y up)."""
    start_usd()
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise MeshLoadError(f"{path}: cannot open the USD stage")
    prim = next((p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)), None)
    if prim is None:
        raise MeshLoadError(f"{path}: no UsdGeom.Mesh in the stage")
    geom = UsdGeom.Mesh(prim)
    points_attr = geom.GetPointsAttr()
    samples = list(points_attr.GetTimeSamples())
    frames = [c for c in samples if abs(c - round(c)) < 1e-6]  # whole time codes: frames (others: subframes)
    codes = frames or samples or [Usd.TimeCode.Default()]
    # the face lists at the first frame: their default, or their sample there when they are time-sampled
    counts = np.asarray(geom.GetFaceVertexCountsAttr().Get(codes[0]), dtype=np.int64)
    indices = np.asarray(geom.GetFaceVertexIndicesAttr().Get(codes[0]), dtype=np.int64)
    z_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    stored = [np.asarray(points_attr.Get(code), dtype=np.float64) for code in codes]
    if turns is None:
        matches = rest is not None and stored[0].shape == np.shape(rest)
        turns = detect_turns(stored[0], np.asarray(rest)) if matches else (1 if z_up else 0)
    positions = [restore_input_world(p, turns) for p in stored]
    if len({p.shape for p in positions}) != 1:
        raise MeshLoadError(f"{path}: the topology changes over time; preview the frames/ files instead")
    offsets = np.concatenate([[0], np.cumsum(counts)])
    if samples:
        numbers = [round(float(c)) for c in codes]
    else:
        numbers = [round(stage.GetStartTimeCode()) if stage.HasAuthoredTimeCodeRange() else 1]
    mesh = Mesh(positions=positions[0], face_indices=indices, face_offsets=offsets, source=path)
    return mesh, np.stack(positions), numbers, float(stage.GetTimeCodesPerSecond() or 24.0)


def read_usd_result(root: Path, input_mesh: Mesh | None, turns: int | None = None) -> ResultFrames | None:
    """The frames of a result folder's `scene.usdc` (or `.usda`, `.usd`), or None when there is none;
    `turns` as `read_usd_frames` (None: detected against the input mesh's rest pose)."""
    usd = next((root / n for n in ("scene.usdc", "scene.usda", "scene.usd") if (root / n).is_file()), None)
    if usd is None:
        return None
    rest = None if input_mesh is None else input_mesh.positions
    base, stacked, numbers, fps = read_usd_frames(usd, turns, rest)
    return ResultFrames(prefer_input(base, input_mesh), list(stacked), numbers, usd.name, fps=fps)


class UsdReadBack(ReadBack):
    """`read_usd_result` for a run's frames in memory: float32 points in the stage's up axis and back, the
    first frame's topology, the run's fps, and the errors reading the stage gives (no polygons, so no
    `UsdGeom.Mesh`; a vertex count that changes over time)."""

    def __init__(self, ctx: ExportContext, stage_name: str = "scene.usdc") -> None:
        super().__init__(ctx)
        self.source = stage_name  # the file the reader opens: scene.usdc, or scene.usda with `ascii`
        self._path = ctx.out_dir / self.source
        self._error: MeshLoadError | None = None

    def keep(self, positions: np.ndarray) -> np.ndarray:
        points = self.ctx.to_output_world(np.asarray(positions, dtype=np.float64))
        return np.ascontiguousarray(points, dtype=np.float32)

    def item(self, mesh: Mesh, kept: np.ndarray) -> FrameItem:
        return restore_input_world(kept.astype(np.float64), self.ctx.output_turns)

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        self.fps = float(self.ctx.fps)  # the stage's timeCodesPerSecond
        self._vertex_count = mesh.vertex_count
        if self.ctx.mesh.face_count == 0:
            self._error = MeshLoadError(f"{self._path}: no UsdGeom.Mesh in the stage")
        offsets = np.concatenate([[0], np.cumsum(np.asarray(mesh.face_sizes, dtype=np.int64))])
        face_indices = np.asarray(mesh.face_indices, dtype=np.int64)
        stage_mesh = Mesh(positions=self.item(mesh, kept), face_indices=face_indices, face_offsets=offsets)
        self.base = prefer_input(stage_mesh, self.ctx.mesh)
        return self.base

    def add(self, frame: FrameData, mesh: Mesh) -> None:
        if self._error is None and mesh.vertex_count != self._vertex_count:
            self._error = MeshLoadError(
                f"{self._path}: the topology changes over time; preview the frames/ files instead"
            )

    def check(self) -> None:
        if self._error is not None:
            raise self._error
