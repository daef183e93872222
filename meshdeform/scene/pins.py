"""Pins: hard pins following keyframed targets, soft pins pulling toward them, and the keyframes.

Hard pins are the model's `pinned` vertices (inv_mass 0): the simulate loop puts them at
`Scene.pin_motion(time)` every substep, so `HardPinMotion` only evaluates the animation. Soft
pins are a Constraint: after each solver substep a pinned vertex moves a fraction of the way to
its target, chosen so that the pull behaves like a zero-length spring of `k` (1/s^2)
independent of the substep size (equilibrium sag under gravity g/k, as in XPBD).

Targets move by a `Motion`: `Keyframes`, or a pin attached to a collider (its keyframes, or for a
deforming body `deforming.SurfaceAttachment`, which carries each point with the body surface it
was bound to at rest).

Keyframes (`Keyframes`) hold translate / rotate (Euler XYZ degrees) / scale channels, linearly
interpolated, applied about a pivot: target = pivot + T + R S (rest - pivot). A key that omits
a channel keeps that channel's previous value (identity before the first key that sets it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Constraint, Remappable

#: soft-pin spring constant per unit stiffness-odds: k = SOFT_PIN_RATE * s / (1 - s) in 1/s^2,
#: so stiffness 0.5 sags 1 cm under 9.81 m/s^2 and 0.9 about 1 mm
SOFT_PIN_RATE = 1000.0


class Motion(Protocol):
    """How pin targets move: rest points (P, 3) -> their positions (P, 3) at `time` seconds (the
    same rest points give the same result: implementations may bind them once)."""

    def apply(self, points: np.ndarray, time: float) -> np.ndarray: ...


@dataclass(frozen=True)
class Keyframe:
    """One key: time (s) and any of translate (3,), rotate (3,) Euler XYZ degrees, scale (3,)."""

    time: float
    translate: tuple[float, float, float] | None = None
    rotate: tuple[float, float, float] | None = None
    scale: tuple[float, float, float] | None = None


def euler_matrices(degrees: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) for Euler angles (N, 3) in degrees: R = Rz @ Ry @ Rx."""
    a = np.deg2rad(np.atleast_2d(np.asarray(degrees, dtype=np.float64)))
    cx, cy, cz = np.cos(a).T
    sx, sy, sz = np.sin(a).T
    r = np.empty((a.shape[0], 3, 3))
    r[:, 0, 0] = cy * cz
    r[:, 0, 1] = sx * sy * cz - cx * sz
    r[:, 0, 2] = cx * sy * cz + sx * sz
    r[:, 1, 0] = cy * sz
    r[:, 1, 1] = sx * sy * sz + cx * cz
    r[:, 1, 2] = cx * sy * sz - sx * cz
    r[:, 2, 0] = -sy
    r[:, 2, 1] = sx * cy
    r[:, 2, 2] = cx * cy
    return r


