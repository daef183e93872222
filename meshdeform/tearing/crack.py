"""Where a tear opens: which end of each failing structural spring splits, by which plane, and
how far the crack runs on in the same update.

- A failing structural spring (a mesh edge u-v) tears the cloth open at one of its ends: that
  vertex is split by the plane through it perpendicular to the spring, so the polygons around
  it on the far side of the plane get a copy of the vertex of their own. The crack runs along
  mesh edges (through vertices, across the pull), never through a polygon.
- Which end: a tearable, not hard-pinned end whose polygons lie on both sides of the plane
  (otherwise splitting it changes nothing); of two such ends the one on a boundary (an existing
  crack tip or the cloth's edge), then the lower index. When several failing springs pick the
  same vertex, the most stretched one sets its plane.
- A crack runs on in the same update: the load concentrates at its tips, so a tearable
  neighbour at the end of the new opening whose spring across the crack is already stretched to
  `tip` (0.9) of its threshold splits too (by the plane perpendicular to that spring), up to
  `lookahead` (8) vertices deep. Without it a crack could only advance one vertex per update,
  slower than the load builds up elsewhere in a fine mesh (which then fragments).
"""

from __future__ import annotations

import numpy as np

from meshdeform.arrays import run_lengths
from meshdeform.model import SpringModel
from meshdeform.tearing.corners import Corners, expand_ranges
from meshdeform.tearing.detect import SpringState, tested_structural
from meshdeform.tearing.settings import TearSettings


