"""Solvers under collider contact: a cloth that lands or drapes keeps its shape and does not
bounce, with each position solver at its defaults. Checked by measures written here (structural
stretch from the rest lengths, the triangles' total area, heights), not by the solvers' figures.

The implicit solver is the one these scenes caught: its BDF2 steps extrapolate each vertex's
last two steps, which a collider's correction breaks (a landed vertex kept the fall in its
history and bounced), and a few iterations of one frame-sized step cannot resolve a contact
that stops part of the cloth within a step (the drape over a sphere flickered between 1.05
and 1.7 stretch at 4 steps a frame; with the bending and shear springs out of its matrix it
crumpled into a ball).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from factories import KNIT, grid_cloth, grid_sheet
from test_bending import triangle_mesh

from meshdeform.material import KindMaterial, Material
from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel
from meshdeform.scene.colliders import Box, Collider, Plane, Sphere
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.topology import SpringKind
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

pytestmark = pytest.mark.usefixtures("one_numba_thread")

THICKNESS = 0.01


def structural_stretch(model, positions: np.ndarray) -> float:
    """The largest structural spring length over its rest length."""
    structural = model.kinds == SpringKind.STRUCTURAL
    a, b = model.springs[structural].T
    return float((np.linalg.norm(positions[a] - positions[b], axis=1) / model.rest_lengths[structural]).max())


def area(triangles: np.ndarray, positions: np.ndarray) -> float:
    """Total area (m^2) of the triangles (T, 3) at positions (V, 3)."""
    p0, p1, p2 = (positions[triangles[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1).sum())


@pytest.mark.parametrize("solver", ["xpbd", "verlet", "implicit"])
def test_a_sheet_draped_over_a_sphere_holds_its_shape(solver: str) -> None:
    """A 1 m sheet of 40 x 40 vertices dropped flat from 0.5 m onto a sphere of radius 0.15 m
    (no ground) lands at frame 8 and drapes: from frame 12 on its structural springs stay within
    25 % of rest (xpbd 1.17 at most, implicit at its defaults 1.11; 4 implicit steps a frame
    flickered up to 1.7) and its area within 20 % (a cloth crumpled into a ball has lost most)."""
    cloth = grid_cloth(40, plane="xz", offset=(-0.5, 0.5, -0.5), material=KNIT)
    model = cloth.model
    scene = Scene(constraints=[Collider(Sphere((0.0, 0.15, 0.0), 0.15), friction=0.3, thickness=THICKNESS)])
    rest_area = area(model.triangles, model.rest_positions)
    frames = list(simulate(model, scene, Settings(solver=solver, frames=36)))
    assert frames[11].welded_positions[:, 1].min() < 0.1  # it did fall past the sphere's top
    stretch = [structural_stretch(model, f.welded_positions) for f in frames[11:]]
    areas = [area(model.triangles, f.welded_positions) / rest_area for f in frames[11:]]
    assert max(stretch) < 1.25, stretch
    assert min(areas) > 0.8, areas


def box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance (m) of each point (N, 3) outside the box [lo, hi] (negative inside: minus the
    distance to the nearest face), by the clamp formula."""
    outside = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)
    inside = np.minimum(points - lo, hi - points).min(axis=1)
    return np.where(outside > 0.0, outside, -np.maximum(inside, 0.0))


