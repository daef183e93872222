"""External forces of a scene as `Force` objects: wind with turbulence, impacts.

Every force adds accelerations (m/s^2) for welded vertices into `out` in `accumulate`, vectorised
over faces and vertices. Gravity itself is `Scene.gravity` (`scene.base.gravity_vector` picks it
from the up axis).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from meshdeform.geometry import triangle_vertex_normals
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Force, Remappable
from meshdeform.solvers.jit import FAST

AIR_DENSITY = 1.2


@nb.njit(**FAST)
def _noise_add(points, time, k, omega, phase, amplitude, advect, gain, out):  # pragma: no cover - compiled
    """out += gain * sum_m amplitude_m sin(k_m . (p - advect t) + omega_m t + phase_m), per point."""
    for i in range(points.shape[0]):
        px = points[i, 0] - advect[0] * time
        py = points[i, 1] - advect[1] * time
        pz = points[i, 2] - advect[2] * time
        for m in range(k.shape[0]):
            s = np.sin(k[m, 0] * px + k[m, 1] * py + k[m, 2] * pz + omega[m] * time + phase[m]) * gain
            out[i, 0] += amplitude[m, 0] * s
            out[i, 1] += amplitude[m, 1] * s
            out[i, 2] += amplitude[m, 2] * s


@nb.njit(**FAST)
def _wind_faces(x, relative, tri, inv_mass_lumped, rho, drag, lift, out):  # pragma: no cover - compiled
    """Per triangle drag + lift from the corners' mean relative air velocity; a third to each corner."""
    for t in range(tri.shape[0]):
        a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
        e1x, e1y, e1z = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e2x, e2y, e2z = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        nx = 0.5 * (e1y * e2z - e1z * e2y)
        ny = 0.5 * (e1z * e2x - e1x * e2z)
        nz = 0.5 * (e1x * e2y - e1y * e2x)
        area = np.sqrt(nx * nx + ny * ny + nz * nz)
        ux = (relative[a, 0] + relative[b, 0] + relative[c, 0]) / 3.0
        uy = (relative[a, 1] + relative[b, 1] + relative[c, 1]) / 3.0
        uz = (relative[a, 2] + relative[b, 2] + relative[c, 2]) / 3.0
        speed = np.sqrt(ux * ux + uy * uy + uz * uz)
        if area <= 0.0 or speed <= 1e-12:
            continue
        nx /= area
        ny /= area
        nz /= area
        ux /= speed
        uy /= speed
        uz /= speed
        dot = nx * ux + ny * uy + nz * uz
        if dot < 0.0:  # the normal on the downwind side
            nx, ny, nz, dot = -nx, -ny, -nz, -dot
        q = 0.5 * rho * area * speed * speed * dot / 3.0
        fx = q * (drag * ux + lift * (nx - dot * ux))
        fy = q * (drag * uy + lift * (ny - dot * uy))
        fz = q * (drag * uz + lift * (nz - dot * uz))
        for v in (a, b, c):
            out[v, 0] += fx * inv_mass_lumped[v]
            out[v, 1] += fy * inv_mass_lumped[v]
            out[v, 2] += fz * inv_mass_lumped[v]


