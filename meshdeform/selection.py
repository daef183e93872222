"""Vertex selections: which input vertices a pin, impact, tear or material region applies to.

A selection is a small tree of nodes (`Indices`, `Box`, `Sphere`, `HalfSpace`, `Group`,
`Attribute`, combined with `AnyOf`, `AllOf`, `Not`) evaluated on a `Mesh` into a (V,) bool mask
over the input vertices, vectorised. Coordinates are absolute, or relative to the mesh's
bounding box (`relative=True`, see `BoundsFrame`) so one recipe serves assets of any size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from meshdeform.arrays import isin_int, unique_int
from meshdeform.errors import SelectionError
from meshdeform.mesh import Mesh

#: slack on box and plane tests, so boundaries given as 0 or 1 include the vertices on them
EPS = 1e-9


class SelectionResolveError(SelectionError):
    """A selection cannot be evaluated on a mesh; `path` is the key path of the node, `detail` what is wrong."""

    def __init__(self, path: str, detail: str) -> None:
        super().__init__(f"{path}: {detail}" if path else detail)
        self.path = path
        self.detail = detail


@dataclass(frozen=True)
class BoundsFrame:
    """Maps relative coordinates (0..1 per axis of the bounding box) to world coordinates.

    Axes along which the mesh is flat (extent below 1e-9 of the largest) use the largest extent
    instead, so relative coordinates can still reach above or below a flat sheet. Relative lengths
    (radii) are multiples of the largest extent.
    """

    origin: np.ndarray
    scale: np.ndarray

    @classmethod
    def from_positions(cls, positions: np.ndarray) -> BoundsFrame:
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape[0] == 0:
            return cls(np.zeros(3), np.ones(3))
        lo = positions.min(axis=0)
        extent = positions.max(axis=0) - lo
        largest = float(extent.max())
        if largest <= 0.0:
            largest = 1.0
        scale = np.where(extent > 1e-9 * largest, extent, largest)
        return cls(lo, scale)

    @property
    def size(self) -> float:
        """The largest extent: the unit of relative lengths."""
        return float(self.scale.max())

    def to_world(self, point: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(point, dtype=np.float64) * self.scale

    def to_relative(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.scale

    def length(self, value: float) -> float:
        return float(value) * self.size


@dataclass
class SelectionContext:
    """What nodes evaluate against: the mesh, its positions and bounding frame (relative coords cached)."""

    mesh: Mesh
    positions: np.ndarray
    frame: BoundsFrame
    _relative: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def for_mesh(cls, mesh: Mesh, positions: np.ndarray | None = None) -> SelectionContext:
        pos = np.asarray(mesh.positions if positions is None else positions, dtype=np.float64)
        return cls(mesh=mesh, positions=pos, frame=BoundsFrame.from_positions(mesh.positions))

    @property
    def relative_positions(self) -> np.ndarray:
        if self._relative is None:
            self._relative = self.frame.to_relative(self.positions)
        return self._relative

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])


@dataclass(frozen=True)
class Selection:
    """Base of the selection nodes; `path` names the node in error messages (e.g. `pins[0].select`)."""

    def mask(self, ctx: SelectionContext) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def indices(self, mesh: Mesh) -> np.ndarray:
        """Selected input vertex indices, sorted."""
        return np.flatnonzero(self.mask(SelectionContext.for_mesh(mesh)))


@dataclass(frozen=True)
class Indices(Selection):
    """An explicit list of input vertex indices."""

    values: tuple[int, ...]
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        idx = np.asarray(self.values, dtype=np.int64)
        out = np.zeros(ctx.count, dtype=bool)
        if idx.size:
            bad = (idx < 0) | (idx >= ctx.count)
            if bad.any():
                raise SelectionResolveError(
                    self.path, f"vertex index {int(idx[bad][0])} is out of range (the mesh has {ctx.count} vertices)"
                )
            out[idx] = True
        return out


@dataclass(frozen=True)
class Box(Selection):
    """Vertices inside an axis-aligned box (boundaries included)."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]
    relative: bool = False
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        p = ctx.relative_positions if self.relative else ctx.positions
        lo = np.asarray(self.min)
        hi = np.asarray(self.max)
        tol = EPS * (1.0 if self.relative else max(ctx.frame.size, 1.0))
        return np.all((p >= lo - tol) & (p <= hi + tol), axis=1)


@dataclass(frozen=True)
class Sphere(Selection):
    """Vertices within a radius of a centre (relative: centre in the box, radius times its largest extent)."""

    center: tuple[float, float, float]
    radius: float
    relative: bool = False
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        c = ctx.frame.to_world(self.center) if self.relative else np.asarray(self.center)
        r = ctx.frame.length(self.radius) if self.relative else self.radius
        d = ctx.positions - c
        return np.einsum("ij,ij->i", d, d) <= r * r * (1.0 + EPS)