@pytest.mark.parametrize("solver", ["xpbd", "implicit"])
def test_a_sheet_dropped_on_a_thin_bar_hangs_over_it_without_hooking_through(solver: str) -> None:
    """The fold scene of benchmarks/contact.py without its ground: a 1 m sheet of 40 x 40 dropped
    flat, off centre, from 0.8 m onto a bar 4 cm wide and 4 cm deep, 70 cm up. Every vertex stays
    the thickness (less 1 mm) out of the bar in every frame, and from frame 4 on (it lands in
    frame 3) no structural spring passes 1.6x its rest length. The implicit solver applied the
    bar only after each long step: the cloth ended hooked around it, springs at 4 to 7x rest
    (xpbd 1.10); now the contact is held inside its iterations."""
    cloth = grid_cloth(40, plane="xz", offset=(-0.4, 0.8, -0.5))
    model = cloth.model
    lo, hi = np.array([-0.02, 0.66, -0.7]), np.array([0.02, 0.7, 0.7])
    scene = Scene(constraints=[Collider(Box(lo, hi), friction=0.3, thickness=THICKNESS)])
    frames = list(simulate(model, scene, Settings(solver=solver, frames=24)))
    assert frames[-1].welded_positions[:, 1].min() < 0.3  # it fell off both sides of the bar
    for frame in frames:
        assert box_distance(frame.welded_positions, lo, hi).min() > THICKNESS - 1e-3, frame.index
    stretch = [structural_stretch(model, f.welded_positions) for f in frames[3:]]
    assert max(stretch) < 1.6, stretch


def test_an_implicit_cloth_landing_on_the_ground_does_not_bounce() -> None:
    """A 12 x 12 sheet dropped flat from 0.5 m onto the ground (an inelastic contact: the
    collider takes the normal velocity away) stays on it. The implicit solver's BDF2 history
    starts afresh where a collider moved a vertex: with the fall still in it, the sheet rose
    4.7 cm off the ground after landing."""
    model = grid_cloth(12, plane="xz", offset=(0.0, 0.5, 0.0)).model
    scene = Scene(constraints=[Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.3, thickness=THICKNESS)])
    frames = simulate(model, scene, Settings(solver="implicit", frames=36))
    heights = [float(f.welded_positions[:, 1].max()) for f in frames]
    landed = next(i for i, h in enumerate(heights) if h < THICKNESS + 1e-3)
    assert landed < 12
    assert max(heights[landed:]) < THICKNESS + 1e-3, heights[landed:]


def test_a_stiff_sheet_dropped_on_a_sphere_on_the_ground_drapes_without_flickering() -> None:
    """The drop scene of benchmarks/contact.py in a woven material (10 000 N/m): a 1 m sheet of
    40 x 40 dropped flat from 0.5 m onto a sphere of radius 0.15 m resting on the ground, implicit
    at its contact steps. From landing on, its structural springs stay within 15 % of rest (the
    knit: 1.04 at most). When every contact was let go in each step's last iteration, the stiff
    springs drove whole regions into the obstacles, whose pushes then stored energy: 1.1 to 1.5
    from frame 24, 4.8 by frame 56."""
    cloth = grid_cloth(40, plane="xz", offset=(-0.5, 0.5, -0.5), material=Material(stretch_modulus=10_000.0))
    model = cloth.model
    scene = Scene(
        constraints=[
            Collider(Sphere((0.0, 0.15, 0.0), 0.15), friction=0.3, thickness=THICKNESS),
            Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.3, thickness=THICKNESS),
        ]
    )
    frames = list(simulate(model, scene, Settings(solver="implicit", frames=60)))
    assert frames[-1].welded_positions[:, 1].min() < 0.05  # it draped down to the ground
    stretch = [structural_stretch(model, f.welded_positions) for f in frames[8:]]
    assert max(stretch) < 1.15, stretch


SLOPE = math.radians(20.0)


