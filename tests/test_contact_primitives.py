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
