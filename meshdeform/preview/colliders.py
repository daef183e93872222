"""The scene's colliders as triangle surfaces in world coordinates, for previews to draw beside the cloth.

Each `meshdeform.scene.colliders.Collider` becomes one `Surface` at a time t: spheres and capsules
tessellated as surfaces of revolution (`SEGMENTS` around, `RINGS` from pole to pole), a box as its
8 corners and 12 triangles, a mesh collider as its own triangles, and a ground or plane as a finite
square of half-side `FLOOR_SCALE` times the cloth's bounds diagonal, centred on the foot of the
perpendicular from the cloth's bounds centre (the floor under the cloth). Every closed surface is
oriented outward. Animated colliders follow their keyframes (`Collider.keys.apply`: rigid motion and
uniform scale about the pivot): the rest-frame tessellation is made once and moved per frame; a
deforming body (`scene.deforming.DeformingMesh`) is drawn at its cache's positions at t.

Only the colliders' public attributes are read (the shape classes and their fields, `Collider.keys`,
`DeformingMesh.positions_at`),
not their contact code. Units: the cloth's (metres); arrays float64, triangles int64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from meshdeform.geometry import triangle_vertex_normals
from meshdeform.scene.base import Scene
from meshdeform.scene.colliders import Box, Capsule, Collider, Plane, Shape, Sphere, TriangleMesh
from meshdeform.scene.deforming import DeformingMesh

#: vertices around a sphere or capsule (longitude steps)
SEGMENTS = 48
#: latitude steps of a sphere from pole to pole (a capsule has this many over its two caps, plus its side)
RINGS = 24
#: half-side of a plane's square, in cloth bounds diagonals: the floor reaches past the framed cloth
FLOOR_SCALE = 3.0


@dataclass(frozen=True)
class Surface:
    """One collider's surface at one time.

    points: (N, 3) world positions. triangles: (T, 3) vertex indices, outward for closed shapes.
    smooth: shade with the vertex normals (`normals`, (N, 3) unit; spheres and capsules), else flat
    (boxes, meshes, planes: their facets are the collision geometry). floor: a plane (drawn as a floor).
    """

    points: np.ndarray
    triangles: np.ndarray
    smooth: bool
    floor: bool

    @property
    def normals(self) -> np.ndarray:
        """Area-weighted unit vertex normals (N, 3) of the triangles."""
        return triangle_vertex_normals(self.points, self.triangles)


def scene_colliders(scene: Scene) -> list[Collider]:
    """The colliders of a scene, in the order they act."""
    return [c for c in scene.constraints if isinstance(c, Collider)]


def lathe(
    ring_radius: np.ndarray, ring_height: np.ndarray, top: float, bottom: float, segments: int
) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented surface of revolution about the local z axis.

    ring_radius, ring_height: (R,) radius and z of each ring, top to bottom (radii > 0); top, bottom:
    z of the two poles. Returns points (2 + R * segments, 3) (top pole first, bottom pole last) and
    triangles (2 * R * segments, 3): a fan at each pole, two triangles per quad between rings.
    """
    rings = ring_radius.shape[0]
    phi = np.arange(segments) * (2.0 * np.pi / segments)
    ring_points = np.empty((rings, segments, 3))
    ring_points[..., 0] = ring_radius[:, None] * np.cos(phi)[None, :]
    ring_points[..., 1] = ring_radius[:, None] * np.sin(phi)[None, :]
    ring_points[..., 2] = ring_height[:, None]
    points = np.concatenate([[[0.0, 0.0, top]], ring_points.reshape(-1, 3), [[0.0, 0.0, bottom]]])
    last = points.shape[0] - 1
    j = np.arange(segments)
    nxt = (j + 1) % segments
    top_fan = np.stack([np.zeros(segments, dtype=np.int64), 1 + j, 1 + nxt], axis=1)
    bottom_fan = np.stack(
        [np.full(segments, last), 1 + (rings - 1) * segments + nxt, 1 + (rings - 1) * segments + j], axis=1
    )
    k = np.arange(rings - 1)[:, None] * segments
    a = (1 + k + j[None, :]).ravel()
    b = (1 + k + nxt[None, :]).ravel()
    c = b + segments
    d = a + segments
    bands = np.concatenate([np.stack([a, d, c], axis=1), np.stack([a, c, b], axis=1)])
    return points, np.concatenate([top_fan, bands, bottom_fan]).astype(np.int64)


