"""Colliders: ground/plane, sphere, box, capsule and static triangle meshes, as Constraints.

Each shape answers a vectorised closest-surface query in its own rest frame (`Shape.query`:
signed distance, negative inside, and outward unit normal; `Collider.signed_distance` in the
world). `Collider.project` runs after every solver substep and keeps the whole cloth surface,
not only its vertices, `thickness` away from the shape: every triangle, every edge outside a
triangle (ropes) and every vertex (`meshdeform.contact.collider_kernels`):

- continuous: each primitive's linear path from its start-of-substep position to its end
  position (in the collider's rest frame, so a keyframed collider's motion is included) is
  swept by conservative advancement on the exact distance, so nothing passes through a shape
  however thin or fast; the first contact found gives a plane the end position is kept in front of;
- then the contacts at the end positions (exact closest points of each triangle or edge to the
  shape) are resolved by position corrections weighted by the contact point's barycentric
  weights and the vertices' inverse masses, Gauss-Seidel in a fixed order;
- the velocity into the surface (relative to a moving collider) is removed at every contact
  point and the tangential velocity reduced by Coulomb friction.

Planes are tested at the vertices only: a half-space is convex and a triangle's distance to a
plane is linear over it, so its nearest point is always a vertex, and a vertex's path is a
straight line in the plane's frame. Boxes have exact closest points of their own
(`meshdeform.contact.box_distance`). Mesh colliders find exact closest points with a BVH over their
triangles; closed meshes are solids (inside: behind the nearest surface point by its
angle-weighted pseudo-normal), open ones two-sided sheets (each vertex keeps the side it was
last seen on). Every collider keeps at least `MIN_GAP`. Colliders can follow keyframes (rigid motion
plus uniform scale) like pins. `Collider.stats` counts the contacts and how often the swept
test found what the end positions alone would have missed.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from meshdeform.contact import collider_kernels as ck
from meshdeform.contact.bvh import TriangleBVH
from meshdeform.contact.surface import Surface, signed_closest, surface_of
from meshdeform.model import ContactPlanes, SpringModel, State
from meshdeform.scene.base import Constraint, Remappable
from meshdeform.scene.pins import Keyframes
from meshdeform.topology import SpringKind

#: scene units: the least contact gap of every collider, whatever its `thickness`: at 0, the cloth's
#: vertices lay on a box's faces with the triangles between them cutting its edges (5 to 12 mm
#: deep), and an open mesh collider is two-sided: a sheet's side is only known while the cloth
#: keeps clear of it
MIN_GAP = 1e-4
#: steps of conservative advancement per primitive and substep before a grazing path counts as a hit
MAX_ADVANCE_STEPS = 256
#: Gauss-Seidel sweeps: over the time-of-impact planes alone, then over planes and closest points
PLANE_SWEEPS = 2
JOINT_SWEEPS = 4
#: further sweep-and-solve rounds for primitives that the corrections moved into a new contact
EXTRA_ROUNDS = 2
#: a primitive left nearer than (1 - this) h after the corrections has its vertices put back
#: where they started the substep (`collider_kernels.fail_safe`)
FAIL_FRACTION = 0.1
#: a contact counts as touching at the end (its velocity treated) within this fraction above h
TOUCH_FRACTION = 1e-3
#: a primitive of the cloth nearer than this many thicknesses to a collider after a substep gets a
#: contact plane for the next (`Collider.planes`)
PLANE_REACH = 1.5
#: a contact point nearer than (1 - this) thicknesses after a substep gets its plane through
#: itself (`Collider.planes`); within it, the thickness out: the colliders' Gauss-Seidel leaves
#: points up to 1e-4 h inside (`collider_kernels.SETTLED`), and planes lowered to those let a
#: sheet on a ball sink by that every substep and never rest
PLANE_SLACK = 0.01
#: no velocities (`Collider.planes` near band alone): the plane kernel's empty (0, 3) array
NO_VELOCITIES = np.zeros((0, 3))
#: Gauss-Seidel sweeps of the contact velocities' sequential impulses (`collider_kernels.respond`)
RESPONSE_SWEEPS = 4
#: stretches of a frame over which a moving collider's speed is measured (`Collider.largest_speed`)
SPEED_SAMPLES = 8


def _unit(v: Sequence[float]) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _normalise_rows(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    length = np.sqrt(np.einsum("ij,ij->i", v, v))
    ok = length > 1e-12
    out = np.empty_like(v)
    out[ok] = v[ok] / length[ok, None]
    out[~ok] = fallback
    return out


def _placeholder_surface() -> Surface:
    """A one-triangle surface for the shapes that have none (the contact kernels take one list of
    arguments for every shape), made in NumPy: `surface_of` would compile the BVH build and the
    normals kernels in every process with an empty compile cache, for a scene without a mesh
    collider. The same arrays as `surface_of(np.eye(3), [[0, 1, 2]])`
    (tests/test_contact_primitives.py): the face's unit normal, its edges' (a lone face's), its
    corners' (the normal times the corner's angle), and a BVH of one leaf."""
    vertices = np.eye(3)
    triangles = np.array([[0, 1, 2]], dtype=np.int64)
    corners = vertices[triangles[0]]
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    normal /= np.linalg.norm(normal)
    first, second = np.roll(corners, -1, axis=0) - corners, np.roll(corners, 1, axis=0) - corners
    angles = np.arctan2(np.linalg.norm(np.cross(first, second), axis=1), np.einsum("ij,ij->i", first, second))
    normals = np.concatenate([np.tile(normal, (4, 1)), angles[:, None] * normal])[None]
    box = np.concatenate([corners.min(axis=0), corners.max(axis=0)])[None]
    bvh = TriangleBVH(
        bounds=box, nodes=np.array([[-1, -1, 0, 1]], dtype=np.int64), order=np.zeros(1, dtype=np.int64),
        tri_bounds=box.copy(), depth=1,
    )
    return Surface(vertices=vertices, triangles=triangles, normals=normals, bvh=bvh, closed=False)


class Shape:
    """A solid (or, for open meshes, two-sided) surface in its rest frame."""

    #: True when the inside is well defined (a vertex behind the surface is pushed out to the front)
    solid: bool = True

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (N,) and outward unit normal (N, 3) of the nearest surface point."""
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Axis-aligned bounds of the surface, None for unbounded shapes (planes)."""
        return None

    @property
    def center(self) -> np.ndarray:
        b = self.bounds()
        return np.zeros(3) if b is None else 0.5 * (b[0] + b[1])

    def arrays(self) -> ck.ShapeArrays:
        """The shape as the contact kernels read it (`collider_kernels.ShapeArrays`), built once."""
        cached = self.__dict__.get("_arrays")
        if cached is None:
            cached = self._make_arrays()
            self.__dict__["_arrays"] = cached
        return cached

    def _make_arrays(self) -> ck.ShapeArrays:
        raise NotImplementedError


def _arrays(
    kind: int,
    point: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    axis: np.ndarray | None = None,
    radius: float = 0.0,
    surface: Surface | None = None,
) -> ck.ShapeArrays:
    params = np.zeros((5, 3))
    params[1] = (0.0, 1.0, 0.0)
    if point is not None:
        params[0] = point
    if normal is not None:
        params[1] = normal
    if axis is not None:
        params[2:4] = axis
    params[4, 0] = radius
    return ck.shape_arrays(kind, params, _placeholder_surface() if surface is None else surface)


class Plane(Shape):
    """The half-space behind a plane through `point` with `normal` (the ground)."""

    def __init__(self, point: Sequence[float], normal: Sequence[float]) -> None:
        self.point = np.asarray(point, dtype=np.float64)
        self.normal = _unit(normal)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (points - self.point) @ self.normal, np.tile(self.normal, (points.shape[0], 1))

    @property
    def center(self) -> np.ndarray:
        return self.point

    def _make_arrays(self) -> ck.ShapeArrays:
        return _arrays(ck.PLANE, point=self.point, normal=self.normal)


class Sphere(Shape):
    def __init__(self, center: Sequence[float], radius: float) -> None:
        self.c = np.asarray(center, dtype=np.float64)
        self.radius = float(radius)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = points - self.c
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return length - self.radius, _normalise_rows(d, np.array([0.0, 1.0, 0.0]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.c - self.radius, self.c + self.radius

    def _make_arrays(self) -> ck.ShapeArrays:
        return _arrays(ck.SPHERE, point=self.c, radius=self.radius)


class Box(Shape):
    """An axis-aligned box (rotate it with keyframes)."""

    def __init__(self, lo: Sequence[float], hi: Sequence[float]) -> None:
        self.lo = np.asarray(lo, dtype=np.float64)
        self.hi = np.asarray(hi, dtype=np.float64)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = 0.5 * (self.lo + self.hi)
        h = 0.5 * (self.hi - self.lo)
        p = points - c
        q = np.abs(p) - h
        outside = np.maximum(q, 0.0)
        out_len = np.sqrt(np.einsum("ij,ij->i", outside, outside))
        inside = np.minimum(q.max(axis=1), 0.0)
        dist = out_len + inside
        sign = np.where(p < 0, -1.0, 1.0)
        normal = np.empty_like(p)
        is_out = out_len > 0
        normal[is_out] = outside[is_out] * sign[is_out] / out_len[is_out, None]
        axis = np.argmax(q[~is_out], axis=1)
        inner = np.zeros((axis.shape[0], 3))
        inner[np.arange(axis.shape[0]), axis] = sign[~is_out][np.arange(axis.shape[0]), axis]
        normal[~is_out] = inner
        return dist, normal

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lo, self.hi

    def corners(self) -> np.ndarray:
        """The 8 corners (8, 3): bit 0 of the index picks hi in x, bit 1 in y, bit 2 in z."""
        bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
        return np.where(bits == 1, self.hi, self.lo)

    def _make_arrays(self) -> ck.ShapeArrays:
        """Its corners as the surface's vertices (`closest_box` reads them, and no triangle, normal
        or BVH: the placeholder's, which spares a fresh process compiling the BVH build)."""
        return _arrays(
            ck.BOX, axis=np.stack([self.lo, self.hi]), surface=_placeholder_surface()._replace(vertices=self.corners())
        )