@pytest.mark.parametrize("solver", ["implicit", "xpbd"])
@pytest.mark.parametrize("friction", [0.0, 0.2, 0.5])
def test_a_sheet_on_a_slope_slides_as_friction_and_air_damping_allow(solver: str, friction: float) -> None:
    """A 12 x 12 sheet laid on a 20 degree slope (a plane collider) slides down it with the
    acceleration g (sin a - friction cos a) less the default air damping's drag (rate c = ln 10 /s):
    after 2 s at g (sin a - friction cos a) (1 - exp(-2 c)) / c, 1.44 m/s without friction and
    0.65 m/s at friction 0.2, and it stays where friction exceeds tan a (0.36): within 1 cm and
    at rest (with xpbd the colliders' static friction puts a still contact back where it started
    along the surface; implicit holds a contact whose forces lie within the friction's cone along
    every axis in its iterations; with the velocity friction alone they crept 1.5 and 3.4 cm).
    implicit tied every held contact down in its matrix, which held the sheet against sliding too:
    0.50 m/s without friction, and at 0.2 it did not move."""
    normal = np.array([-math.sin(SLOPE), math.cos(SLOPE), 0.0])
    turn = np.array([[math.cos(SLOPE), -math.sin(SLOPE), 0.0], [math.sin(SLOPE), math.cos(SLOPE), 0.0], [0, 0, 1]])
    model = grid_cloth(12, plane="xz", offset=(-0.5, 0.0, -0.5)).model
    laid = model.rest_positions @ turn.T + (THICKNESS + 1e-4) * normal
    model = replace(model, rest_positions=laid)
    slope = Collider(Plane((0.0, 0.0, 0.0), tuple(normal)), friction=friction, thickness=THICKNESS)
    *_, last = simulate(model, Scene(constraints=[slope]), Settings(solver=solver, frames=48))
    downhill = -np.array([math.cos(SLOPE), math.sin(SLOPE), 0.0])
    rate = math.log(10.0)
    pull = 9.81 * (math.sin(SLOPE) - friction * math.cos(SLOPE))
    travelled = float((last.welded_positions - laid).mean(axis=0) @ downhill)
    if pull <= 0.0:
        assert abs(travelled) < 0.01 and last.max_speed < 0.01
        assert last.rest_frame is not None
    else:
        assert last.max_speed == pytest.approx(pull * (1.0 - math.exp(-2.0 * rate)) / rate, rel=0.05)
        assert travelled > 0.5


def test_a_stiff_sheet_folded_over_a_bar_onto_the_ground_stays_inextensible() -> None:
    """The fold scene of benchmarks/contact.py in a woven material (10 000 N/m), without
    self-collision: a 1 m sheet of 40 x 40 dropped flat and off centre onto a 4 cm bar 0.7 m up,
    its halves swinging down and hanging from it; implicit at its contact steps. Its structural
    springs stay within 8 % of rest in every frame. While the matrix that preconditions the
    L-BFGS iterations knew nothing of the held contacts, the free vertices next to them were
    given moves of up to a metre into the obstacle, the trust region cut every step to
    millimetres, and the cloth stayed stretched: 1.2x from frame 17, 2.8x at frame 40, its long
    half stretched down onto the ground (`anchors`)."""
    cloth = grid_cloth(40, plane="xz", offset=(-0.4, 0.8, -0.5), material=Material(stretch_modulus=10_000.0))
    model = cloth.model
    scene = Scene(
        constraints=[
            Collider(Box((-0.02, 0.66, -0.7), (0.02, 0.7, 0.7)), friction=0.3, thickness=THICKNESS),
            Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.3, thickness=THICKNESS),
        ]
    )
    frames = list(simulate(model, scene, Settings(solver="implicit", frames=48)))
    last = frames[-1].welded_positions[:, 1]
    assert last.max() > 0.66 and last.min() < 0.25  # over the bar, its long half hanging down
    stretch = [structural_stretch(model, f.welded_positions) for f in frames]
    assert max(stretch) < 1.08, stretch


