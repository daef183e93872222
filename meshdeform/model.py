"""SpringModel (static, built once, read-only arrays), State (what a solver advances) and
ContactPlanes (the colliders' contacts a solver may keep between two collider passes).

The model lives on welded vertices (see `topology.weld`); `vertex_map` takes results back to
the input's own vertex layout, which every output keeps.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from meshdeform.material import Material
from meshdeform.mesh import Mesh
from meshdeform.topology import KIND_NAMES, SpringKind, Springs, Welding, build_springs


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class SpringModel:
    """Static simulation data as a structure of arrays over W welded vertices and S springs.

    rest_positions (W, 3) float64; springs (S, 2) int32; rest_lengths (S,) float64;
    kinds (S,) int8 (SpringKind); stiffness / compression / damping (S,) float64 per spring
    from the material (times per-vertex maps where given); mass, inv_mass (W,) float64 with
    inv_mass 0 for hard-pinned vertices; pinned (W,) bool; vertex_map (V,) input -> welded;
    representative (W,) welded -> first input vertex; triangles (T, 3) int32 on welded indices
    (fan triangulation, for areas, wind, pressure and colliders).
    """

    rest_positions: np.ndarray
    springs: np.ndarray
    rest_lengths: np.ndarray
    kinds: np.ndarray
    stiffness: np.ndarray
    compression: np.ndarray
    damping: np.ndarray
    mass: np.ndarray
    inv_mass: np.ndarray
    pinned: np.ndarray
    vertex_map: np.ndarray
    representative: np.ndarray
    triangles: np.ndarray
    material: Material = field(default_factory=Material)

    @property
    def vertex_count(self) -> int:
        """Welded (simulated) vertex count."""
        return int(self.rest_positions.shape[0])

    @property
    def spring_count(self) -> int:
        return int(self.springs.shape[0])

    def spring_counts(self) -> dict[str, int]:
        return {name: int(np.count_nonzero(self.kinds == i)) for i, name in enumerate(KIND_NAMES)}

    def to_input_layout(self, welded_positions: np.ndarray) -> np.ndarray:
        """Positions in the input file's vertex order and count."""
        return welded_positions[self.vertex_map]

    def pinned_input_mask(self) -> np.ndarray:
        """(V,) bool: which input vertices are pinned."""
        return self.pinned[self.vertex_map]

    def with_pins(self, pinned: np.ndarray) -> SpringModel:
        """A copy with these welded vertices hard-pinned (inv_mass 0)."""
        pinned = np.asarray(pinned, dtype=bool)
        inv_mass = np.where(pinned, 0.0, 1.0 / self.mass)
        return replace(self, pinned=_frozen(pinned), inv_mass=_frozen(inv_mass))

    def spring_lengths(self, positions: np.ndarray) -> np.ndarray:
        """Current length of every spring for welded positions (S,)."""
        d = positions[self.springs[:, 1]] - positions[self.springs[:, 0]]
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def max_stretch(self, positions: np.ndarray, kind: SpringKind = SpringKind.STRUCTURAL) -> float:
        """Largest current/rest length ratio over springs of one kind (1.0 when there are none)."""
        mask = self.kinds == kind
        if not mask.any():
            return 1.0
        d = positions[self.springs[mask, 1]] - positions[self.springs[mask, 0]]
        ratio = np.sqrt(np.einsum("ij,ij->i", d, d)) / np.maximum(self.rest_lengths[mask], 1e-300)
        return float(ratio.max())

    @classmethod
    def from_mesh(
        cls,
        mesh: Mesh,
        material: Material | None = None,
        pinned_input: np.ndarray | None = None,
        welding_and_springs: tuple[Welding, Springs] | None = None,
        vertex_stiffness: np.ndarray | None = None,
        vertex_mass: np.ndarray | None = None,
    ) -> SpringModel:
        """Build the model: weld, derive springs, rest lengths, lumped masses, pins.

        pinned_input: (V,) bool over input vertices. vertex_stiffness: (V,) factor on every
        spring touching a vertex (a spring takes the mean of its two ends). vertex_mass: (V,)
        kg per input vertex, overriding the density-based mass.
        """
        material = material or Material()
        welding, springs = welding_and_springs or build_springs(mesh)
        rep = welding.representative
        positions = mesh.positions[rep].astype(np.float64)
        keep = _enabled_mask(springs.kinds, material)
        pairs = springs.pairs[keep]
        kinds = springs.kinds[keep]
        d = positions[pairs[:, 1]] - positions[pairs[:, 0]]
        rest = np.sqrt(np.einsum("ij,ij->i", d, d))
        per_kind = np.array([material.kind(k).stiffness for k in range(3)])
        per_kind_c = np.array([material.kind(k).compression_stiffness for k in range(3)])
        per_kind_d = np.array([material.kind(k).damping for k in range(3)])
        stiffness = per_kind[kinds]
        compression = per_kind_c[kinds]
        if vertex_stiffness is not None:
            vs = np.zeros(welding.count)
            np.maximum.at(vs, welding.vertex_map, np.asarray(vertex_stiffness, dtype=np.float64))
            factor = 0.5 * (vs[pairs[:, 0]] + vs[pairs[:, 1]])
            stiffness = stiffness * factor
            compression = compression * factor
        triangles = welding.vertex_map[mesh.triangles].astype(np.int32)
        mass = lumped_mass(positions, triangles, pairs[kinds == SpringKind.STRUCTURAL], material)
        if vertex_mass is not None:
            vm = np.zeros(welding.count)
            np.add.at(vm, welding.vertex_map, np.asarray(vertex_mass, dtype=np.float64))
            mass = np.where(vm > 0, vm, mass)
        pinned = np.zeros(welding.count, dtype=bool)
        if pinned_input is not None:
            pinned[welding.vertex_map[np.asarray(pinned_input, dtype=bool)]] = True
        inv_mass = np.where(pinned, 0.0, 1.0 / mass)
        return cls(
            rest_positions=_frozen(positions),
            springs=_frozen(pairs.astype(np.int32)),
            rest_lengths=_frozen(rest),
            kinds=_frozen(kinds.astype(np.int8)),
            stiffness=_frozen(stiffness.astype(np.float64)),
            compression=_frozen(compression.astype(np.float64)),
            damping=_frozen(per_kind_d[kinds].astype(np.float64)),
            mass=_frozen(mass),
            inv_mass=_frozen(inv_mass),
            pinned=_frozen(pinned),
            vertex_map=_frozen(welding.vertex_map),
            representative=_frozen(rep),
            triangles=_frozen(triangles),
            material=material,
        )


