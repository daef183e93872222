"""What acts on the cloth besides its springs: the Scene and its Forces and Constraints.

- `base`: `Scene` (and its gravity), the `Force` / `Constraint` / `Remappable` contracts, `PinMotion`;
- `forces`: wind with turbulence, impacts (Forces);
- `effects`: pressure, plasticity, tethers (material effects as Forces / Constraints);
- `pins`: keyframes, hard pin motion, soft pins (a Constraint);
- `colliders`: planes, spheres, boxes, capsules and triangle meshes (Constraints).
"""

from meshdeform.scene.base import Constraint, Force, PinMotion, Remappable, Scene, gravity_vector, up_vector
from meshdeform.scene.colliders import Box, Capsule, Collider, Plane, Shape, Sphere, TriangleMesh
from meshdeform.scene.effects import NearestPinTethers, Plasticity, Pressure
from meshdeform.scene.forces import Impact, Turbulence, Wind
from meshdeform.scene.pins import HardPinMotion, Keyframe, Keyframes, SoftPins

__all__ = [
    "Box",
    "Capsule",
    "Collider",
    "Constraint",
    "Force",
    "HardPinMotion",
    "Impact",
    "Keyframe",
    "Keyframes",
    "NearestPinTethers",
    "PinMotion",
    "Plane",
    "Plasticity",
    "Pressure",
    "Remappable",
    "Scene",
    "Shape",
    "SoftPins",
    "Sphere",
    "TriangleMesh",
    "Turbulence",
    "Wind",
    "gravity_vector",
    "up_vector",
]