class Keyframes:
    """A keyframed rigid-plus-scale transform about a pivot, linearly interpolated, held outside the keys.

    loop: after the last key, start again from the first (period = last time - first time).
    """

    def __init__(self, keys: Sequence[Keyframe], pivot: np.ndarray | Sequence[float], loop: bool = False) -> None:
        if not keys:
            raise ValueError("keyframes need at least one key")
        times = np.array([k.time for k in keys], dtype=np.float64)
        if np.any(np.diff(times) <= 0):
            raise ValueError("keyframe times must increase strictly")
        self.times = times
        self.pivot = np.asarray(pivot, dtype=np.float64).reshape(3)
        self.loop = bool(loop)
        self.channels = np.empty((len(keys), 9))  # translate, rotate, scale
        current = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
        for i, key in enumerate(keys):
            if key.translate is not None:
                current[0:3] = key.translate
            if key.rotate is not None:
                current[3:6] = key.rotate
            if key.scale is not None:
                current[6:9] = key.scale
            self.channels[i] = current

    @property
    def uniform_scale(self) -> bool:
        s = self.channels[:, 6:9]
        return bool(np.all(s == s[:, :1]))

    def _local_time(self, time: float) -> float:
        t0, t1 = self.times[0], self.times[-1]
        if self.loop and t1 > t0 and time > t1:
            return t0 + (time - t0) % (t1 - t0)
        return time

    def at(self, time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(translate (3,), rotation (3, 3), scale (3,)) at a time."""
        t = self._local_time(float(time))
        if self.times.shape[0] == 1:
            values = self.channels[0]
        else:
            values = np.array([np.interp(t, self.times, self.channels[:, c]) for c in range(9)])
        return values[0:3], euler_matrices(values[3:6])[0], values[6:9]

    def apply(self, points: np.ndarray, time: float) -> np.ndarray:
        """Transformed points (N, 3): pivot + T + R S (points - pivot)."""
        translate, rot, scale = self.at(time)
        local = (np.asarray(points, dtype=np.float64) - self.pivot) * scale
        return self.pivot + translate + local @ rot.T

    def inverse(self, points: np.ndarray, time: float) -> np.ndarray:
        """Rest-frame points for world points: the inverse of `apply` (scale must be non-zero)."""
        translate, rot, scale = self.at(time)
        local = (np.asarray(points, dtype=np.float64) - self.pivot - translate) @ rot
        return self.pivot + local / scale

    def rotation(self, time: float) -> np.ndarray:
        return self.at(time)[1]

    def scale_at(self, time: float) -> np.ndarray:
        return self.at(time)[2]


class HardPinMotion:
    """`Scene.pin_motion` for hard pins: targets of `np.flatnonzero(model.pinned)` at a time.

    groups: (welded vertex indices, `Motion` or None) per pin entry; a vertex in several
    entries follows the last one. Pinned vertices in no animated group stay at rest.
    """

    def __init__(self, model: SpringModel, groups: Sequence[tuple[np.ndarray, Motion | None]]) -> None:
        self.pinned_idx = np.flatnonzero(model.pinned)
        self.rest = np.array(model.rest_positions[self.pinned_idx], dtype=np.float64)
        owner = np.full(self.pinned_idx.shape[0], -1, dtype=np.int64)
        for g, (idx, _) in enumerate(groups):
            idx = np.asarray(idx, dtype=np.int64)
            idx = idx[model.pinned[idx]]
            owner[np.searchsorted(self.pinned_idx, idx)] = g
        self.animated: list[tuple[np.ndarray, Motion]] = []
        for g, (_, keys) in enumerate(groups):
            slots = np.flatnonzero(owner == g)
            if keys is not None and slots.size:
                self.animated.append((slots, keys))

    @property
    def is_animated(self) -> bool:
        return bool(self.animated)

    def __call__(self, time: float) -> np.ndarray:
        out = self.rest.copy()
        for slots, keys in self.animated:
            out[slots] = keys.apply(self.rest[slots], time)
        return out


def soft_pin_rate(stiffness: np.ndarray | float) -> np.ndarray:
    """Spring constant k (1/s^2) for soft-pin stiffness in [0, 1): SOFT_PIN_RATE * s / (1 - s)."""
    s = np.clip(np.asarray(stiffness, dtype=np.float64), 0.0, 1.0 - 1e-9)
    return SOFT_PIN_RATE * s / (1.0 - s)


class SoftPins(Constraint, Remappable):
    """Constraint pulling vertices toward (animated) targets like zero-length springs.

    indices: welded vertices; stiffness: (P,) in [0, 1) (see `soft_pin_rate`); keys: optional
    motion of the targets (`Motion`: keyframes or an attachment, of the rest positions);
    damping: fraction of the velocity relative to the target removed per second (0..1).
    """

    def __init__(
        self,
        indices: np.ndarray,
        rest: np.ndarray,
        stiffness: np.ndarray | float,
        keys: Motion | None = None,
        damping: float = 0.0,
    ) -> None:
        self.indices = np.asarray(indices, dtype=np.int64)
        self.rest = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
        self.rate = np.broadcast_to(soft_pin_rate(stiffness), self.indices.shape).copy()
        self.keys = keys
        self.damping = float(damping)

    def targets(self, time: float) -> np.ndarray:
        return self.rest if self.keys is None else self.keys.apply(self.rest, time)

    def pulled_vertices(self) -> np.ndarray:
        """The welded vertices it pulls (`scene.base.Pulling`)."""
        return self.indices

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """Follow a tear (`index_map`: new vertex -> old): copies of a pinned vertex are pulled
        toward the same target."""
        slot = np.full(int(max(index_map.max(initial=-1), self.indices.max(initial=-1))) + 1, -1, dtype=np.int64)
        slot[self.indices] = np.arange(self.indices.shape[0])
        source = slot[index_map]
        rows = np.flatnonzero(source >= 0)
        self.indices = rows.astype(np.int64)
        self.rest = self.rest[source[rows]]
        self.rate = self.rate[source[rows]]

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None:
        idx = self.indices
        free = model.inv_mass[idx] > 0
        idx = idx[free]
        if idx.size == 0 or dt <= 0:
            return
        target = self.targets(time)[free]
        kdt2 = self.rate[free] * dt * dt
        fraction = kdt2 / (1.0 + kdt2)
        x = state.positions[idx]
        delta = fraction[:, None] * (target - x)
        state.positions[idx] = x + delta
        v = state.velocities[idx] + delta / dt
        if self.damping > 0.0:
            target_velocity = (target - self.targets(time - dt)[free]) / dt if self.keys is not None else 0.0
            keep = (1.0 - min(self.damping, 0.999999)) ** dt
            v = target_velocity + (v - target_velocity) * keep
            state.previous[idx] = state.positions[idx] - v * dt
        state.velocities[idx] = v


def pivot_of(points: np.ndarray) -> np.ndarray:
    """Default pivot: the centroid of the pinned set's rest positions."""
    return np.asarray(points, dtype=np.float64).reshape(-1, 3).mean(axis=0)