def _enabled_mask(kinds: np.ndarray, material: Material) -> np.ndarray:
    enabled = np.array([material.kind(k).enabled for k in range(3)], dtype=bool)
    return enabled[kinds]


def lumped_mass(positions: np.ndarray, triangles: np.ndarray, structural: np.ndarray, material: Material) -> np.ndarray:
    """Mass per welded vertex: a third of each incident triangle's area times the density.

    Vertices that touch no area (polylines, ropes) take half the length of their structural
    edges times the density; vertices touching nothing take the mean mass, so none is zero.
    """
    n = positions.shape[0]
    if material.vertex_mass is not None:
        return np.full(n, float(material.vertex_mass))
    mass = lumped_area(positions, triangles, n)
    mass *= material.density
    if structural.shape[0]:
        d = positions[structural[:, 1]] - positions[structural[:, 0]]
        half = 0.5 * np.sqrt(np.einsum("ij,ij->i", d, d)) * material.density
        edge_mass = np.bincount(structural.ravel(), weights=np.repeat(half, 2), minlength=n)
        mass = np.where(mass > 0, mass, edge_mass)
    positive = mass > 0
    fallback = float(mass[positive].mean()) if positive.any() else max(material.density, 1e-6) * 1e-3
    return np.where(positive, mass, fallback)


def lumped_area(positions: np.ndarray, triangles: np.ndarray, n: int) -> np.ndarray:
    """(n,) area each vertex carries (m^2): a third of each incident triangle's area, for
    positions (W, 3) and triangles (T, 3); the mass a vertex lumps is this times the density."""
    if triangles.shape[0] == 0:
        return np.zeros(n)
    e1 = positions[triangles[:, 1]] - positions[triangles[:, 0]]
    e2 = positions[triangles[:, 2]] - positions[triangles[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    return np.bincount(triangles.ravel(), weights=np.repeat(area / 3.0, 3), minlength=n)


@dataclass
class State:
    """What changes per step, over welded vertices: positions, previous positions, velocities, time."""

    positions: np.ndarray
    previous: np.ndarray
    velocities: np.ndarray
    time: float = 0.0

    @classmethod
    def at_rest(cls, model: SpringModel) -> State:
        positions = np.array(model.rest_positions, dtype=np.float64, copy=True)
        return cls(positions=positions, previous=positions.copy(), velocities=np.zeros_like(positions))

    def copy(self) -> State:
        return State(self.positions.copy(), self.previous.copy(), self.velocities.copy(), self.time)


class ContactPlanes(NamedTuple):
    """The colliders' contacts after the last substep as planes for the next one (`Control.planes`).

    Row k: the cloth point p = sum_j weights[k, j] x[vertices[k, j]] (a vertex, an edge point or a
    face point) keeps normals[k] . p >= offsets[k] + normals[k] . velocities[k] tau at the time
    tau (s) into the substep: the collider's surface plane at the contact, `thickness` out, moving
    with the surface's velocity (m/s) there; friction[k] is the collider's Coulomb coefficient.
    Shapes: vertices (C, 3) int64, weights, normals and velocities (C, 3) float64, offsets (m) and
    friction (C,) float64. A solver that runs many steps of its own between two collider passes
    (the explicit ones), or sweeps springs that pull a resting contact inward (xpbd), keeps its
    contacts on these planes: otherwise a resting cloth falls into the collider within the
    substep and is put back after it, and the cycle never comes to rest.
    """

    vertices: np.ndarray
    weights: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    velocities: np.ndarray
    friction: np.ndarray
