"""The implicit solver on a large cloth: its step energy and coarse Hessian in two slabs (a thread
each where faster) are the whole energy and Hessian, its own factor's halves likewise, and the
bytes do not depend on the threads."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth

from meshdeform.material import KindMaterial, Material
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers.implicit import cholesky
from meshdeform.solvers.implicit import solver as implicit
from meshdeform.solvers.implicit.solver import SPLIT_SPRINGS, ImplicitSolver
from meshdeform.solvers.options import ImplicitOptions

N = 100  # 59 000 springs: past SPLIT_SPRINGS


@pytest.fixture(scope="module")
def cloth():
    return grid_cloth(N, pins=TOP_CORNERS)


def _prepared(model, threads: int) -> ImplicitSolver:
    solver = ImplicitSolver(ImplicitOptions(coarse=5))
    solver._prepare(model)
    solver._factorise(1.0 / 48.0)
    solver._threads = threads
    return solver


def test_a_large_cloth_is_split_and_a_small_one_is_not(cloth) -> None:
    assert cloth.model.springs.shape[0] >= SPLIT_SPRINGS
    solver = _prepared(cloth.model, 2)
    parts = solver.energy_parts
    assert len(parts) == 3 and sum(part[1].shape[0] for part in parts) == solver.a.shape[0]
    assert parts[0][0].shape[0] + parts[1][0].shape[0] == solver.free_vertices.shape[0] and not parts[2][0].size
    assert 0 < parts[2][1].shape[0] < 0.02 * solver.a.shape[0]  # two slabs along the cloth, few springs across
    assert solver.coarse_space.second_half > 0
    small = _prepared(grid_cloth(20, pins=TOP_CORNERS).model, 2)
    assert len(small.energy_parts) == 1 and small.coarse_space.second_half == 0


def test_the_slabs_arrays_are_typed_as_a_whole_cloth_s(cloth) -> None:
    """The energy kernel gets arrays of the same Numba types (dtype, layout, read-only) from a
    split cloth's slabs as from a small cloth's whole: one build serves both, so a large run
    loads the build `pipeline.compile_ahead`'s small stand-in compiled instead of compiling its
    own (the slabs' copies were writable where the model's arrays are not)."""
    from numba import typeof

    large = _prepared(cloth.model, 2)
    small = _prepared(grid_cloth(20, pins=TOP_CORNERS).model, 2)
    whole = [typeof(array) for array in small.energy_parts[0]]
    for part in large.energy_parts:
        assert [typeof(array) for array in part] == whole


def test_the_energy_in_two_slabs_is_the_whole_energy_and_gradient(cloth) -> None:
    """Against a direct NumPy sum over the model's springs (tension or compression stiffness by the
    sign of l - L), on positions where springs are stretched and compressed; and the same bytes on
    one thread and two."""
    model = cloth.model
    rng = np.random.default_rng(5)
    rest = np.asarray(model.rest_positions, dtype=np.float64)
    x = rest + rng.normal(0.0, 0.002, rest.shape)
    y = x + rng.normal(0.0, 0.002, rest.shape)
    results = []
    for threads in (1, 2):
        solver = _prepared(model, threads)
        gradient = np.zeros((solver.free_vertices.shape[0], 3))
        results.append((solver._energy(x, y, gradient), gradient))
    assert results[0][0] == results[1][0] and np.array_equal(results[0][1], results[1][1])
    energy, gradient = results[0]

    free = np.asarray(model.inv_mass) > 0.0
    inertia = solver.inertia
    springs = np.asarray(model.springs)
    d = x[springs[:, 0]] - x[springs[:, 1]]
    length = np.linalg.norm(d, axis=1)
    stretch = length - np.asarray(model.rest_lengths)
    modulus = model.material.stretch_modulus
    k = np.where(stretch > 0.0, np.asarray(model.stiffness), np.asarray(model.compression)).clip(min=0.0) * modulus
    expected = 0.5 * (inertia * ((x - y)[free] ** 2).sum(axis=1)).sum() + 0.5 * (k * stretch**2).sum()
    force = (k * stretch / length)[:, None] * d
    full = np.zeros_like(x)
    full[free] = inertia[:, None] * (x - y)[free]
    np.add.at(full, springs[:, 0], force)
    np.add.at(full, springs[:, 1], -force)
    assert energy == pytest.approx(expected, rel=1e-12)
    assert np.abs(gradient - full[free]).max() <= 1e-9 * np.abs(full[free]).max()


def test_the_coarse_hessian_in_two_halves_is_the_one_sum(cloth) -> None:
    model = cloth.model
    solver = _prepared(model, 1)
    space = solver.coarse_space
    rng = np.random.default_rng(8)
    x = np.asarray(model.rest_positions, dtype=np.float64) * 1.05 + rng.normal(0.0, 0.001, (model.vertex_count, 3))
    args = (x, solver.a, solver.b, solver.rest, solver.weight)
    halves = [solver.coarse_inertia.copy() for _ in (1, 2)]
    for threads, matrix in zip((1, 2), halves, strict=True):
        space.add_spring_hessian(*args, matrix, threads)
    assert np.array_equal(halves[0], halves[1])
    one_sum = replace(space, second_half=0)
    whole = solver.coarse_inertia.copy()
    one_sum.add_spring_hessian(*args, whole)
    assert np.allclose(halves[0], whole, rtol=1e-12, atol=1e-9 * np.abs(whole).max())
    assert np.array_equal(halves[0], halves[0].T)


def _frames_on(threads: int, model, monkeypatch) -> list[np.ndarray]:
    """Three frames of `model` hanging, the split kernels given at most `threads` threads."""
    monkeypatch.setattr(implicit, "split_threads", lambda: threads)
    return [frame.welded_positions.copy() for frame in simulate(model, Scene(), Settings(solver="implicit", frames=3))]


def test_a_split_cloth_runs_to_the_same_bytes_on_one_thread_and_two(cloth, monkeypatch) -> None:
    one, two = (_frames_on(threads, cloth.model, monkeypatch) for threads in (1, 2))
    assert all(np.array_equal(a, b) for a, b in zip(one, two, strict=True))


def test_our_own_factor_runs_to_the_same_bytes_on_one_thread_and_two_and_as_cholmods(cloth, monkeypatch) -> None:
    """The large-cloth factor (`cholesky.SparseCholesky`, its halves a thread each) taken for this
    10 000-vertex cloth: the same bytes on one thread and two, and within rounding of the run on
    CHOLMOD's factor (a different ordering and algorithm, the same matrix)."""
    with_cholmod = _frames_on(2, cloth.model, monkeypatch)
    monkeypatch.setattr(cholesky, "OWN_FACTOR_ROWS", 5_000)
    one, two = (_frames_on(threads, cloth.model, monkeypatch) for threads in (1, 2))
    assert all(np.array_equal(a, b) for a, b in zip(one, two, strict=True))
    assert max(np.abs(a - b).max() for a, b in zip(two, with_cholmod, strict=True)) < 1e-9
    assert np.abs(two[-1] - two[0]).max() > 1e-4  # the cloth moved: 10^5 times the tolerance


def test_a_cloth_on_our_own_factor_may_take_two_threads_with_few_springs(monkeypatch) -> None:
    """A cloth of structural springs only, too few to split its energy (`SPLIT_SPRINGS`), but with
    free rows enough for our own factor: the picker may still give the factor's halves two threads."""
    monkeypatch.setattr(implicit, "split_threads", lambda: 2)
    material = Material(shear=KindMaterial(enabled=False), bending=KindMaterial(enabled=False))
    model = grid_cloth(150, pins=TOP_CORNERS, material=material).model
    solver = _prepared(model, 2)
    assert solver.a.shape[0] < SPLIT_SPRINGS <= 2 * solver.a.shape[0]
    assert solver.free_vertices.shape[0] >= cholesky.OWN_FACTOR_ROWS
    assert len(solver.energy_parts) == 1 and solver._picker.most == 2
    assert isinstance(solver.factor, cholesky.SparseCholesky)