def _axis_frame(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rows u, v, w: a right-handed orthonormal frame whose w is the unit `axis`."""
    w = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]
    u = np.cross(helper, w)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(w, u), w])


def sphere_surface(
    center: np.ndarray, radius: float, segments: int = SEGMENTS, rings: int = RINGS
) -> tuple[np.ndarray, np.ndarray]:
    """Points on the sphere and outward triangles (`lathe` over `rings` latitude steps)."""
    theta = np.arange(1, rings) * (np.pi / rings)
    points, triangles = lathe(radius * np.sin(theta), radius * np.cos(theta), radius, -radius, segments)
    return points + center, triangles


def capsule_surface(
    a: np.ndarray, b: np.ndarray, radius: float, segments: int = SEGMENTS, rings: int = RINGS
) -> tuple[np.ndarray, np.ndarray]:
    """Points within `radius` of segment a-b's surface: two hemispherical caps joined by the side."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    if length <= 1e-12 * max(radius, 1e-300):
        return sphere_surface(0.5 * (a + b), radius, segments, rings)
    half = rings // 2
    theta = np.arange(1, half + 1) * (np.pi / (2 * half))  # top cap down to its equator
    r = radius * np.sin(theta)
    z = radius * np.cos(theta)
    ring_radius = np.concatenate([r, r[::-1]])
    ring_height = np.concatenate([z + 0.5 * length, -z[::-1] - 0.5 * length])
    top = radius + 0.5 * length
    # the two equator rings (radius r, at +-length/2): the band between them is the cylinder side
    points, triangles = lathe(ring_radius, ring_height, top, -top, segments)
    return points @ _axis_frame(axis) + 0.5 * (a + b), triangles


#: the 12 outward triangles of a box over its corners i = x + 2 y + 4 z (bit set: the high side)
BOX_TRIANGLES = np.array(
    [
        [0, 4, 6], [0, 6, 2],  # -x
        [1, 3, 7], [1, 7, 5],  # +x
        [0, 1, 5], [0, 5, 4],  # -y
        [2, 6, 7], [2, 7, 3],  # +y
        [0, 2, 3], [0, 3, 1],  # -z
        [4, 5, 7], [4, 7, 6],  # +z
    ],
    dtype=np.int64,
)  # fmt: skip


def box_surface(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box's 8 corners (8, 3) and its 12 outward triangles."""
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, hi, lo).astype(np.float64), BOX_TRIANGLES.copy()


def square_surface(center: np.ndarray, normal: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A square of half-side `half` centred on `center` in the plane of unit `normal`: 4 corners and
    2 triangles facing along `normal`."""
    u, v, _ = _axis_frame(normal)
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]) * half
    return center + corners[:, :1] * u + corners[:, 1:] * v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def rest_surface(shape: Shape) -> tuple[np.ndarray, np.ndarray, bool] | None:
    """(points, triangles, smooth) of a bounded shape in its rest frame; None for a plane (its square
    depends on where the cloth is)."""
    if isinstance(shape, Sphere):
        return (*sphere_surface(shape.c, shape.radius), True)
    if isinstance(shape, Capsule):
        return (*capsule_surface(shape.a, shape.b, shape.radius), True)
    if isinstance(shape, Box):
        return (*box_surface(shape.lo, shape.hi), False)
    if isinstance(shape, TriangleMesh):
        return np.asarray(shape.vertices, dtype=np.float64), np.asarray(shape.triangles, dtype=np.int64), False
    if isinstance(shape, Plane):
        return None
    raise TypeError(f"preview: no surface for a {type(shape).__name__} collider")


class ColliderSurfaces:
    """The surfaces of a scene's colliders at any time, with planes as floors under the cloth.

    cloth_bounds: (2, 3) min and max corner of the cloth over the whole sequence (fixed, so a
    floor does not move between frames unless its plane does).
    """

    def __init__(self, colliders: Sequence[Collider], cloth_bounds: np.ndarray) -> None:
        bounds = np.asarray(cloth_bounds, dtype=np.float64).reshape(2, 3)
        self.colliders = list(colliders)
        self.cloth_center = 0.5 * (bounds[0] + bounds[1])
        self.floor_half = FLOOR_SCALE * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-6)
        self._rest = [rest_surface(c.shape) for c in self.colliders]

    @property
    def animated(self) -> bool:
        """Does any surface move over time?"""
        return any(c.keys is not None or isinstance(c.shape, DeformingMesh) for c in self.colliders)

    def at(self, time: float) -> list[Surface]:
        """Every collider's surface at `time` seconds, in collider order."""
        return [self._surface(collider, rest, time) for collider, rest in zip(self.colliders, self._rest, strict=True)]

    def _surface(self, collider: Collider, rest: tuple[np.ndarray, np.ndarray, bool] | None, time: float) -> Surface:
        keys = collider.keys
        if rest is not None:
            points, triangles, smooth = rest
            if isinstance(collider.shape, DeformingMesh):  # a body following its cache
                points = collider.shape.positions_at(time)
            elif keys is not None:
                points = keys.apply(points, time)
            return Surface(points, triangles, smooth, floor=False)
        plane = collider.shape
        assert isinstance(plane, Plane)
        point, normal = plane.point, plane.normal
        if keys is not None:  # where the keys take the plane's point and the tip of its normal
            moved = keys.apply(np.stack([point, point + normal]), time)
            point, normal = moved[0], (moved[1] - moved[0]) / np.linalg.norm(moved[1] - moved[0])
        foot = self.cloth_center - ((self.cloth_center - point) @ normal) * normal
        points, triangles = square_surface(foot, normal, self.floor_half)
        return Surface(points, triangles, smooth=False, floor=True)
