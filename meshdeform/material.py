"""Material: per spring kind stiffness and damping, and how mass is spread over vertices.

Stiffness is dimensionless in 0..1 per spring kind, so one recipe reads the same for every
solver. The three force/compliance based solvers share one physical mapping, so they agree
on the equilibrium shape (a hanging cloth sags the same with each of them once converged):

    k = stiffness * stretch_modulus            [N/m, independent of the spring's length]

Independent of length, so on a regular grid the sheet's resistance to stretch does not
change with the resolution (a finer grid has more, shorter springs side by side and in
series). How each solver uses a kind's `stiffness` s, `compression` c and `damping` z:

| solver     | stiffness s                                  | compression c            | damping z (ratio)            |
|------------|----------------------------------------------|--------------------------|------------------------------|
| `anchor`   | neighbour springs (option): k = s * modulus  | k = c * modulus          | as `springs`                 |
| `verlet`   | relaxation: a substep removes the fraction   | same, k = c * modulus,   | not used (air damping only)  |
|            | k dt^2 w / (1 + k dt^2 w) of a spring's      | when shorter than rest   |                              |
|            | error, k = s * modulus, w = w_a + w_b; per   |                          |                              |
|            | sweep 1 - (1 - that) ** (1 / iterations)     |                          |                              |
| `xpbd`     | compliance alpha = 1 / (s * modulus) [m/N];  | alpha = 1 / (c * modulus)| XPBD constraint damping with |
|            | s = 0 removes the constraint                 |                          | c = 2 z sqrt(k m_reduced)    |
| `springs`  | Hooke: f = k (l - L), k = s * modulus        | k = c * modulus          | c = 2 z sqrt(k m_reduced)    |
| `implicit` | k = s * modulus (projective dynamics weight) | k = c * modulus          | not used (integrator + air)  |

A single spring of stiffness s between a pinned point and a mass m therefore oscillates
with period 2 pi sqrt(m / (s * stretch_modulus)) under `springs`, `implicit` and `xpbd`, and
hangs at the stretch m g / (s * stretch_modulus) under all four. On a mesh the position based
solvers (`verlet`, `xpbd`) reach that equilibrium only when their sweeps converge; too few for
the mesh leave the cloth softer (each frame's `force_residual` says how far from it a cloth at
rest is: `meshdeform.simulate`, figures in docs/performance.md).
`damping` z is the spring's damping ratio: 1 damps the relative motion of its two ends
critically. Air damping of whole-vertex velocity is a solver option
(`SolverOptions.damping`), not a material property.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from meshdeform.topology import KIND_NAMES, SpringKind


@dataclass(frozen=True)
class KindMaterial:
    """How one kind of spring behaves.

    stiffness: 0..1 under tension (1 = as stiff as the material's stretch_modulus).
    compression: 0..1 when shorter than rest; None means the same as `stiffness`.
    damping: 0..1 spring damping ratio along the spring (relative velocity of its ends).
    enabled: False removes this kind of spring altogether.
    """

    stiffness: float = 1.0
    compression: float | None = None
    damping: float = 0.1
    enabled: bool = True

    @property
    def compression_stiffness(self) -> float:
        return self.stiffness if self.compression is None else self.compression


@dataclass(frozen=True)
class Material:
    """Spring kinds plus mass: area density (kg/m^2; kg/m for polylines) or a fixed per-vertex mass.

    stretch_modulus: N/m, the spring constant of a spring of stiffness 1 (see the module
    docstring for how each solver uses it). On a grid it is also about the sheet's resistance
    to stretch per unit width (N per m of width per unit strain), whatever the resolution. The
    default 10 000 N/m is a light woven fabric (woven cotton measures some 10 to 50 kN/m along
    its threads; knits and jersey 100 to 1000 N/m): a 1 m cloth of 0.2 kg/m^2 hanging from two
    corners sags about 0.2 mm by stretching, and a 256 x 256 one stretches 1.03 at the pins
    (1000 N/m: 1.25, rubbery; docs/performance.md, "The woven default material").
    """

    structural: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=1.0, damping=0.1))
    shear: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=0.5, damping=0.1))
    bending: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=0.005, damping=0.1))
    density: float = 0.2
    vertex_mass: float | None = None
    stretch_modulus: float = 10000.0

    def kind(self, kind: SpringKind | int) -> KindMaterial:
        return getattr(self, KIND_NAMES[int(kind)])

    def spring_constant(self, stiffness: float) -> float:
        """k in N/m of a spring with this dimensionless stiffness (springs, implicit, xpbd)."""
        return float(stiffness) * self.stretch_modulus