class Capsule(Shape):
    """All points within `radius` of the segment a-b."""

    def __init__(self, a: Sequence[float], b: Sequence[float], radius: float) -> None:
        self.a = np.asarray(a, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)
        self.radius = float(radius)

    def _fallback(self) -> np.ndarray:
        """A unit vector across the axis: the push direction of a point on the axis."""
        ab = self.b - self.a
        if float(ab @ ab) == 0.0:
            return np.array([0.0, 1.0, 0.0])
        fallback = np.cross(ab, [1.0, 0.0, 0.0])
        if np.linalg.norm(fallback) < 1e-12 * np.linalg.norm(ab):
            fallback = np.cross(ab, [0.0, 1.0, 0.0])
        return _unit(fallback)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ab = self.b - self.a
        denom = float(ab @ ab)
        t = np.clip((points - self.a) @ ab / denom, 0.0, 1.0) if denom > 0 else np.zeros(points.shape[0])
        d = points - (self.a + t[:, None] * ab)
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return length - self.radius, _normalise_rows(d, self._fallback())

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.minimum(self.a, self.b) - self.radius, np.maximum(self.a, self.b) + self.radius

    def _make_arrays(self) -> ck.ShapeArrays:
        return _arrays(ck.CAPSULE, normal=self._fallback(), axis=np.stack([self.a, self.b]), radius=self.radius)


