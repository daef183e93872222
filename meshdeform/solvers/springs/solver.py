"""Hooke springs with spring damping, semi-implicit Euler, optional strain limit (Provot 1995).

Per explicit step: f = sum over springs of (k (l - L) + c (v_b - v_a) . n) n on each end,
v += dt (a + f / m), air damping v *= (1 - damping) ** dt, x += dt v. With k = stiffness *
material.stretch_modulus (N/m; compression separately) and c = 2 z sqrt(k m_reduced) from
the kind's damping ratio z.

Explicit springs explode when a step is too long for the stiffest spring (the "dynamic
springs could explode" flaw). With `options.stable_substeps` (default) each substep is
split into as many explicit steps as a Gershgorin bound on the largest eigenvalue of
M^-1 K (and of the damping) requires: omega^2 dt^2 + 2 gamma dt <= 3.2 (stable below 4),
so stiff materials cost time, never stability. All those steps run inside one Numba call.

Provot's deformation constraint (`options.strain_limit`, e.g. 1.1): after every explicit
step, Gauss-Seidel passes pull structural springs longer than ratio * rest back to that
length (mass-weighted) and add the correction / dt to the velocities, until none exceeds it.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from meshdeform.model import ContactPlanes, SpringModel, State
from meshdeform.solvers.base import Control, Solver, velocity_retention
from meshdeform.solvers.common import ModelCache, damping_coefficients, spring_constants, structural_mask
from meshdeform.solvers.layout import spring_layout
from meshdeform.solvers.options import SpringsOptions
from meshdeform.solvers.springs import kernels


def stable_step(model: SpringModel, k: np.ndarray, c: np.ndarray, extra_omega2: float = 0.0) -> float:
    """Longest explicit step that keeps semi-implicit Euler stable (inf when nothing is stiff).

    lambda_max(M^-1 K) <= max_i 2 w_i sum_{s at i} k_s (Gershgorin), likewise for damping;
    the step satisfies lambda dt^2 + 2 gamma dt <= 3.2 (the limit is 4).
    """
    n = model.vertex_count
    if n == 0:
        return math.inf
    a = model.springs[:, 0]
    b = model.springs[:, 1]
    ksum = np.bincount(a, weights=k, minlength=n) + np.bincount(b, weights=k, minlength=n)
    csum = np.bincount(a, weights=c, minlength=n) + np.bincount(b, weights=c, minlength=n)
    w = np.asarray(model.inv_mass)
    lam = float((2.0 * w * ksum).max()) + extra_omega2 if n else extra_omega2
    gam = float((2.0 * w * csum).max()) if n else 0.0
    budget = 3.2
    if lam <= 0.0:
        return budget / (2.0 * gam) if gam > 0.0 else math.inf
    return (-gam + math.sqrt(gam * gam + budget * lam)) / lam


class ExplicitSolver(ModelCache, Solver):
    """Semi-implicit Euler over springs and/or anchors; subclasses choose which."""

    use_springs: ClassVar[bool] = True
    reads_planes: ClassVar[bool] = True
    #: decay rate (1/s) of velocities relative to the anchors (`anchor` only)
    anchor_damping: float = 0.0

    def __init__(self, options: SpringsOptions) -> None:
        super().__init__(options)
        self._dt = -1.0
        self.inner_steps = 1

    def _anchor(self, model: SpringModel) -> tuple[float, np.ndarray, bool, np.ndarray]:
        return 0.0, np.zeros((0, 3)), False, np.zeros(3)

    def _prepare(self, model: SpringModel) -> None:
        self.inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        self.mass = np.ascontiguousarray(model.mass, dtype=np.float64)
        self.forces = np.zeros((model.vertex_count, 3))
        kt, kc = spring_constants(model)
        c = damping_coefficients(model, kt)
        springs_on = self.use_springs and model.spring_count > 0
        if springs_on:
            lay = spring_layout(model, 0)  # the auto slab count: the order the force sums run in
            self.a, self.b, self.rest, self.offsets, self.parts = lay.a, lay.b, lay.rest, lay.offsets, lay.parts
            self.kt, self.kc, self.c = lay.take(kt), lay.take(kc), lay.take(c)
            structural = np.flatnonzero(structural_mask(model))
            self.la = np.ascontiguousarray(model.springs[structural, 0], dtype=np.int64)
            self.lb = np.ascontiguousarray(model.springs[structural, 1], dtype=np.int64)
            self.lrest = np.ascontiguousarray(model.rest_lengths[structural], dtype=np.float64)
        else:
            empty_i = np.zeros(0, dtype=np.int64)
            empty_f = np.zeros(0)
            self.a = self.b = self.la = self.lb = empty_i
            self.rest = self.kt = self.kc = self.c = self.lrest = empty_f
            self.offsets = np.zeros(2, dtype=np.int64)
            self.parts = 1
        self.anchor_k, self.anchors, self.follow, self.rest_center = self._anchor(model)
        self.max_dt = self._stable_step(model, kt, kc, c, self.anchor_k)
        self._dt = -1.0

    def _stable_step(self, model: SpringModel, kt: np.ndarray, kc: np.ndarray, c: np.ndarray, anchor_k: float) -> float:
        """The longest stable explicit step (s) on the model: its springs' (spring constants kt, kc
        and damping coefficients c (S,)) where they act, and the anchors' (anchor_k, 1/s^2)."""
        if self.use_springs and model.spring_count > 0:
            return stable_step(model, np.maximum(kt, kc), c, anchor_k)
        return math.sqrt(3.2 / anchor_k) if anchor_k > 0 else math.inf

    def contact_substeps(self, model: SpringModel, fps: float) -> int:
        """Substeps a frame at `fps` that keep each substep within `CONTACT_INNER_STEPS` stable
        explicit steps (0 without stable substeps, which trust the substeps given): a cloth
        pressed onto a collider was pulled through it by its springs within the steps between two
        collider projections when these were many spring periods apart, and each push back
        stored energy (a sheet on a thin bar at 8 substeps of 29 steps blew up at 27x stretch);
        the contact planes now hold it in every step (`Control.planes`), and self-collision, which
        still acts between substeps only, sets the bound."""
        if not self.options.stable_substeps:
            return 0
        kt, kc = spring_constants(model)
        max_dt = self._stable_step(model, kt, kc, damping_coefficients(model, kt), self._anchor(model)[0])
        if not math.isfinite(max_dt) or fps <= 0.0:
            return 0
        return math.ceil(1.0 / (fps * CONTACT_INNER_STEPS * max_dt) - 1e-9)

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        if not self._prepared(model):
            self._prepare(model)
        if dt != self._dt:
            self.inner_steps = max(1, math.ceil(dt / self.max_dt - 1e-9)) if self.options.stable_substeps else 1
            self._dt = dt
        n = self.inner_steps
        h = dt / n
        limit = self.options.strain_limit
        ratio = float(limit) if (limit is not None and self.use_springs) else 0.0
        x, v, prev = state.positions, state.velocities, state.previous
        planes = control.planes if control.planes is not None else NO_PLANES
        pinned_velocity(x, prev, v, self.inv_mass, 1.0 / dt)
        kernels.explicit_advance(
            x, v, prev, self.inv_mass, self.mass, control.accelerations,
            velocity_retention(self.options.damping, h), h, n,
            self.a, self.b, self.rest, self.kt, self.kc, self.c, self.offsets, self.parts, self.forces,
            self.anchor_k, self.anchors, self.follow, self.rest_center, math.exp(-self.anchor_damping * h),
            self.la, self.lb, self.lrest, ratio, int(self.options.strain_iterations),
            planes.vertices, planes.weights, planes.normals, planes.offsets, planes.velocities, planes.friction,
        )