@pytest.mark.parametrize("solver", ["implicit", "xpbd", "springs"])
def test_a_stiff_closed_shell_dropped_on_the_ground_lands(solver: str) -> None:
    """A triangulated 0.5 m cube of 10 000 N/m springs (no bending springs) dropped 0.3 m onto the
    ground comes to lie on it: from its first contact on, its lowest point never rises more than
    2 cm above the ground's thickness. implicit held its bottom vertices against the compressed
    springs after the impact, and the energy the collider's push had stored in them came back as a
    bounce: 0.28 m, and still bouncing two seconds later (`IMPACT_SINKS`)."""
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5)).subdivide()
    positions = np.asarray(box.vertices, dtype=np.float64)
    positions[:, 1] += 0.3 - positions[:, 1].min()
    material = Material(stretch_modulus=10_000.0, bending=KindMaterial(enabled=False))
    model = SpringModel.from_mesh(triangle_mesh(positions, np.asarray(box.faces)), material)
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.5, thickness=THICKNESS)
    frames = simulate(model, Scene(constraints=[ground]), Settings(solver=solver, frames=48))
    lowest = [f.welded_positions[:, 1].min() for f in frames]
    touched = next(k for k, low in enumerate(lowest) if low < THICKNESS + 1e-3)
    assert touched < 12  # it fell and landed within half a second
    assert max(lowest[touched:]) < THICKNESS + 0.02, max(lowest[touched:])


def test_a_standing_sheet_landing_on_its_edge_stays_inextensible() -> None:
    """A 1 m sheet of 40 x 40 (triangles), standing upright 2 m up with a 2 cm ripple and a soft
    bend, falls onto the ground edge first at 3.6 m/s; implicit at its defaults. At 8 steps a
    frame its lowest row moved 0.73 edges a step, and the frame it landed stretched its springs to
    1.38 (2.54 with self-collision on); the frames in which it falls that fast now take more
    steps (`meshdeform.simulate.fast_substeps`), and no frame stretches past 10 %."""
    mesh = grid_sheet(40, 40, size=1.0, plane="xy", triangles=True, offset=(-0.5, 2.0, 0.0))
    positions = mesh.positions.copy()
    positions[:, 2] = 0.02 * np.sin(6 * np.pi * positions[:, 1])
    model = SpringModel.from_mesh(replace(mesh, positions=positions), Material(bending=KindMaterial(stiffness=5e-4)))
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.5, thickness=0.005)
    frames = list(simulate(model, Scene(constraints=[ground]), Settings(solver="implicit", frames=30)))
    assert min(f.welded_positions[:, 1].min() for f in frames) < 0.01  # it landed
    assert max(f.max_stretch for f in frames) < 1.10


@pytest.mark.parametrize("solver", ["implicit", "xpbd"])
def test_a_sheet_pushed_together_on_grippy_ground_folds_without_stretching(solver: str) -> None:
    """A 20 x 20 sheet of 1 m lying on the ground (friction 0.5), self-collision on, its two
    opposite edges pinned and pushed 25 cm each towards the other over 1.5 s, then held, 5 s
    through a recipe: from 2 s on no structural spring is longer than 1.1 times its rest length
    and at the end nothing moves faster than 5 cm/s. Under implicit static friction held every
    pressed contact in place along every axis, rows sliding at a metre a second too, so the
    compressed sheet could not lift into folds: its shear springs pushed it apart across the push,
    40-45 % stretched, and it flailed at 1-2 m/s to the end."""
    mesh = grid_mesh(20, 20, size=(1.0, 1.0), plane="xz")
    mesh = replace(mesh, positions=mesh.positions + np.array([-0.5, 0.02, -0.5]))
    text = (
        f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = 120\n\n[self_collision]\n\n'
        "[[colliders]]\nground = { height = 0.0 }\nfriction = 0.5\n"
    )
    for side in (-1.0, 1.0):
        edge = f"min = [{0.5 * side - 0.01}, -1, -1], max = [{0.5 * side + 0.01}, 1, 1]"
        push = f"{{ time = 1.5, translate = [{-0.25 * side}, 0, 0] }}"
        text += f"\n[[pins]]\nselect = {{ box = {{ {edge} }} }}\nanimate = [{{ time = 0.0 }}, {push}]\n"
    built = build_simulation(parse_recipe(text), mesh)
    model = built.model
    a, b = np.asarray(model.springs)[np.asarray(model.kinds) == SpringKind.STRUCTURAL].T
    rest = np.linalg.norm(model.rest_positions[a] - model.rest_positions[b], axis=1)
    frames = list(simulate(model, built.scene, built.settings))
    stretch = [float((np.linalg.norm(f.welded_positions[a] - f.welded_positions[b], axis=1) / rest).max())
               for f in frames]
    assert max(stretch[48:]) < 1.1
    assert frames[-1].max_speed < 0.05