def _outward(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Triangles of a closed mesh wound so that their normals point out (negative enclosed
    volume: all flipped); a consistently wound mesh is assumed."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum())
    return triangles[:, ::-1].copy() if volume < 0 else triangles


def surface_query(surface: Surface, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`Shape.query` of a triangle surface: signed distance (N,) (negative behind the nearest
    point's pseudo-normal) and outward unit normal (N, 3) of points (N, 3)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    closest, pseudo, dist = signed_closest(surface, points)
    offset = points - closest
    side = np.where(np.einsum("ij,ij->i", offset, pseudo) < 0, -1.0, 1.0)
    direction = offset / np.where(dist > 1e-12, dist, np.inf)[:, None]
    normal = np.where((dist > 1e-9)[:, None], direction * side[:, None], pseudo)
    return side * dist, normal


class TriangleMesh(Shape):
    """A static triangle mesh. Closed meshes are solids (behind the nearest surface point, by its
    angle-weighted pseudo-normal, is inside; an inside-out winding is turned outward); open ones
    are thin two-sided sheets whose side is remembered from the previous position.

    Closest points are exact: a BVH over the triangles (`meshdeform.contact.bvh`), built once.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        if self.triangles.shape[0] == 0:
            raise ValueError("a mesh collider needs at least one triangle")
        surface = surface_of(self.vertices, self.triangles)
        if surface.closed:
            outward = _outward(self.vertices, self.triangles)
            if outward is not self.triangles:
                self.triangles = outward
                surface = surface_of(self.vertices, self.triangles)
        self.surface = surface
        self.face_normals = surface.normals[:, 0]
        self.solid = surface.closed

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return surface_query(self.surface, points)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def _make_arrays(self) -> ck.ShapeArrays:
        return _arrays(ck.MESH, surface=self.surface)


@dataclass(frozen=True)
class ContactStats:
    """What a collider did, summed over the substeps it projected (subtract two to get a frame's).

    substeps: projections run; contacts: primitive contacts touching at substep ends; swept:
    contacts the swept test found along a path that was clear of the shape at its start;
    crossed: of those, the ones whose end position, as the solver left it, was inside or
    behind the surface, nearest to its other side or had passed beyond it (what a test at the
    end positions alone would have got wrong); rounds: extra sweep-and-solve rounds after corrections made new contacts;
    reverted: vertices put back at their start by the fail-safe (`collider_kernels.fail_safe`).
    """

    substeps: int = 0
    contacts: int = 0
    swept: int = 0
    crossed: int = 0
    rounds: int = 0
    reverted: int = 0

    def counts(self) -> tuple[int, int, int, int, int, int]:
        """The fields in order (`dataclasses.astuple` copies deeply and cost 0.3 ms a substep)."""
        return (self.substeps, self.contacts, self.swept, self.crossed, self.rounds, self.reverted)

    def __add__(self, other: ContactStats) -> ContactStats:
        return ContactStats(*(a + b for a, b in zip(self.counts(), other.counts(), strict=True)))

    def __sub__(self, other: ContactStats) -> ContactStats:
        return ContactStats(*(a - b for a, b in zip(self.counts(), other.counts(), strict=True)))


@dataclass(frozen=True)
class _ClothPrimitives:
    """A model's contact primitives as rows (i0, i1, i2): vertices (a, a, a), edges outside any
    triangle (a, b, b) (ropes, lines), triangles. `points`: every vertex (for planes);
    `surface`: the vertices in no triangle or edge, the edges, the triangles (spheres, capsules:
    a triangle's closest point covers its edges and corners); `every`: all vertices first (row i
    is vertex i), then the edges and triangles (meshes: the vertices carry the inside test and a
    sheet's side; boxes and meshes: a triangle lying flat on a face has its corners tied, and its
    contact falls on one of them only)."""

    points: np.ndarray
    surface: np.ndarray
    every: np.ndarray

    @classmethod
    def of(cls, model: SpringModel) -> _ClothPrimitives:
        n = model.vertex_count
        tris = np.asarray(model.triangles, dtype=np.int64).reshape(-1, 3)
        structural = np.asarray(model.springs[model.kinds == SpringKind.STRUCTURAL], dtype=np.int64)
        tri_edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        key = np.minimum(tri_edges[:, 0], tri_edges[:, 1]) * n + np.maximum(tri_edges[:, 0], tri_edges[:, 1])
        lo = np.minimum(structural[:, 0], structural[:, 1])
        hi = np.maximum(structural[:, 0], structural[:, 1])
        loose = structural[~np.isin(lo * n + hi, key)]
        used = np.zeros(n, dtype=bool)
        used[tris.ravel()] = True
        used[loose.ravel()] = True
        idx = np.arange(n, dtype=np.int64)
        points = np.stack([idx, idx, idx], axis=1)
        edges = loose[:, [0, 1, 1]]
        return cls(
            points=points,
            surface=np.ascontiguousarray(np.concatenate([points[~used], edges, tris])),
            every=np.ascontiguousarray(np.concatenate([points, edges, tris])),
        )


def collider_kinds(constraints: Sequence[Constraint]) -> frozenset[int]:
    """The shape kinds (`collider_kernels.PLANE` ..) of the colliders among `constraints`."""
    return frozenset(int(c.shape.arrays().kind) for c in constraints if isinstance(c, Collider))


def share_company(constraints: Sequence[Constraint]) -> None:
    """Tells each collider among `constraints` the shape kinds of all of them (`Collider.company`),
    so that a plane runs in the contact pipeline another collider's kind compiles anyway
    (`collider_kernels.contact_kernel`)."""
    kinds = collider_kinds(constraints)
    for constraint in constraints:
        if isinstance(constraint, Collider):
            constraint.company = kinds


def hold_contacts_still(constraints: Sequence[Constraint], hold: bool) -> None:
    """Tells each collider among `constraints` whether static friction puts a held contact back
    where it was along the surface (`Collider.holds_still`): off for a solver that holds contacts
    in its own step, whose own static friction holds them (`Solver.holds_contacts`)."""
    for constraint in constraints:
        if isinstance(constraint, Collider):
            constraint.holds_still = hold


def pushed_vertices(constraints: Sequence[Constraint], vertex_count: int, *, still: bool = False) -> np.ndarray:
    """(V,) bool: the vertices a collider among `constraints` moved in its last `project` (a
    still one only, where `still`)."""
    pushed = np.zeros(vertex_count, dtype=np.bool_)
    for collider in _pushing(constraints, vertex_count, still):
        pushed |= collider.pushed
    return pushed


def still_pushes(constraints: Sequence[Constraint], vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Which vertices a still collider moved in its last `project` (V,) bool
    (`Control.still_contact`), and the friction coefficient of that collider (V,) (the largest
    where several did; 0 where none did: `Control.friction`). A moving collider's contacts are
    left out of both: its static friction would hold a vertex to its moving surface, which the
    solver does not know (they keep the velocity friction alone), and a hold along the push of
    its moving, turning surface is no hold on it."""
    friction = np.zeros(vertex_count)
    for collider in _pushing(constraints, vertex_count, True):
        np.maximum(friction, np.where(collider.pushed, collider.friction, 0.0), out=friction)
    return pushed_vertices(constraints, vertex_count, still=True), friction


def _pushing(constraints: Sequence[Constraint], vertex_count: int, still: bool) -> list[Collider]:
    """The colliders among `constraints` whose last `project` left a (vertex_count,) `pushed`
    array (the still ones only, where `still`)."""
    return [
        c for c in constraints
        if isinstance(c, Collider) and not (still and c.moves) and c.pushed is not None
        and c.pushed.shape[0] == vertex_count
    ]


def fastest_motion(place: Callable[[float], np.ndarray], start: float, end: float) -> float:
    """The fastest (m/s) any of the points `place(time)` (N, 3) moves over [start, end] (s),
    measured over `SPEED_SAMPLES` equal stretches; 0 for an empty interval."""
    if end <= start:
        return 0.0
    times = np.linspace(start, end, SPEED_SAMPLES + 1)
    where = place(start)
    fastest = 0.0
    for before, after in itertools.pairwise(times):
        moved = place(after)
        step = moved - where
        fastest = max(fastest, float(np.sqrt(np.einsum("ij,ij->i", step, step).max(initial=0.0))) / (after - before))
        where = moved
    return fastest


def largest_surface_speed(constraints: Sequence[Constraint], points: np.ndarray, start: float, end: float) -> float:
    """The fastest (m/s) any collider among `constraints` would carry any of `points` (N, 3) over
    [start, end] (s) (`Collider.largest_speed`); 0 without a moving one."""
    speeds = [c.largest_speed(points, start, end) for c in constraints if isinstance(c, Collider) and c.moves]
    return max(speeds, default=0.0)


def nearest_obstacle(constraints: Sequence[Constraint], points: np.ndarray, time: float) -> float:
    """The smallest distance (m) of any of `points` (N, 3) from the surface of any collider among
    `constraints` at `time` (s), less that collider's thickness (negative: within it); infinite
    without a collider (`meshdeform.simulate`: a fast frame takes more steps only where the cloth
    can meet an obstacle within it)."""
    nearest = np.inf
    for constraint in constraints:
        if isinstance(constraint, Collider) and points.shape[0]:
            distance, _ = constraint.signed_distance(points, time)
            nearest = min(nearest, float(distance.min()) - constraint.thickness)
    return nearest


def contact_planes(constraints: Sequence[Constraint], model: SpringModel, state: State) -> ContactPlanes | None:
    """The contact planes of the colliders among `constraints` after their last `project` for the
    cloth of `model` at `state` (`Collider.planes`, the colliders' rows in list order;
    `Control.planes`); None without any."""
    parts = [c.planes(model, state.positions, state.velocities) for c in constraints if isinstance(c, Collider)]
    parts = [p for p in parts if p is not None and p.offsets.shape[0] > 0]
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return ContactPlanes(*(np.concatenate(column) for column in zip(*parts, strict=True)))


class Collider(Constraint, Remappable):
    """A shape as a Constraint: keeps the cloth's surface `thickness` outside it, with Coulomb friction.

    friction: 0 (ice) .. 1 and above (sticky); thickness: metres kept between the shape and every
    point of the cloth; keys: optional animation (rigid motion plus uniform scale, pivot in the keys).
    """

    def __init__(
        self, shape: Shape, friction: float = 0.2, thickness: float = 0.01, keys: Keyframes | None = None
    ) -> None:
        if keys is not None and not keys.uniform_scale:
            raise ValueError("collider animation must scale uniformly")
        self.shape = shape
        self.friction = float(friction)
        self.thickness = float(thickness)
        self.keys = keys
        self._side: np.ndarray | None = None
        self._totals = np.zeros(6, dtype=np.int64)  # `ContactStats`' fields in order, summed
        self._model: SpringModel | None = None
        self._prims: _ClothPrimitives | None = None
        #: whether a vertex contact that static friction holds is put back where it was along the
        #: surface (`collider_kernels.hold_still`; `hold_contacts_still`): off for a solver that
        #: holds contacts in its own step. Either way the contact velocities are solved to the end
        #: (`collider_kernels.respond`: sweeps of sequential impulses, then each vertex settled):
        #: one pass of point impulses over-pushed a vertex shared by several contacts, and a
        #: moving collider threw the cloth it carried (docs/performance.md, "A moving collider's
        #: contacts under implicit")
        self.holds_still = True
        #: (V,) bool: the vertices the last `project` moved (None before the first)
        self.pushed: np.ndarray | None = None
        #: the shape kinds of the scene's colliders (`share_company`): which compiled contact
        #: pipeline runs this one (`collider_kernels.contact_kernel`)
        self.company: frozenset[int] = frozenset()
        #: the time and substep of the last `project` (`planes`; None before the first)
        self._planes_at: tuple[float, float] | None = None

    @property
    def moves(self) -> bool:
        """Whether its surface moves (animated keys; a deforming body overrides it)."""
        return self.keys is not None

    def carry(self, points: np.ndarray, start: float, end: float) -> np.ndarray:
        """Where points (N, 3, world) fixed to its surface at `start` are at `end` (s): (N, 3)."""
        if self.keys is None:
            return np.array(points, dtype=np.float64)
        return np.asarray(self._to_world(self._to_local(points, start), end), dtype=np.float64)

    def largest_speed(self, points: np.ndarray, start: float, end: float) -> float:
        """The fastest (m/s) its surface moves where it may meet any of `points` (N, 3, world, at
        `start`) over [start, end] (s), from `SPEED_SAMPLES` stretches of its motion: what a cloth
        it meets may be moved at (`meshdeform.simulate.fast_steps_for`); 0 for a still one or one
        that reaches none of the points. A bounded shape: the fastest corner of its bounds (no
        slower than its surface), where a point lies within those bounds grown by its thickness
        and the farthest a corner moves in the interval; a plane: how fast it would carry the
        points themselves."""
        if self.keys is None or points.shape[0] == 0:
            return 0.0
        local = np.asarray(self._to_local(points, start))
        bounds = self.shape.bounds()
        if bounds is None:
            return fastest_motion(lambda time: self._to_world(local, time), start, end)
        lo, hi = bounds
        corners = np.where(((np.arange(8)[:, None] >> np.arange(3)) & 1) == 1, hi, lo)
        fastest = fastest_motion(lambda time: self._to_world(corners, time), start, end)
        scale = self._scale(start)
        reach = fastest * (end - start) / scale + self._gaps(scale)[0]
        return fastest if np.any(np.all((local >= lo - reach) & (local <= hi + reach), axis=1)) else 0.0

    @property
    def stats(self) -> ContactStats:
        """Contacts and continuous-collision work so far (`ContactStats`, summed over substeps)."""
        return ContactStats(*(int(total) for total in self._totals))

    @property
    def swept_hits(self) -> int:
        """Contacts found by the swept test along clear paths so far (`ContactStats.swept`)."""
        return int(self._totals[2])

    # -- frames ---------------------------------------------------------------------------------
    def _to_local(self, points: np.ndarray, time: float) -> np.ndarray:
        return points if self.keys is None else self.keys.inverse(points, time)

    def _to_world(self, points: np.ndarray, time: float) -> np.ndarray:
        return points if self.keys is None else self.keys.apply(points, time)

    def _scale(self, time: float) -> float:
        return 1.0 if self.keys is None else float(self.keys.scale_at(time)[0])

    def signed_distance(self, points: np.ndarray, time: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World signed distance (N,) and outward world normals (N, 3) at a time."""
        local = self._to_local(np.asarray(points, dtype=np.float64), time)
        dist, normal = self.shape.query(local)
        if self.keys is not None:
            dist = dist * self._scale(time)
            normal = normal @ self.keys.rotation(time).T
        return dist, normal

    def clearance(self, points: np.ndarray, time: float) -> np.ndarray:
        """(N,) m: how far each of `points` (N, 3) lies outside the thickness this collider keeps at
        `time`: its distance from the surface less the thickness (negative: within it, or inside
        a solid). An open mesh is two-sided: its distance on either side."""
        distance, _ = self.signed_distance(points, time)
        arrays = self._shape_at(time)
        if arrays.kind == ck.MESH and not arrays.closed:
            distance = np.abs(distance)
        return distance - self.thickness

    def planes(
        self, model: SpringModel, positions: np.ndarray, velocities: np.ndarray | None = None
    ) -> ContactPlanes | None:
        """Contact planes in the world (`ContactPlanes`) for the cloth of `model` at positions
        (V, 3) after the last `project` (the substep's end): every primitive of the cloth with a
        movable vertex nearer than `PLANE_REACH` thicknesses to the surface, or farther out but
        closing on its plane (at its velocity from `velocities` (V, 3), m/s, relative to the
        surface's) by more than the rest of that band within a substep (the last one's dt) and
        as far as it closes in one, gets the surface's tangent plane at its closest point, moved
        out by the thickness (or through the point itself where it lies nearer), with the
        surface's velocity there. Not only the contacts the last `project` touched: a face or
        vertex that hovers a hair above the surface after one substep falls onto it within the
        next (on a ball, a face's middle lies below its corners), and would meet it unheld; nor
        only the near ones: a stiff body landing at 2 m/s crossed a centimetre of the surface
        within a substep of 5 ms unheld, and the colliders' push after it compressed its bottom
        layer at once, which threw it back up higher than it fell (a plane that a point is still
        in front of holds nothing until the point reaches it). Not every point within the
        fastest one's reach either: a far point's tangent plane on a ball is no surface for a
        point moving along it. None before the first `project`."""
        if self._planes_at is None:
            return None
        time, dt = self._planes_at
        shape = self._shape_at(time)
        prims = self._primitives(model)
        scale = self._scale(time)
        h, _ = self._gaps(scale)
        reach = PLANE_REACH * h
        far = velocities is not None and velocities.shape[0] > 0
        if far:
            fastest = ck.fastest_speed(velocities, np.asarray(model.inv_mass, dtype=np.float64))
            fastest += self.largest_speed(positions, time, time + dt)
            reach += fastest * dt / scale
            far = reach > PLANE_REACH * h
        x = np.ascontiguousarray(self._to_local(positions, time), dtype=np.float64)
        lo, hi = self._bounds(shape)
        hint = self._hints(prims, x.shape[0], shape.kind == ck.MESH and not shape.closed)
        ids, rows, _ = ck.near_kernel(shape.kind, self.company)(
            *shape, x, prims, np.asarray(model.inv_mass) > 0.0, hint, lo, hi, reach,
        )  # fmt: skip
        surface_local = np.ascontiguousarray(rows[:, 3:6])
        normals = np.ascontiguousarray(rows[:, 6:9])
        if self.keys is not None:
            normals = np.ascontiguousarray(normals @ self.keys.rotation(time).T)
        surface = np.ascontiguousarray(self._to_world(surface_local, time), dtype=np.float64)
        surface_velocity = np.ascontiguousarray(self._surface_velocity(surface_local, time, dt), dtype=np.float64)
        # beyond the near band, only the points closing on their plane by more than the band in a
        # substep, as far as they close in one; and never further out than the point is now where
        # it was left nearer than the thickness (beyond the colliders' own tolerance, `PLANE_SLACK`;
        # by self-collision after the colliders, or a pin): it is not thrown out within the next
        # steps, whose position-based velocity would turn the way into speed; the colliders' pass
        # after the substep frees it with their own response
        vertices, weights, normals, offsets, surface_velocity = ck.plane_rows(
            ids, np.ascontiguousarray(rows[:, 0:3]), prims, np.ascontiguousarray(positions, dtype=np.float64),
            velocities if far else NO_VELOCITIES, normals, surface, surface_velocity, h * scale,
            (PLANE_REACH - 1.0) * h * scale, PLANE_SLACK * h * scale, dt, far,
        )  # fmt: skip
        return ContactPlanes(
            vertices=vertices, weights=weights, normals=normals, offsets=offsets,
            velocities=surface_velocity, friction=np.full(vertices.shape[0], self.friction),
        )  # fmt: skip

    def _gaps(self, scale: float) -> tuple[float, float]:
        """The thickness kept (at least `MIN_GAP`) and the advancement's tolerance, in the shape's
        local units (`scale`: the collider's scale at the time)."""
        h = max(self.thickness, MIN_GAP) / scale
        return h, 0.5 * h

    def _bounds(self, shape: ck.ShapeArrays) -> tuple[np.ndarray, np.ndarray]:
        """The shape's local bounds (zeros for an unbounded plane)."""
        bounds = self.shape.bounds() if shape.kind != ck.MESH else (shape.bounds[0, :3], shape.bounds[0, 3:])
        return (np.zeros(3), np.zeros(3)) if bounds is None else bounds

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear (`index_map`: new vertex -> old): copies remember their original's side."""
        if self._side is not None and self._side.shape[0] > int(index_map.max(initial=-1)):
            self._side = self._side[index_map]

    # -- what a deforming collider changes (`meshdeform.scene.deforming`) ------------------------
    def _shape_at(self, time: float) -> ck.ShapeArrays:
        """The shape as the kernels read it at a time (in its rest frame: it does not change)."""
        return self.shape.arrays()

    def _start_positions(self, state: State, end: np.ndarray, h: float, time: float, dt: float) -> np.ndarray:
        """The cloth's positions (W, 3) at the substep's start, in the frame the contact runs in
        (the collider's rest frame at time - dt). end: the local end positions; h: the local
        thickness."""
        return self._to_local(state.previous, time - dt)

    def _surface_velocity(self, points: np.ndarray, time: float, dt: float) -> np.ndarray:
        """World velocity (N, 3) over the substep of the collider's material points at local
        points (N, 3) at its end: what contact friction is relative to and what a vertex put
        back at its start moves with."""
        if self.keys is None or dt <= 0:
            return np.zeros_like(points)
        return (self._to_world(points, time) - self._to_world(points, time - dt)) / dt

    # -- the constraint -------------------------------------------------------------------------
    def _primitives(self, model: SpringModel) -> np.ndarray:
        """This shape's primitive rows for the model (cached per model: a tear makes a new one)."""
        if self._model is not model or self._prims is None:
            self._prims = _ClothPrimitives.of(model)
            self._model = model
        kind = self.shape.arrays().kind
        if kind == ck.PLANE:
            return self._prims.points
        if kind in (ck.MESH, ck.BOX):  # flat faces: a triangle's corners tie, each vertex has a row of its own
            return self._prims.every
        return self._prims.surface

    def _hints(self, prims: np.ndarray, n: int, sheet: bool) -> np.ndarray:
        """(P,) side each primitive keeps of an open sheet (+1, -1; 0 unknown); zeros otherwise.
        Vertex rows come first in the mesh set, so row i < n is vertex i."""
        hint = np.zeros(prims.shape[0])
        if not sheet:
            return hint
        if self._side is None or self._side.shape[0] != n:
            self._side = np.zeros(n)
        hint[:n] = self._side
        hint[n:] = np.sign(self._side[prims[n:]].sum(axis=1))
        return hint

    def project(
        self, model: SpringModel, state: State, time: float, dt: float, start: np.ndarray | None = None
    ) -> None:
        """Keep the cloth's surface `thickness` out of the shape after a substep (module
        docstring): state.previous and state.positions are the substep's start and end (time
        - dt, time); corrected positions, velocities and previous positions are written back
        for the vertices that changed only, so the others keep their bytes.

        start (V, 3), world positions: where the paths start instead, with the shape where it is
        at `time` (a pass after another constraint moved the cloth within the substep: the
        positions this collider left clear before that move). state.previous is what the velocities
        imply (self-collision's `_settle`), which need not be clear of the shape, and a contact the
        corrections cannot free goes back to its start."""
        shape = self._shape_at(time)
        prims = self._primitives(model)
        n = state.positions.shape[0]
        scale = self._scale(time)
        sheet = shape.kind == ck.MESH and not shape.closed
        h, gap = self._gaps(scale)
        floor = h - FAIL_FRACTION * h
        x1 = np.array(self._to_local(state.positions, time), dtype=np.float64, order="C")
        x0 = np.ascontiguousarray(
            self._start_positions(state, x1, h, time, dt) if start is None else self._to_local(start, time),
            dtype=np.float64,
        )
        lo, hi = self._bounds(shape)
        inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        hint = self._hints(prims, n, sheet)
        # a contact touches at the end within `touch`; static friction's hold runs inside the kernel,
        # before its fail-safe (a vertex held on a moving box's top could drag a triangle into its edge)
        touch = h * (1.0 + TOUCH_FRACTION) + 1e-12
        hold = self.friction if self.holds_still else 0.0
        ids, plane, end, d_end, push, moved, reverted, counts = ck.contact_kernel(shape.kind, self.company)(
            *shape, x0, x1, prims, inv_mass > 0, inv_mass, hint, lo, hi, h, gap, floor,
            MAX_ADVANCE_STEPS, PLANE_SWEEPS, JOINT_SWEEPS, EXTRA_ROUNDS, hold, touch,
        )  # fmt: skip
        if sheet:  # each vertex's side as the sweep found it (none crosses)
            self._side = hint[:n].copy()
        # velocities: at the final contact where it touches, else where a time-of-impact plane pushed
        acting = ck.acting_contacts(ids, plane, end, d_end, push, touch, self._totals, counts)
        ids, rows, push = ids[:acting], plane[:acting], push[:acting]
        self.pushed = moved  # the kernel's own array, new each call
        if self.keys is None:
            ck.copy_rows(state.positions, x1, moved)
        else:
            if moved.any():
                state.positions[moved] = self._to_world(x1[moved], time)
            rows[:, 6:9] = rows[:, 6:9] @ self.keys.rotation(time).T
        surface_v = self._surface_velocity(np.ascontiguousarray(rows[:, 3:6]), time, dt)
        self._planes_at = (time, dt)
        touched = moved.copy()
        ck.respond(
            state.velocities, inv_mass, prims, ids, rows, surface_v, push * scale, self.friction, dt, touched,
            RESPONSE_SWEEPS,
        )  # fmt: skip
        if reverted.any():  # they move with the collider
            state.velocities[reverted] = self._surface_velocity(np.ascontiguousarray(x0[reverted]), time, dt)
        ck.restart_paths(state.previous, state.positions, state.velocities, touched, dt)
