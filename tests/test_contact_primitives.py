"""The closest-point primitives against brute-force minimisation over dense samples."""

from __future__ import annotations

import numpy as np

from meshdeform.contact.primitives import point_triangle_weights, segment_segment_params


def _triangle_samples(tri: np.ndarray, n: int = 120) -> np.ndarray:
    """Points of a triangle (3, 3) on a barycentric lattice of n steps per side, (K, 3)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    u, v = i[keep] / n, j[keep] / n
    return tri[0] + u[:, None] * (tri[1] - tri[0]) + v[:, None] * (tri[2] - tri[0])


def test_point_triangle_matches_dense_sampling() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        tri = rng.normal(size=(3, 3))
        p = rng.normal(size=3) * 2.0
        wa, wb, wc = point_triangle_weights(p[0], p[1], p[2], tri, 0, 1, 2)
        assert min(wa, wb, wc) >= -1e-12 and abs(wa + wb + wc - 1.0) < 1e-12
        found = np.linalg.norm(p - (wa * tri[0] + wb * tri[1] + wc * tri[2]))
        sampled = np.linalg.norm(_triangle_samples(tri) - p, axis=1).min()
        assert found <= sampled + 1e-12  # never worse than any sample
        assert found >= sampled - 0.05 * np.linalg.norm(tri[1] - tri[0]) - 0.05  # and near the best


def test_point_triangle_degenerate_triangle_is_finite() -> None:
    tri = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    weights = point_triangle_weights(1.5, 1.0, 0.0, tri, 0, 1, 2)
    point = sum(w * tri[k] for k, w in enumerate(weights))
    assert np.all(np.isfinite(point))
    assert abs(np.linalg.norm(point - [1.5, 1.0, 0.0]) - 1.0) < 1e-9


def test_segment_segment_matches_dense_sampling() -> None:
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 1.0, 401)
    for case in range(200):
        p = rng.normal(size=(2, 3))
        q = rng.normal(size=(2, 3))
        if case % 10 == 0:  # parallel segments
            q[1] = q[0] + 0.7 * (p[1] - p[0])
        s_best, t_best = segment_segment_params(p, 0, 1, q, 0, 1)
        assert 0.0 <= s_best <= 1.0 and 0.0 <= t_best <= 1.0
        found = np.linalg.norm(p[0] + s_best * (p[1] - p[0]) - q[0] - t_best * (q[1] - q[0]))
        ps = p[0] + t[:, None] * (p[1] - p[0])
        qs = q[0] + t[:, None] * (q[1] - q[0])
        sampled = np.linalg.norm(ps[:, None, :] - qs[None, :, :], axis=2).min()
        assert found <= sampled + 1e-12
        assert found >= sampled - 0.02


# -- a triangle, segment or point against a box (`meshdeform.contact.box_distance`) ----------------

_BOX_LO = np.array([-0.3, -0.2, -0.5])
_BOX_HI = np.array([0.4, 0.25, 0.1])
#: the box's 12 triangles, for the oracle (corners by bits: 1 -> hi in x, 2 -> y, 4 -> z)
_BOX_FACES = [(0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3), (0, 4, 5), (0, 5, 1),
              (2, 3, 7), (2, 7, 6), (0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5)]  # fmt: skip


def _box_corners() -> np.ndarray:
    bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
    return np.where(bits == 1, _BOX_HI, _BOX_LO)


def _oracle_box_distance(tri: np.ndarray, corners: int) -> tuple[float, bool]:
    """(distance, meets) of a primitive (the first `corners` rows of tri) and the solid box, by
    the IPC Toolkit's squared distances and edge-triangle predicate on the box's 12 triangles:
    the distance of two disjoint convex sets is their surfaces' distance; they meet when a corner
    is inside or an edge of either crosses a face of the other."""
    import ipctk

    box = _box_corners()
    faces = [box[list(f)] for f in _BOX_FACES]
    box_edges = [(box[a], box[a | bit]) for a in range(8) for bit in (1, 2, 4) if not a & bit]
    pts = [tri[k] for k in range(corners)]
    edges = [(tri[k], tri[(k + 1) % corners]) for k in range(corners if corners == 3 else corners - 1)]
    squared = [ipctk.point_triangle_distance(p, *f) for p in pts for f in faces]
    squared += [ipctk.edge_edge_distance(p, q, r, s) for p, q in edges for r, s in box_edges]
    if corners == 3:
        squared += [ipctk.point_triangle_distance(c, *tri) for c in box]
    if corners == 2:
        squared += [ipctk.point_edge_distance(c, tri[0], tri[1]) for c in box]
    inside = any(np.all(p > _BOX_LO) and np.all(p < _BOX_HI) for p in pts)
    crossing = any(ipctk.is_edge_intersecting_triangle(p, q, *f) for p, q in edges for f in faces)
    if corners == 3:
        crossing = crossing or any(ipctk.is_edge_intersecting_triangle(r, s, *tri) for r, s in box_edges)
    return float(np.sqrt(min(squared))), inside or crossing


def test_primitive_box_closest_matches_the_ipc_toolkit() -> None:
    """Random triangles, segments and points about a box: outside, the clearance is ipctk's
    distance, reached by the points returned; where they meet, the answer says so (d <= 0) and
    points out of the box along a unit normal with d = n . (p - q)."""
    from meshdeform.contact.box_distance import primitive_box_closest

    rng = np.random.default_rng(11)
    box = _box_corners()
    seen = {"apart": 0, "meet": 0}
    for case in range(900):
        corners = 3 - case % 3
        centre = rng.uniform(-0.8, 0.8, size=3)
        tri = centre + rng.normal(scale=rng.choice([0.05, 0.3, 0.8]), size=(3, 3))
        if corners == 2:
            tri[2] = tri[1]
        elif corners == 1:
            tri[1] = tri[2] = tri[0]
        d, w0, w1, w2, qx, qy, qz, nx, ny, nz = primitive_box_closest(tri, corners, box, _BOX_LO, _BOX_HI)
        w = np.array([w0, w1, w2])
        assert np.all(w >= -1e-12) and abs(w.sum() - 1.0) < 1e-12
        p, q, n = w @ tri, np.array([qx, qy, qz]), np.array([nx, ny, nz])
        assert abs(np.linalg.norm(n) - 1.0) < 1e-9
        assert abs(n @ (p - q) - d) < 1e-9
        assert np.all(q >= _BOX_LO - 1e-12) and np.all(q <= _BOX_HI + 1e-12)
        distance, meets = _oracle_box_distance(tri, corners)
        if meets:
            seen["meet"] += 1
            assert d <= 1e-12, (case, d)
        else:
            seen["apart"] += 1
            assert abs(d - distance) < 1e-9, (case, d, distance)
            assert abs(np.linalg.norm(p - q) - d) < 1e-9
    assert min(seen.values()) > 80, seen  # both cases well covered


def test_a_triangle_pierced_by_a_box_edge_is_pushed_off_it() -> None:
    """A triangle with its corners outside the box, crossed by one of its edges near a corner of
    the box: the answer is negative, along the triangle's normal away from the box, and moving
    the triangle by -d along it clears the box (ipctk's predicates find no crossing after)."""
    from meshdeform.contact.box_distance import primitive_box_closest

    box = _box_corners()
    corner = _BOX_HI
    # a triangle cutting off the corner hi: its plane x + y + z = sum(hi) - 0.05, corners far out
    s = corner.sum() - 0.05
    tri = np.array([[s - corner[1] - corner[2] + 2.0, corner[1] - 1.0, corner[2] - 1.0],
                    [corner[0] - 1.0, s - corner[0] - corner[2] + 2.0, corner[2] - 1.0],
                    [corner[0] - 1.0, corner[1] - 1.0, s - corner[0] - corner[1] + 2.0]])  # fmt: skip
    assert _oracle_box_distance(tri, 3)[1]
    d, *_, nx, ny, nz = primitive_box_closest(tri, 3, box, _BOX_LO, _BOX_HI)
    n = np.array([nx, ny, nz])
    assert d < 0 and n @ np.ones(3) > 0
    assert abs(-d - 0.05 / np.sqrt(3)) < 1e-9  # the corner's depth beyond the plane
    moved = tri + (-d + 1e-9) * n
    assert not _oracle_box_distance(moved, 3)[1]


def test_the_placeholder_surface_is_the_one_surface_of_builds() -> None:
    """The shapes without a surface hand the contact kernels a one-triangle placeholder made in
    NumPy (so that a scene without a mesh collider compiles no BVH build): the same arrays as the
    BVH and normals kernels make of that triangle."""
    from meshdeform.contact.surface import surface_of
    from meshdeform.scene.colliders import _placeholder_surface

    made, built = _placeholder_surface(), surface_of(np.eye(3), np.array([[0, 1, 2]]))
    for name in ("vertices", "triangles", "normals"):
        assert getattr(made, name).dtype == getattr(built, name).dtype
        np.testing.assert_allclose(getattr(made, name), getattr(built, name), rtol=0, atol=1e-15)
    for name in ("bounds", "nodes", "order", "tri_bounds"):
        assert getattr(made.bvh, name).dtype == getattr(built.bvh, name).dtype
        assert np.array_equal(getattr(made.bvh, name), getattr(built.bvh, name))
    assert made.bvh.depth == built.bvh.depth and made.closed == built.closed