def plane_sides(
    corners: Corners, cv: np.ndarray, n: int, x: np.ndarray, vertices: np.ndarray, normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polygons around each vertex against the plane through it with that normal (k, 3):
    (entry per item, corner per item, signed distance of the corner's polygon centroid)."""
    owner, at = corners.of(cv, n, vertices)
    centroid = corners.centroids(cv, x, corners.face[at])
    d = np.einsum("ij,ij->i", centroid - x[vertices][owner], normals[owner])
    return owner, at, d


def choose_ends(
    corners: Corners,
    cv: np.ndarray,
    model: SpringModel,
    tearable: np.ndarray,
    x: np.ndarray,
    springs: np.ndarray,
    ratio: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For failing structural springs (indices (k,), stretch ratios (k,)): which end to split and
    the plane normal there.

    Returns (rows, vertex, normal): one row per vertex to split (set by the most stretched
    spring choosing it, ties to the lower spring index), then the rows of springs with no
    end that can split, with vertex -1.
    """
    n = model.vertex_count
    pairs = np.asarray(model.springs, dtype=np.int64)[springs]
    k = pairs.shape[0]
    ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
    direction = np.concatenate([x[pairs[:, 1]] - x[pairs[:, 0]], x[pairs[:, 0]] - x[pairs[:, 1]]])
    eligible = tearable[ends] & ~np.asarray(model.pinned)[ends]
    cand = np.flatnonzero(eligible)
    if cand.size:
        # splitting only helps where polygons lie on both sides of the plane
        owner, _, d = plane_sides(corners, cv, n, x, ends[cand], direction[cand])
        front = np.bincount(owner, weights=(d > 0).astype(np.float64), minlength=cand.shape[0])
        total = np.bincount(owner, minlength=cand.shape[0])
        eligible[cand[(front == 0) | (front == total)]] = False
    boundary = np.zeros(2 * k, dtype=bool)
    if eligible.any():
        boundary[eligible] = corners.on_boundary(cv, n, ends[eligible])
    # per spring: eligible first, then on a boundary (a crack tip or the edge), then the first end
    score = eligible.astype(np.int64) * 4 + boundary * 2 + np.repeat([1, 0], k)
    best = np.where(score[:k] >= score[k:], np.arange(k), np.arange(k, 2 * k))
    has = eligible[best]
    spring_rows = np.flatnonzero(has)
    cand_idx = best[spring_rows]
    vert = ends[cand_idx]
    order = np.lexsort((springs[spring_rows], -ratio[spring_rows], vert))
    starts, _ = run_lengths(vert[order])
    chosen = order[starts]
    none_rows = np.flatnonzero(~has)
    return (
        np.concatenate([spring_rows[chosen], none_rows]),
        np.concatenate([vert[chosen], np.full(none_rows.shape[0], -1, dtype=np.int64)]),
        np.concatenate([direction[cand_idx[chosen]], np.zeros((none_rows.shape[0], 3))]),
    )


def crack_ahead(
    model: SpringModel,
    settings: TearSettings,
    sp: SpringState,
    x: np.ndarray,
    vertices: np.ndarray,
    normals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Crack tips that give way in the same update: (vertices, plane normals).

    A crack concentrates the load at its tips. From each vertex being split, the crack runs
    on along its plane: a neighbour lying near that plane (a tip of the new opening) that may
    tear, is not pinned and has a structural spring across the crack (within 45 degrees of
    the plane normal) stretched to `settings.tip` times its threshold is split too, by the
    plane perpendicular to its most stretched such spring; up to `settings.lookahead` rings.
    """
    s = settings
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    if s.lookahead <= 0 or s.tip <= 0 or vertices.size == 0:
        return empty
    indptr, slots = tested_structural(sp, model)
    n = model.vertex_count
    taken = np.zeros(n, dtype=bool)
    taken[vertices] = True
    able = s.tearable & ~np.asarray(model.pinned)
    unit = normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
    front, front_n = vertices, unit
    found_v: list[np.ndarray] = []
    found_n: list[np.ndarray] = []

    def springs_at(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        owner, index = expand_ranges(indptr[verts], indptr[verts + 1] - indptr[verts])
        return owner, slots[index]

    for _ in range(s.lookahead):
        # neighbours of the front that lie near its plane: where the opening ends
        owner, slot = springs_at(front)
        here = front[owner]
        other = np.where(sp.a[slot] == here, sp.b[slot], sp.a[slot])
        d = x[other] - x[here]
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
        near_plane = np.abs(np.einsum("ij,ij->i", d, front_n[owner])) < 0.5 * length
        keep = near_plane & able[other] & ~taken[other]
        cand, cand_n = other[keep], front_n[owner[keep]]
        if cand.size == 0:
            break
        first = np.unique(cand, return_index=True)[1]  # one plane per candidate (the first front's)
        cand, cand_n = cand[first], cand_n[first]
        # their springs across the crack, and how far they are stretched toward breaking
        owner2, slot2 = springs_at(cand)
        e = x[sp.b[slot2]] - x[sp.a[slot2]]
        elen = np.maximum(np.linalg.norm(e, axis=1), 1e-300)
        across = np.abs(np.einsum("ij,ij->i", e, cand_n[owner2])) > 0.7071 * elen
        load = np.where(across, elen * sp.inv_rest[slot2] / sp.thr[slot2], 0.0)
        best = np.full(cand.shape[0], -1.0)
        np.maximum.at(best, owner2, load)
        gives = best >= s.tip
        if not gives.any():
            break
        # the plane of each new tip: perpendicular to its most loaded spring across the crack
        row = np.flatnonzero(load == best[owner2])
        pick = np.full(cand.shape[0], -1, dtype=np.int64)
        pick[owner2[row[::-1]]] = row[::-1]
        tips = np.flatnonzero(gives)
        new_n = e[pick[tips]]
        new_n /= np.maximum(np.linalg.norm(new_n, axis=1), 1e-300)[:, None]
        new_n *= np.where(np.einsum("ij,ij->i", new_n, cand_n[tips]) < 0, -1.0, 1.0)[:, None]
        front, front_n = cand[tips], new_n
        taken[front] = True
        found_v.append(front)
        found_n.append(front_n)
    if not found_v:
        return empty
    return np.concatenate(found_v), np.concatenate(found_n)