class Turbulence:
    """Smooth, seeded vector noise in space and time: a sum of random travelling sine waves.

    u(x, t) = sum_m a_m sin(k_m . (x - advect t) + w_m t + phi_m); each component has unit RMS.
    Same seed -> same field; spatial wavelength about `scale` metres, changes at about `frequency` Hz,
    the pattern carried along with the mean wind (`advect`).
    """

    def __init__(
        self,
        seed: int,
        scale: float = 1.0,
        frequency: float = 0.5,
        advect: Sequence[float] = (0, 0, 0),
        modes: int = 16,
    ) -> None:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x6D657368]))
        directions = rng.normal(size=(modes, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        magnitude = 2.0 * np.pi / float(scale) * rng.uniform(0.5, 1.5, size=modes)
        self.k = directions * magnitude[:, None]
        self.omega = 2.0 * np.pi * float(frequency) * rng.uniform(0.5, 1.5, size=modes)
        self.phase = rng.uniform(0.0, 2.0 * np.pi, size=modes)
        self.amplitude = rng.normal(size=(modes, 3)) * np.sqrt(2.0 / modes)
        self.advect = np.asarray(advect, dtype=np.float64)

    def __call__(self, points: np.ndarray, time: float) -> np.ndarray:
        out = np.zeros((np.shape(points)[0], 3))
        self.add(points, time, 1.0, out)
        return out

    def add(self, points: np.ndarray, time: float, gain: float, out: np.ndarray) -> None:
        """out += gain * field(points, time), in place (compiled)."""
        pts = np.ascontiguousarray(points, dtype=np.float64)
        _noise_add(pts, float(time), self.k, self.omega, self.phase, self.amplitude, self.advect, float(gain), out)


class Wind(Force, Remappable):
    """Aerodynamic drag and lift per triangle from the air's velocity relative to the cloth.

    For each triangle with unit normal n, area A and relative air velocity u (wind at the centroid
    minus the triangle's velocity, both the mean of its corners), with q = rho A |u|^2 / 2 and cos = |n . u| / |u|:
    drag q C_d cos along u, lift q C_l cos sin perpendicular to u in the plane of u and n.
    A third of each triangle's force goes to each corner, divided by the vertex mass.
    `air_damping` (1/s) also pulls every vertex's velocity toward the local wind (vertices without
    faces, such as ropes, feel the wind only through it). `turbulence` is the RMS gust speed as a
    fraction of the wind speed.
    """

    def __init__(
        self,
        velocity: Sequence[float] = (0.0, 0.0, 0.0),
        *,
        drag: float = 1.0,
        lift: float = 0.3,
        air_density: float = AIR_DENSITY,
        turbulence: float = 0.0,
        turbulence_scale: float = 1.0,
        turbulence_frequency: float = 0.5,
        air_damping: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.velocity = np.asarray(velocity, dtype=np.float64)
        self.drag = float(drag)
        self.lift = float(lift)
        self.air_density = float(air_density)
        self.gust = float(turbulence) * float(np.linalg.norm(self.velocity))
        self.air_damping = float(air_damping)
        self.noise = (
            Turbulence(seed, turbulence_scale, turbulence_frequency, advect=self.velocity) if self.gust > 0 else None
        )
        self._inv_mass: np.ndarray | None = None

    def wind_at(self, points: np.ndarray, time: float) -> np.ndarray:
        """Air velocity (N, 3) at points and a time."""
        w = np.empty((np.shape(points)[0], 3))
        w[:] = self.velocity
        if self.noise is not None:
            self.noise.add(points, time, self.gust, w)
        return w

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear: masses changed, recompute the inverse masses."""
        self._inv_mass = None

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
        x = state.positions
        tri = model.triangles
        # air velocity relative to each vertex, once; faces take the mean of their corners
        relative = self.wind_at(x, time)
        relative -= state.velocities
        if tri.shape[0] and (self.drag or self.lift):
            if self._inv_mass is None or self._inv_mass.shape[0] != x.shape[0]:
                self._inv_mass = 1.0 / model.mass
            _wind_faces(x, relative, tri, self._inv_mass, self.air_density, self.drag, self.lift, out)
        if self.air_damping > 0:
            out += self.air_damping * relative


FALLOFFS = ("inverse_square", "smooth")


def falloff(distance: np.ndarray, radius: float, kind: str = "inverse_square") -> np.ndarray:
    """Impact weight by distance: 1/(1 + (d/r)^2) (the original deformer, r = 1 reproduces it) or
    the smooth (1 - (d/r)^2)^2 that reaches 0 at the radius."""
    t = np.asarray(distance, dtype=np.float64) / radius
    if kind == "inverse_square":
        return 1.0 / (1.0 + t * t)
    if kind == "smooth":
        return np.where(t < 1.0, (1.0 - t * t) ** 2, 0.0)
    raise ValueError(f"falloff must be one of {', '.join(FALLOFFS)}, not {kind!r}")


def ray_hit(
    positions: np.ndarray, triangles: np.ndarray, origin: np.ndarray, direction: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """First hit of a ray with triangles (Moller-Trumbore, vectorised): (point, unit normal) or None."""
    if triangles.shape[0] == 0:
        return None
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    o = np.asarray(origin, dtype=np.float64)
    p0 = positions[triangles[:, 0]]
    e1 = positions[triangles[:, 1]] - p0
    e2 = positions[triangles[:, 2]] - p0
    h = np.cross(d, e2)
    a = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(a) > 1e-14
    f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    s = o - p0
    u = f * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = f * (q @ d)
    t = f * np.einsum("ij,ij->i", e2, q)
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-12)
    if not hit.any():
        return None
    k = int(np.flatnonzero(hit)[np.argmin(t[hit])])
    normal = np.cross(e1[k], e2[k])
    return o + t[k] * d, normal / np.linalg.norm(normal)


@dataclass
class _Occurrence:
    index: int
    point: np.ndarray
    normal: np.ndarray


class Impact(Force, Remappable):
    """A scripted push: during [time, time + duration) vertices gain a velocity change of
    `strength * falloff(d)` m/s spread evenly over the duration (so the result does not depend on
    the substep size), along `direction`: "radial" (away from the point; negative strength pulls
    in, the "black hole"), "normal" (along the surface normal at the hit, into the surface as seen
    from the point or ray origin) or a fixed vector. `every` repeats it (`count` times, default
    forever). With `ray` = (origin, direction) the point is where the ray first hits the mesh at
    the moment each impact starts (falling back to `fallback_point` when it misses then).
    `mask` (W,) limits the vertices it acts on. A substep the impact covers in part gets that
    part of the acceleration (`accumulate`'s dt), so the impulse is exact at any substep length.
    """

    kicks = True

    def __init__(
        self,
        *,
        time: float,
        radius: float,
        strength: float,
        duration: float,
        point: Sequence[float] | None = None,
        ray: tuple[Sequence[float], Sequence[float]] | None = None,
        direction: str | Sequence[float] = "radial",
        falloff: str = "inverse_square",
        every: float | None = None,
        count: int | None = None,
        mask: np.ndarray | None = None,
        fallback_point: Sequence[float] | None = None,
    ) -> None:
        if (point is None) == (ray is None):
            raise ValueError("an impact needs exactly one of point and ray")
        if falloff not in FALLOFFS:
            raise ValueError(f"falloff must be one of {', '.join(FALLOFFS)}")
        self.time = float(time)
        self.radius = float(radius)
        self.strength = float(strength)
        self.duration = float(duration)
        self.point = None if point is None else np.asarray(point, dtype=np.float64)
        self.ray = None if ray is None else (np.asarray(ray[0], float), np.asarray(ray[1], float))
        self.direction = direction if isinstance(direction, str) else np.asarray(direction, dtype=np.float64)
        if not isinstance(self.direction, str):
            self.direction = self.direction / np.linalg.norm(self.direction)
        self.falloff = falloff
        self.every = every
        self.count = count
        self.mask = None if mask is None else np.asarray(mask, dtype=bool)
        self.fallback_point = None if fallback_point is None else np.asarray(fallback_point, dtype=np.float64)
        self._current: _Occurrence | None = None

    def _weight(self, time: float, dt: float) -> tuple[int, float]:
        """(occurrence index, fraction of the full acceleration over the substep [time, time + dt)):
        the part of the substep the impact lasts, so the substeps' velocity changes add up to
        `strength` whatever their length."""
        local = time - self.time
        k = 0
        if self.every is not None and local >= 0:
            k = int(np.floor(local / self.every))
            if self.count is not None and k >= self.count:
                k = self.count - 1
            local -= k * self.every
        overlap = min(local + dt, self.duration) - max(local, 0.0)
        return k, max(overlap, 0.0) / dt

    def largest_kick(self, start: float, end: float) -> float:
        """|strength| (m/s, the falloff is at most 1) where an occurrence overlaps [start, end)."""
        first = 0
        last = 0
        if self.every is not None:
            first = max(0, math.floor((start - self.time - self.duration) / self.every))
            last = math.floor((end - self.time) / self.every)
            if self.count is not None:
                last = min(last, self.count - 1)
        for k in range(first, last + 1):
            begins = self.time + k * (self.every or 0.0)
            if begins < end and begins + self.duration > start:
                return abs(self.strength)
        return 0.0

    def _occurrence(self, k: int, model: SpringModel, x: np.ndarray) -> _Occurrence:
        if self._current is not None and self._current.index == k:
            return self._current
        if self.ray is not None:
            origin, d = self.ray
            hit = ray_hit(x, model.triangles, origin, d)
            if hit is None:
                point = self.fallback_point if self.fallback_point is not None else origin
                normal = -d / np.linalg.norm(d)
            else:
                point, normal = hit
            towards = d
        else:
            point = self.point
            normal = np.zeros(3)
            if isinstance(self.direction, str) and self.direction == "normal":
                nearest = int(np.argmin(np.einsum("ij,ij->i", x - point, x - point)))
                if model.triangles.shape[0]:
                    normal = triangle_vertex_normals(x, model.triangles)[nearest]
                towards = x[nearest] - point
                if np.linalg.norm(towards) < 1e-12:
                    towards = -normal
            else:
                towards = np.zeros(3)
        if np.dot(normal, towards) < 0:
            normal = -normal
        self._current = _Occurrence(k, np.asarray(point, dtype=np.float64), normal)
        return self._current

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear (`index_map`: new vertex -> old): copies inherit the mask."""
        if self.mask is not None:
            self.mask = self.mask[index_map]

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
        k, weight = self._weight(time, dt)
        if weight <= 0.0:
            return
        x = state.positions
        occ = self._occurrence(k, model, x)
        rel = x - occ.point
        dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
        gain = self.strength * weight / self.duration * falloff(dist, self.radius, self.falloff)
        if self.mask is not None:
            gain = gain * self.mask
        if isinstance(self.direction, str):
            if self.direction == "radial":
                direction = rel / np.where(dist > 1e-12, dist, np.inf)[:, None]
            else:
                direction = np.broadcast_to(occ.normal, x.shape)
        else:
            direction = np.broadcast_to(self.direction, x.shape)
        out += gain[:, None] * direction