def punched_hammock(n: int, frames: int, solver: str = "xpbd"):
    """An n x n sheet of 1 m pinned along two opposite edges, a 30 cm plate 1 cm thick punched
    0.4 m down through it at 20 m/s from 0.05 s, `solver` at its defaults (xpbd, verlet: tethers
    1.0), 24 fps, built from a recipe."""
    grid = grid_mesh(n, n, size=(1.0, 1.0), plane="xz")
    mesh = replace(grid, positions=grid.positions + np.array([-0.5, 1.0, -0.5]))
    end = 0.05 + 0.6 / 20.0
    text = (
        f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = {frames}\n\n'
        "[[pins]]\nselect = { any = [ { box = { min = [-0.51, 0.9, -0.6], max = [-0.49, 1.1, 0.6] } },\n"
        "                          { box = { min = [0.49, 0.9, -0.6], max = [0.51, 1.1, 0.6] } } ] }\n\n"
        "[[colliders]]\nbox = { min = [-0.15, 1.20, -0.15], max = [0.15, 1.21, 0.15] }\nfriction = 0.3\n"
        "animate = [ { time = 0.0, translate = [0, 0, 0] }, { time = 0.05, translate = [0, 0, 0] },\n"
        f"            {{ time = {end!r}, translate = [0, -0.6, 0] }} ]\n"
    )
    return build_simulation(parse_recipe(text), mesh)


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_a_plate_punched_through_a_cloth_pinned_at_both_sides_runs_with_tethers(solver: str) -> None:
    """The punched cloth of `punched_hammock` (30 x 30), half a second: the run goes through and
    no spring ends stretched like the blow-up's. The tethers held every vertex within its rest
    distance of the pinned edges, which the plate makes impossible: the vertices next to those it
    carried were held back and the springs between took the whole difference (xpbd 10.7x at frame
    6, where the divergence guard stopped the run; verlet 7.9x). Now the tethers give way around
    the push (`sweep_kernels.release_tethers`); `implicit`, without tethers, stretches the same
    scene 3.9x."""
    built = punched_hammock(30, 12, solver)
    frames = list(simulate(built.model, built.scene, built.settings))
    assert len(frames) == 12
    assert frames[-1].welded_positions[:, 1].min() < 0.65  # the plate carried the cloth down
    assert max(f.max_stretch for f in frames) < 5.0


@pytest.mark.parametrize("solver_name", ["xpbd", "verlet"])
def test_a_solver_whose_tethers_gave_way_starts_the_next_run_with_them_held(solver_name: str) -> None:
    """Two runs of the punched cloth (`punched_hammock`, 20 x 20, 6 frames: the plate still
    presses at the end, its tethers released) with one solver give the bytes of a new solver's
    run: the released limits belong to the run that released them."""
    from meshdeform.solvers import make_solver

    built = punched_hammock(20, 6, solver_name)
    fresh = [f.positions for f in simulate(built.model, built.scene, built.settings)]
    solver = make_solver(solver_name)
    first = [f.positions for f in simulate(built.model, built.scene, built.settings, solver=solver)]
    assert solver.released[0] > 0  # the first run ended with tethers released
    again = [f.positions for f in simulate(built.model, built.scene, built.settings, solver=solver)]
    assert all(a.tobytes() == b.tobytes() for a, b in zip(fresh, first, strict=True))
    assert all(a.tobytes() == b.tobytes() for a, b in zip(fresh, again, strict=True))
