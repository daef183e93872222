"""Deforming mesh colliders: a body whose vertices follow an animation (a point cache), as a Constraint.

A `DeformingMesh` is a triangle mesh with fixed triangles whose vertex positions (M, 3) at any
time come from a `Track` (seconds -> positions; `meshdeform.io.caches` samples a PC2, MDD, USD or
per-frame OBJ/PLY cache by linear interpolation between its frames). At every substep the
collider's surface is the mesh at the substep's end: the normals are computed anew and the BVH is
refitted, not rebuilt (`contact.surface.moved_surface`), so its closest points stay exact.

`DeformingCollider` runs the same contact as a rigid `Collider` (swept conservative advancement,
position corrections, friction: `meshdeform.scene.colliders`), with the body's motion folded in:
- the cloth's start-of-substep positions near the body are carried by the motion of their nearest
  body point over the substep (`surface_motion`), so the swept test sees the cloth's motion
  relative to the surface: a cloth point resting on a moving arm does not move relative to it,
  and a point the arm sweeps towards is met by the arm's own travel (exact where the body moves
  rigidly over a substep, a first-order approximation where it deforms);
- friction and the velocity of vertices put back at their start are relative to the velocity of
  the body's material point at the contact, from the same nearest-point weights.
Closed bodies are solids (inside: behind the nearest point's pseudo-normal), open ones two-sided
sheets, as for static meshes. The triangles are oriented outward once, at rest.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from meshdeform.contact import collider_kernels as ck
from meshdeform.contact.surface import Surface, closest_triangles, edge_index, moved_surface, surface_motion
from meshdeform.model import State
from meshdeform.scene.colliders import MIN_GAP, SPEED_SAMPLES, Collider, TriangleMesh, surface_query

#: maps a time in seconds (from the simulation's start) to the body's vertex positions (M, 3)
Track = Callable[[float], np.ndarray]

#: times closer than this (s) are the same instant (a substep's start is the last one's end)
SAME_TIME = 1e-9


def _largest_norm(vectors: np.ndarray) -> float:
    """The largest length among rows (N, 3) (0 for none)."""
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", vectors, vectors), initial=0.0)))


class DeformingMesh(TriangleMesh):
    """A triangle mesh whose vertices follow `track`: rest `vertices` (M, 3) (the pose the shape
    is oriented, classified closed or open and bound to by attached pins in), triangles (K, 3)
    int, track(t) -> (M, 3) positions at t seconds. `surface_at(t)` is the mesh at time t."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, track: Track) -> None:
        super().__init__(vertices, triangles)
        self.track = track
        self._edges = edge_index(self.triangles, self.vertices.shape[0])
        self._recent: list[tuple[float, Surface]] = []

    def positions_at(self, time: float) -> np.ndarray:
        """Vertex positions (M, 3) float64 at `time` seconds."""
        positions = np.asarray(self.track(time), dtype=np.float64)
        if positions.shape != self.vertices.shape:
            raise ValueError(f"the body's track gave {positions.shape} positions, not {self.vertices.shape}")
        return positions

    def surface_at(self, time: float) -> Surface:
        """The surface at `time` (the last two asked for are kept: a substep's end is the next
        one's start)."""
        for when, surface in self._recent:
            if abs(when - time) <= SAME_TIME:
                return surface
        surface = moved_surface(self.surface, self.positions_at(time), self._edges)
        self._recent = [*self._recent[-1:], (time, surface)]
        return surface

    def arrays_at(self, time: float) -> ck.ShapeArrays:
        """The kernels' view of the mesh at `time`."""
        return ck.shape_arrays(ck.MESH, self.arrays().params, self.surface_at(time))

    def query_at(self, points: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        """`Shape.query` against the mesh at `time`: signed distance (N,), outward normal (N, 3)."""
        return surface_query(self.surface_at(time), points)


class DeformingCollider(Collider):
    """A `DeformingMesh` as a collider (module docstring): keeps the cloth's surface `thickness`
    (m) out of the moving body, with Coulomb `friction` relative to the body's surface velocity."""

    shape: DeformingMesh

    def __init__(self, shape: DeformingMesh, friction: float = 0.2, thickness: float = 0.01) -> None:
        super().__init__(shape, friction=friction, thickness=thickness)

    def signed_distance(self, points: np.ndarray, time: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World signed distance (N,) and outward normals (N, 3) to the body at `time`."""
        return self.shape.query_at(np.asarray(points, dtype=np.float64), time)

    @property
    def moves(self) -> bool:
        """A deforming body's surface moves."""
        return True

    def carry(self, points: np.ndarray, start: float, end: float) -> np.ndarray:
        """Points (N, 3) moved as the body's surface nearest them moves from `start` to `end` (s)."""
        return points + self._surface_velocity(np.asarray(points, dtype=np.float64), end, end - start) * (end - start)

    def largest_speed(self, points: np.ndarray, start: float, end: float) -> float:
        """The fastest (m/s) the body's surface moves over [start, end] (s) where it may meet any
        of `points` (N, 3, world, at `start`), from `SPEED_SAMPLES` stretches of its track: the
        fastest corner of the triangles whose bounds over the interval, grown by the thickness,
        reach the points' bounds (a triangle's points move no faster than its fastest corner);
        0 where none does. A walking body's swinging hand does not count for a cape on its back."""
        if end <= start or points.shape[0] == 0:
            return 0.0
        times = np.linspace(start, end, SPEED_SAMPLES + 1)
        track = np.stack([self.shape.positions_at(float(time)) for time in times])  # (S + 1, M, 3)
        steps = np.diff(track, axis=0)
        speeds = (np.sqrt(np.einsum("smi,smi->sm", steps, steps)) / np.diff(times)[:, None]).max(axis=0)  # (M,)
        corners = self.shape.triangles
        grow = max(self.thickness, MIN_GAP)
        low = track.min(axis=0)[corners].min(axis=1) - grow  # (K, 3)
        high = track.max(axis=0)[corners].max(axis=1) + grow
        reached = np.all((low <= points.max(axis=0)) & (high >= points.min(axis=0)), axis=1)
        return float(speeds[corners[reached]].max(initial=0.0))

    def _shape_at(self, time: float) -> ck.ShapeArrays:
        return self.shape.arrays_at(time)

    def _start_positions(self, state: State, end: np.ndarray, h: float, time: float, dt: float) -> np.ndarray:
        start = self.shape.surface_at(time - dt)
        finish = self.shape.surface_at(time)
        # only cloth points that can reach the body within the substep need carrying: farther
        # than the body's and their own largest travel plus the thickness they cannot touch it
        body_travel = _largest_norm(finish.vertices - start.vertices)
        cloth_travel = _largest_norm(end - state.previous)
        reach = 2.0 * (body_travel + cloth_travel + h) + 1e-9
        previous = np.ascontiguousarray(state.previous, dtype=np.float64)
        return previous + surface_motion(start, start.vertices, finish.vertices, previous, reach)

    def _surface_velocity(self, points: np.ndarray, time: float, dt: float) -> np.ndarray:
        if dt <= 0 or points.shape[0] == 0:
            return np.zeros_like(points)
        start = self.shape.surface_at(time - dt)
        finish = self.shape.surface_at(time)
        return surface_motion(finish, start.vertices, finish.vertices, points, np.inf) / dt


class SurfaceAttachment:
    """Pin targets carried by a deforming body (`pins.Motion`): each rest point is bound once to
    the body's surface at time 0, to its nearest point there (triangle, barycentric weights) and
    its offset from that point in the triangle's frame (edge direction, in-plane normal to it,
    face normal), and at time t sits at the same weights and offset on the moved triangle. A
    point bound exactly on the surface stays on it; one a thickness away stays that far out
    along the turning normal."""

    def __init__(self, shape: DeformingMesh) -> None:
        self.shape = shape
        self._bindings: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _binding(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(triangles (P,), weights (P, 3), offsets (P, 3) in the triangle frames) of rest points."""
        key = points.tobytes()
        found = self._bindings.get(key)
        if found is None:
            surface = self.shape.surface_at(0.0)
            tri, weights = closest_triangles(surface, points)
            corners = surface.vertices[surface.triangles[tri]]
            anchor = np.einsum("pk,pkd->pd", weights, corners)
            frames = _triangle_frames(corners)
            offsets = np.einsum("pkd,pd->pk", frames, points - anchor)
            found = (tri, weights, offsets)
            self._bindings[key] = found
        return found

    def apply(self, points: np.ndarray, time: float) -> np.ndarray:
        """Positions (P, 3) at `time` of the rest points (P, 3)."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        tri, weights, offsets = self._binding(points)
        corners = self.shape.surface_at(time).vertices[self.shape.triangles[tri]]
        anchor = np.einsum("pk,pkd->pd", weights, corners)
        return anchor + np.einsum("pk,pkd->pd", offsets, _triangle_frames(corners))


def _triangle_frames(corners: np.ndarray) -> np.ndarray:
    """(P, 3, 3) orthonormal rows (edge 0-1 direction, in-plane perpendicular, unit normal) of
    triangles given by their corners (P, 3, 3); a degenerate triangle gets the world axes."""
    e1 = corners[:, 1] - corners[:, 0]
    normal = np.cross(e1, corners[:, 2] - corners[:, 0])
    e1_len = np.linalg.norm(e1, axis=1)
    n_len = np.linalg.norm(normal, axis=1)
    ok = (e1_len > 0) & (n_len > 0)
    frames = np.broadcast_to(np.eye(3), (corners.shape[0], 3, 3)).copy()
    u = e1[ok] / e1_len[ok, None]
    n = normal[ok] / n_len[ok, None]
    frames[ok, 0] = u
    frames[ok, 1] = np.cross(n, u)
    frames[ok, 2] = n
    return frames
