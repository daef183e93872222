"""Scripted cuts: at a time, split every vertex near a plane or a swept polyline at once.

A `Cut` at its time splits, in one go, every vertex on a mesh edge that crosses the cut
surface and whose polygons lie on both sides of it (the crack follows the mesh edges nearest to
the cut surface), optionally only the vertices of a selection. A polygon's side is the side of
its current centroid. Cuts may split hard-pinned vertices (each copy stays pinned to the same
target); tearing never does, since a pin that holds both copies cannot relieve the stress.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from meshdeform.tearing.corners import Corners


@dataclass(frozen=True, eq=False)
class Cut:
    """A scripted cut at `time` (s): through a plane (`point`, `normal`), or along a polyline
    (`points` (K, 3), K >= 2) swept along `direction` (the cut surface is the polyline moved
    along that direction; seen along it, the mesh is cut where the polyline crosses it).
    `mask` (W,) limits the vertices that may split (None: all)."""

    time: float
    point: np.ndarray | None = None
    normal: np.ndarray | None = None
    points: np.ndarray | None = None
    direction: np.ndarray | None = None
    mask: np.ndarray | None = None

    @classmethod
    def plane(cls, time: float, point: Sequence[float], normal: Sequence[float], mask: np.ndarray | None = None) -> Cut:
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        if not np.linalg.norm(n) > 0:
            raise ValueError("a cut plane needs a non-zero normal")
        p = np.asarray(point, dtype=np.float64).reshape(3)
        return cls(float(time), point=p, normal=n / np.linalg.norm(n), mask=mask)

    @classmethod
    def polyline(
        cls, time: float, points: Sequence[Sequence[float]], direction: Sequence[float], mask: np.ndarray | None = None
    ) -> Cut:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(direction, dtype=np.float64).reshape(3)
        if p.shape[0] < 2:
            raise ValueError("a cut polyline needs at least 2 points")
        if not np.linalg.norm(d) > 0:
            raise ValueError("a cut polyline needs a non-zero direction")
        return cls(float(time), points=p, direction=d / np.linalg.norm(d), mask=mask)


def cut_split(
    cut: Cut, corners: Corners, cv: np.ndarray, origin: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """What a cut splits at positions x (n, 3): (vertices to split (n,) bool, side of each
    corner's polygon (C,) int8), or None when it splits nothing. `origin` (n,) maps the current
    vertices to the welded vertices `cut.mask` is over."""
    n = x.shape[0]
    centroid = corners.centroids(cv, x, np.arange(corners.face_count, dtype=np.int64))
    s = cv
    e = cv[corners.nxt]
    if cut.normal is not None:
        assert cut.point is not None
        vside = (x - cut.point) @ cut.normal > 0
        face_side = (centroid - cut.point) @ cut.normal > 0
        crossing = vside[s] != vside[e]
    else:
        assert cut.points is not None and cut.direction is not None
        e1, e2 = _basis(cut.direction)
        poly = np.stack([cut.points @ e1, cut.points @ e2], axis=1)
        flat = np.stack([x @ e1, x @ e2], axis=1)
        face_side = _polyline_side(np.stack([centroid @ e1, centroid @ e2], axis=1), poly)
        crossing = _segments_cross(flat[s], flat[e], poly)
    near = np.zeros(n, dtype=bool)
    near[s[crossing]] = True
    near[e[crossing]] = True
    if cut.mask is not None:
        near &= np.asarray(cut.mask, dtype=bool)[origin]
    side = face_side[corners.face].astype(np.int8)
    # only vertices with polygons on both sides split
    count = np.bincount(cv, minlength=n)
    front = np.bincount(cv, weights=side.astype(np.float64), minlength=n)
    near &= (front > 0) & (front < count)
    if not near.any():
        return None
    return near, side


def _basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to `direction` and to each other."""
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _polyline_side(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: which side of a 2D polyline each point is on (by its nearest segment)."""
    a = poly[:-1]
    b = poly[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    best = np.full(points.shape[0], np.inf)
    sign = np.zeros(points.shape[0], dtype=bool)
    for k in range(a.shape[0]):  # over the cut's segments (a few), vectorised over the points
        ap = points - a[k]
        t = np.clip(ap @ ab[k] / length2[k], 0.0, 1.0)
        closest = a[k] + t[:, None] * ab[k]
        d = np.einsum("ij,ij->i", points - closest, points - closest)
        cross = ab[k, 0] * ap[:, 1] - ab[k, 1] * ap[:, 0]
        better = d < best
        best = np.where(better, d, best)
        sign = np.where(better, cross > 0, sign)
    return sign


def _segments_cross(p: np.ndarray, q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: whether 2D segment p-q crosses any segment of the polyline."""
    out = np.zeros(p.shape[0], dtype=bool)

    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])

    for k in range(poly.shape[0] - 1):  # over the cut's segments, vectorised over the edges
        a, b = poly[k], poly[k + 1]
        d1 = orient(a, b, p)
        d2 = orient(a, b, q)
        d3 = orient(p, q, a[None, :])
        d4 = orient(p, q, b[None, :])
        out |= ((d1 > 0) != (d2 > 0)) & ((d3 > 0) != (d4 > 0))
    return out
