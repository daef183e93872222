"""One off-screen PyVista Plotter that renders frame after frame (`FrameRenderer`), and what it highlights.

It draws the scene only, coloured by `overlay.COLORMAPS` through a `overlay.LUT_COLORS`-colour table over
the fixed colour range; the frame label and the colour bar are the overlay's (`overlay.Overlay`), in the
room the camera keeps free for them.

Colliders (`meshdeform.preview.colliders`) are drawn opaque and lit in neutral greys (`SOLID_COLOR`,
planes as a floor in `FLOOR_COLOR`), pushed slightly back in depth so the cloth resting on them wins
ties; the camera stays framed on the cloth (colliders may be cropped), only its clipping range grows
to take them in.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from meshdeform.arrays import isin_int
from meshdeform.errors import ExportError
from meshdeform.mesh import Mesh
from meshdeform.preview.camera import frame_camera
from meshdeform.preview.colliders import ColliderSurfaces, Surface
from meshdeform.preview.options import PreviewOptions
from meshdeform.preview.overlay import COLORMAPS, LUT_COLORS, Overlay
from meshdeform.topology import boundary_edges as topology_boundary_edges

#: colliders: a mid grey for solids, a lighter grey for floors (planes), apart from the cloth's colours
SOLID_COLOR = "#8c8c8c"
FLOOR_COLOR = "#c8c8c8"
#: depth offset (VTK polygon offset factor, units) of collider surfaces: behind the cloth where they touch
COLLIDER_DEPTH_OFFSET = (2.0, 4.0)
#: the near clipping plane never comes closer to the camera than this fraction of the focal distance
NEAR_FRACTION = 0.02


def boundary_edges(mesh: Mesh) -> np.ndarray:
    """Polygon edges used by exactly one polygon, (E, 2) sorted pairs (`topology.boundary_edges`)."""
    return topology_boundary_edges(mesh.face_indices, mesh.face_indices[mesh.corner_next], mesh.vertex_count)


def as_pinned_mask(pinned: np.ndarray | Sequence[int] | None, n: int) -> np.ndarray | None:
    """An (n,) bool mask from a mask ((n,) bool or uint8) or vertex indices; ExportError when they do not fit."""
    if pinned is None:
        return None
    arr = np.asarray(pinned)
    if arr.dtype == bool or (arr.dtype == np.uint8 and arr.shape == (n,)):
        mask = arr.astype(bool)
        if mask.shape != (n,):
            raise ExportError(f"preview: pinned mask has shape {mask.shape}, expected ({n},)")
        return mask
    mask = np.zeros(n, dtype=bool)
    idx = arr.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ExportError(f"preview: pinned vertex index out of range 0..{n - 1}")
    mask[idx] = True
    return mask


class FrameRenderer:
    """One off-screen Plotter reused for every frame; `render` returns an (H, W, 3) uint8 image."""

    def __init__(
        self,
        mesh: Mesh,
        options: PreviewOptions,
        bounds: np.ndarray,
        clim: tuple[float, float] | None,
        pinned: np.ndarray | Sequence[int] | None = None,
        colliders: ColliderSurfaces | None = None,
    ) -> None:
        import pyvista as pv
        from vtkmodules.vtkCommonCore import vtkObject

        from meshdeform.export.vtk import polydata_from_mesh

        self._warnings = vtkObject.GetGlobalWarningDisplay()
        vtkObject.GlobalWarningDisplayOff()  # no "bad X server connection" noise when headless
        self.options = options
        self.rest_mesh = mesh
        self._pinned_rest = as_pinned_mask(pinned, mesh.vertex_count)
        self._pv = pv
        self._polydata_from_mesh = polydata_from_mesh
        # a fresh theme (not the user's global one) so images are reproducible; MSAA is the only
        # anti-aliasing that works with EGL/OSMesa, and it is most of the cost with software GL
        theme = pv.themes.Theme()
        theme.multi_samples = 4 if options.anti_aliasing else 0
        theme.anti_aliasing = "msaa" if options.anti_aliasing else None
        self.plotter = pv.Plotter(off_screen=True, window_size=list(options.size), lighting="light_kit", theme=theme)
        p = self.plotter
        try:
            p.set_background(options.background)
            self.overlay = Overlay(options, clim)
            pv.Color(options.flat_color)
        except ValueError as exc:
            p.close()
            vtkObject.SetGlobalWarningDisplay(self._warnings)
            raise ExportError(f"preview: unknown colour ({str(exc).splitlines()[0]})") from exc
        self.poly = pv.wrap(polydata_from_mesh(mesh))
        self._mesh: Mesh = mesh
        self._set_arrays(mesh.positions, None)
        colored = options.color != "flat"
        lines_only = mesh.face_count == 0
        kwargs: dict[str, Any] = {
            "show_edges": options.wireframe,
            "edge_color": "#303030",
            "line_width": 1 if not lines_only else max(2, options.size[1] // 150),
            "render_lines_as_tubes": lines_only,
            "ambient": 0.4,
            "diffuse": 0.65,
            "specular": 0.1,
            "specular_power": 20,
            "smooth_shading": False,
            "interpolation": "gouraud",
        }
        if colored:
            kwargs.update(
                scalars="scalars",
                cmap=COLORMAPS[options.color],
                n_colors=LUT_COLORS,
                clim=list(clim) if clim is not None else None,
                show_scalar_bar=False,
            )
        else:
            kwargs.update(color=options.flat_color, show_scalar_bar=False)
        self.actor = p.add_mesh(self.poly, **kwargs)
        self._colliders = colliders if options.colliders else None
        self._collider_polys: list[Any] = []
        if self._colliders is not None:
            for surface in self._colliders.at(0.0):
                self._collider_polys.append(self._add_collider(surface))
        self.pins: Any = None
        if options.highlight_pins and self._pinned_rest is not None and self._pinned_rest.any():
            self.pins = pv.PolyData(np.asarray(mesh.positions[self._pinned_rest], dtype=np.float32))
            p.add_mesh(
                self.pins,
                color="#ffd400",
                point_size=max(6, options.size[1] // 70),
                render_points_as_spheres=True,
                show_scalar_bar=False,
            )
        self.tears: Any = None
        if options.highlight_tears:
            self._rest_boundary = self._keys(boundary_edges(mesh), mesh.vertex_count)
            self.tears = pv.PolyData()
            self._tear_actor = p.add_mesh(
                pv.PolyData(np.zeros((1, 3), dtype=np.float32)),
                color="#ff00e0",
                line_width=max(2, options.size[1] // 200),
                show_scalar_bar=False,
            )
            self._tear_actor.mapper.SetInputData(self.tears)
        camera = frame_camera(
            bounds,
            options.view,
            options.size,
            options.up_axis,
            reserve_right=self.overlay.reserve[0],
            reserve_top=self.overlay.reserve[1],
        )
        cam = p.camera
        cam.position = camera.position
        cam.focal_point = camera.focal_point
        cam.up = camera.up
        cam.view_angle = camera.view_angle
        cam.SetWindowCenter(*camera.window_center)
        cam.clipping_range = camera.clipping
        p.camera_set = True
        self.camera = camera

    def _add_collider(self, surface: Surface) -> Any:
        """One collider's surface as an opaque grey actor; returns its PolyData (updated per frame)."""
        pv = self._pv
        faces = np.hstack([np.full((surface.triangles.shape[0], 1), 3), surface.triangles]).ravel()
        poly = pv.PolyData(np.asarray(surface.points, dtype=np.float32), faces=faces)
        if surface.smooth:
            poly.point_data["Normals"] = surface.normals.astype(np.float32)
            poly.point_data.active_normals_name = "Normals"
        actor = self.plotter.add_mesh(
            poly,
            color=FLOOR_COLOR if surface.floor else SOLID_COLOR,
            ambient=0.35,
            diffuse=0.7,
            specular=0.05,
            smooth_shading=False,
            interpolation="gouraud" if surface.smooth else "flat",
            show_scalar_bar=False,
            reset_camera=False,
        )
        actor.mapper.SetRelativeCoincidentTopologyPolygonOffsetParameters(*COLLIDER_DEPTH_OFFSET)
        return poly

    def _update_colliders(self, time: float) -> None:
        """Move the collider surfaces to `time` and widen the clipping range to hold them."""
        colliders = self._colliders
        if colliders is None or not self._collider_polys:
            return
        surfaces = colliders.at(time)
        if colliders.animated:
            for poly, surface in zip(self._collider_polys, surfaces, strict=True):
                poly.points[:] = np.asarray(surface.points, dtype=np.float32)
                poly.GetPoints().Modified()
                if surface.smooth:
                    poly.point_data["Normals"] = surface.normals.astype(np.float32)
                poly.Modified()
        camera = self.camera
        position = np.asarray(camera.position)
        view = np.asarray(camera.focal_point) - position
        distance = float(np.linalg.norm(view))
        depth = np.concatenate([(s.points - position) @ (view / distance) for s in surfaces])
        near = max(min(camera.clipping[0], float(depth.min()) * 0.98), NEAR_FRACTION * distance)
        far = max(camera.clipping[1], float(depth.max()) * 1.02, near * 1.01)
        self.plotter.camera.clipping_range = (near, far)

    @staticmethod
    def _keys(edges: np.ndarray, n: int) -> np.ndarray:
        return edges[:, 0] * max(n, 1) + edges[:, 1]

    def _set_arrays(self, positions: np.ndarray, scalars: np.ndarray | None) -> None:
        from meshdeform.geometry import vertex_normals

        poly = self.poly
        pts = np.asarray(positions, dtype=np.float32)
        if poly.n_points == pts.shape[0]:
            poly.points[:] = pts
            poly.GetPoints().Modified()
        else:
            poly.points = pts
        if self._mesh.face_count:
            normals = vertex_normals(self._mesh, positions).astype(np.float32)
            poly.point_data["Normals"] = normals
            poly.point_data.active_normals_name = "Normals"
        values = np.ones(pts.shape[0], dtype=np.float32) if scalars is None else scalars.astype(np.float32)
        poly.point_data["scalars"] = values
        poly.point_data.active_scalars_name = "scalars"
        poly.Modified()

    def _set_topology(self, mesh: Mesh, positions: np.ndarray) -> None:
        new = self._pv.wrap(self._polydata_from_mesh(mesh, positions))
        self.poly.copy_from(new, deep=False)
        self._mesh = mesh

    def render(
        self,
        positions: np.ndarray,
        scalars: np.ndarray | None = None,
        mesh: Mesh | None = None,
        time: float = 0.0,
    ) -> np.ndarray:
        """Update the scene in place to this frame (colliders at `time` seconds) and return the bare view
        (H, W, 3) uint8, without label or colour bar (`self.overlay.decorate` draws them)."""
        self._update_colliders(time)
        if mesh is not None and mesh is not self._mesh:
            self._set_topology(mesh, positions)
        current = self._mesh
        self._set_arrays(positions, scalars)
        if self.pins is not None:
            mask = self._pinned_rest
            assert mask is not None
            m = min(mask.shape[0], positions.shape[0])
            self.pins.points = np.asarray(positions[:m][mask[:m]], dtype=np.float32)
            self.pins.Modified()
        if self.tears is not None:
            # torn: boundary edges now that were not boundary edges of the rest mesh (new vertices
            # from tearing are appended, so edges between original vertices keep their indices)
            edges = boundary_edges(current)
            rest_count = self.rest_mesh.vertex_count
            old = (edges < rest_count).all(axis=1)
            same = np.zeros(edges.shape[0], dtype=bool)
            same[old] = isin_int(self._keys(edges[old], rest_count), self._rest_boundary)
            torn = edges[~same]
            lines = np.hstack([np.full((torn.shape[0], 1), 2), torn]).ravel()
            self.tears.points = np.asarray(positions, dtype=np.float32)
            self.tears.lines = lines if torn.size else np.zeros(0, dtype=np.int64)
            self.tears.Modified()
        return self._draw()

    def _draw(self) -> np.ndarray:
        """Render and grab the image; with colliders, in the polygon-offset mode their depth offsets need
        (a process-wide VTK setting, restored at once; the cloth's own offsets are zero)."""
        from vtkmodules.vtkRenderingCore import vtkMapper

        previous = vtkMapper.GetResolveCoincidentTopology()
        if self._collider_polys:
            vtkMapper.SetResolveCoincidentTopologyToPolygonOffset()
        try:
            self.plotter.render()  # pyvista renders by itself only before the first screenshot
            return np.asarray(self.plotter.screenshot(return_img=True))[..., :3].copy()
        finally:
            vtkMapper.SetResolveCoincidentTopology(previous)

    def close(self) -> None:
        from vtkmodules.vtkCommonCore import vtkObject

        with contextlib.suppress(Exception):
            self.plotter.close()
        vtkObject.SetGlobalWarningDisplay(self._warnings)

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