#: no contact planes (`Control.planes` None): the kernel's empty arrays of their types
NO_PLANES = ContactPlanes(
    vertices=np.zeros((0, 3), dtype=np.int64), weights=np.zeros((0, 3)), normals=np.zeros((0, 3)),
    offsets=np.zeros(0), velocities=np.zeros((0, 3)), friction=np.zeros(0),
)


#: the most stable explicit steps a substep runs where something touches the cloth, when the
#: substeps are the solver's default (`ExplicitSolver.contact_substeps`; figures in
#: docs/performance.md, "springs: explicit steps under contact" and "springs: contact planes in
#: every explicit step": 16 before the planes, 128 let self-collision's layers stretch to 1.12)
CONTACT_INNER_STEPS = 64


def pinned_velocity(x: np.ndarray, prev: np.ndarray, v: np.ndarray, inv_mass: np.ndarray, inv_dt: float) -> None:
    """Pinned vertices' velocities from their motion this substep; free ones' prev = x."""
    kernels.start_step(x, prev, v, inv_mass, inv_dt)


class SpringsSolver(ExplicitSolver):
    """Mass-spring cloth with Hooke springs, spring damping and an optional Provot strain limit."""

    name: ClassVar[str] = "springs"
    summary: ClassVar[str] = "Hooke springs, semi-implicit Euler, stable substeps, optional Provot strain limit"
    hint: ClassVar[str] = "keep stable_substeps on, lower stiffness or use more substeps"
    options_class: ClassVar[type[SpringsOptions]] = SpringsOptions
    default_substeps: ClassVar[int] = 8
