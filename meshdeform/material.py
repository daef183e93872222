"""Material: per spring kind stiffness and damping, and how mass is spread over vertices.

Stiffness is dimensionless in 0..1 so one recipe reads the same for every solver; each solver
documents how it maps it (a relaxation factor for `verlet`, a compliance for `xpbd`, a spring
constant for `springs` and `implicit`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from meshdeform.topology import KIND_NAMES, SpringKind


@dataclass(frozen=True)
class KindMaterial:
    """How one kind of spring behaves.

    stiffness: 0..1 under tension (1 = as stiff as the solver allows).
    compression: 0..1 when shorter than rest; None means the same as `stiffness`.
    damping: 0..1 spring damping along the spring (relative velocity).
    enabled: False removes this kind of spring altogether.
    """

    stiffness: float = 1.0
    compression: float | None = None
    damping: float = 0.0
    enabled: bool = True

    @property
    def compression_stiffness(self) -> float:
        return self.stiffness if self.compression is None else self.compression


@dataclass(frozen=True)
class Material:
    """Spring kinds plus mass: area density (kg/m^2; kg/m for polylines) or a fixed per-vertex mass."""

    structural: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=1.0, damping=0.0))
    shear: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=0.5, damping=0.0))
    bending: KindMaterial = field(default_factory=lambda: KindMaterial(stiffness=0.05, damping=0.0))
    density: float = 0.2
    vertex_mass: float | None = None

    def kind(self, kind: SpringKind | int) -> KindMaterial:
        return getattr(self, KIND_NAMES[int(kind)])