@dataclass(frozen=True)
class HalfSpace(Selection):
    """Vertices on the side of a plane its normal points to (on the plane included)."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    relative: bool = False
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        p = ctx.relative_positions if self.relative else ctx.positions
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        tol = EPS * (1.0 if self.relative else max(ctx.frame.size, 1.0))
        return (p - np.asarray(self.point)) @ n >= -tol


@dataclass(frozen=True)
class Group(Selection):
    """Vertices of the faces in OBJ groups / objects (`Mesh.groups`)."""

    names: tuple[str, ...]
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        mesh = ctx.mesh
        missing = [n for n in self.names if n not in mesh.groups]
        if missing:
            known = ", ".join(sorted(mesh.groups)) or "none"
            raise SelectionResolveError(self.path, f"the mesh has no group {missing[0]!r} (groups: {known})")
        faces = np.concatenate([np.asarray(mesh.groups[n], dtype=np.int64) for n in self.names])
        corner_in = isin_int(mesh.corner_face, unique_int(faces))
        out = np.zeros(ctx.count, dtype=bool)
        out[mesh.face_indices[corner_in]] = True
        return out


def vertex_property(mesh: Mesh, name: str, channel: int | None, path: str = "") -> np.ndarray:
    """A per-vertex scalar (V,) float64 from `Mesh.vertex_properties`, one column of a (V, k) one."""
    if name not in mesh.vertex_properties:
        known = ", ".join(sorted(mesh.vertex_properties)) or "none"
        raise SelectionResolveError(path, f"the mesh has no vertex property {name!r} (properties: {known})")
    values = np.asarray(mesh.vertex_properties[name], dtype=np.float64)
    if values.ndim == 2 and values.shape[1] == 1 and channel is None:
        channel = 0
    if values.ndim == 2:
        if channel is None:
            raise SelectionResolveError(
                path, f"vertex property {name!r} has {values.shape[1]} channels: choose one with `channel`"
            )
        if not 0 <= channel < values.shape[1]:
            raise SelectionResolveError(
                path, f"channel {channel} is out of range: vertex property {name!r} has {values.shape[1]} channels"
            )
        values = values[:, channel]
    elif channel not in (None, 0):
        raise SelectionResolveError(path, f"vertex property {name!r} is a scalar: channel {channel} does not exist")
    if values.shape[0] != mesh.vertex_count:
        raise SelectionResolveError(path, f"vertex property {name!r} has {values.shape[0]} values, not one per vertex")
    return values


@dataclass(frozen=True)
class Attribute(Selection):
    """Vertices whose property value lies in [min, max] (either open); with neither, value > 0."""

    name: str
    channel: int | None = None
    min: float | None = None
    max: float | None = None
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        values = vertex_property(ctx.mesh, self.name, self.channel, self.path)
        if self.min is None and self.max is None:
            return values > 0.0
        out = np.ones(values.shape[0], dtype=bool)
        if self.min is not None:
            out &= values >= self.min
        if self.max is not None:
            out &= values <= self.max
        return out


@dataclass(frozen=True)
class AnyOf(Selection):
    """Union of the parts."""

    parts: tuple[Selection, ...]
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        out = np.zeros(ctx.count, dtype=bool)
        for part in self.parts:
            out |= part.mask(ctx)
        return out


@dataclass(frozen=True)
class AllOf(Selection):
    """Intersection of the parts."""

    parts: tuple[Selection, ...]
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        out = np.ones(ctx.count, dtype=bool)
        for part in self.parts:
            out &= part.mask(ctx)
        return out


@dataclass(frozen=True)
class Not(Selection):
    """Every vertex the part does not select (combine with AllOf for a difference)."""

    part: Selection
    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        return ~self.part.mask(ctx)


@dataclass(frozen=True)
class Everything(Selection):
    """Every vertex."""

    path: str = ""

    def mask(self, ctx: SelectionContext) -> np.ndarray:
        return np.ones(ctx.count, dtype=bool)


def resolve(selection: Selection, mesh: Mesh, path: str = "", *, allow_empty: bool = False) -> np.ndarray:
    """Evaluate a selection on a mesh into a (V,) bool mask; an empty result raises SelectionResolveError."""
    mask = selection.mask(SelectionContext.for_mesh(mesh))
    if not allow_empty and not mask.any():
        raise SelectionResolveError(
            path or getattr(selection, "path", ""), f"selects no vertex of the mesh ({mesh.vertex_count} vertices)"
        )
    return mask


def to_welded(mask_or_values: np.ndarray, vertex_map: np.ndarray, count: int) -> np.ndarray:
    """Carry a per-input-vertex mask (any copy selected) or values (largest copy) to welded vertices."""
    arr = np.asarray(mask_or_values)
    if arr.dtype == bool:
        out = np.zeros(count, dtype=bool)
        out[vertex_map[arr]] = True
        return out
    out = np.full(count, -np.inf)
    np.maximum.at(out, vertex_map, arr.astype(np.float64))
    return out
