"""Slow and fast frames: implicit's longer steps where the cloth touches something but moves slowly
(`meshdeform.simulate.slow_steps_for`, `moves_slowly`), its default steps where it moves fast,
more where it moves many edges a step (`fast_steps_for`, `fast_substeps`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from factories import bumpy_ground, grid_cloth, height_over_grid, write_grid

from meshdeform.scene.colliders import Collider, Plane, TriangleMesh
from meshdeform.scene.forces import Impact
from meshdeform.simulate import (
    FAST_STEP_FACTOR,
    Scene,
    Settings,
    fast_steps_for,
    fast_substeps,
    simulate,
    slow_steps_for,
    steps_for,
)
from meshdeform.solvers.implicit.solver import ImplicitSolver
from meshdeform.solvers.options import ImplicitOptions
from meshdeform.solvers.xpbd.solver import XPBDSolver
from meshdeform.tearing import Cut, Tearer
from pipeline.job import run_job
from pipeline.recipe.load import parse_recipe

GRAVITY = 9.81


def _ground(height: float) -> Collider:
    return Collider(Plane((0.0, height, 0.0), (0.0, 1.0, 0.0)))


def test_slow_steps_only_where_the_cloth_touches_something_and_the_steps_are_the_solvers() -> None:
    """Where a collider touches the cloth and neither count is given, implicit may take its slow
    steps; a calm scene (its calm steps instead), given substeps or iterations, tearing, more
    in-between states than the slow steps hold, or a solver without slow steps: never."""
    touching = Scene(constraints=[_ground(0.0)])
    assert slow_steps_for(steps_for(Settings(solver="implicit"), touching), touching) == ImplicitSolver.slow_steps
    assert slow_steps_for(steps_for(Settings(solver="implicit"), Scene()), Scene()) is None
    given = Settings(solver="implicit", substeps=8)
    assert slow_steps_for(steps_for(given, touching), touching) is None
    given = Settings(solver="implicit", options=ImplicitOptions(iterations=3))
    assert slow_steps_for(steps_for(given, touching), touching) is None
    assert slow_steps_for(Settings(solver="implicit", subframes=8), touching) is None
    assert slow_steps_for(Settings(solver="implicit", subframes=4), touching) is not None
    mesh, model, _ = grid_cloth(4)
    cut = Cut.plane(0.1, point=[0, 0.45, 0], normal=[0, 1, 0])
    tearing = Scene(constraints=[_ground(0.0)], tearing=Tearer(mesh, model, None, [cut]))
    assert slow_steps_for(Settings(solver="implicit"), tearing) is None
    assert slow_steps_for(Settings(solver="xpbd"), touching) is None
    # a copy for fewer frames keeps the steps left to the solver (`dataclasses.replace` would not)
    assert slow_steps_for(Settings(solver="implicit").with_frames(3), touching) is not None


def test_free_fall_stays_exact_across_a_change_of_step_length() -> None:
    """A free sheet falling without damping towards a ground far below starts at rest (slow
    frames: 4 steps) and, once it falls fast, takes 8 steps a frame; BDF2's history starts afresh
    at the change, so every frame stays on the exact free-fall parabola, y0 - g t^2 / 2."""
    cloth = grid_cloth(8, plane="xz")
    scene = Scene(constraints=[_ground(-100.0)])
    settings = Settings(solver="implicit", frames=24, options=ImplicitOptions(damping=0.0))
    frames = list(simulate(cloth.model, scene, settings))
    steps = [f.substeps for f in frames]
    assert steps[0] == ImplicitSolver.slow_steps[0] and steps[-1] == settings.substeps  # both lengths ran
    for frame in frames:
        expected = cloth.model.rest_positions[:, 1] - 0.5 * GRAVITY * frame.time**2
        np.testing.assert_allclose(frame.welded_positions[:, 1], expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(frame.max_speed, GRAVITY * frame.time, rtol=1e-9)


def test_a_sheet_dropped_on_a_ball_lands_at_the_default_steps_and_lies_at_the_slow_ones(tmp_path: Path) -> None:
    """Through a job: a 1 m sheet of 16 x 16 vertices dropped flat from 1.2 m onto a ball on the
    ground lands at about 4 m/s in frames of 8 steps (every frame after one faster than 3 m/s);
    draped and lying it takes the slow steps; it keeps the colliders' thickness (less 1 mm, at its
    vertices) and stays nearly unstretched (measured: 1.061 at worst, a single frame of the drape
    lying on the ball; 1.044 with 8 steps in every frame); the report lists each frame's steps."""
    mesh = write_grid(tmp_path / "sheet.obj", 16, plane="xz")
    recipe = parse_recipe(
        """
        [simulation]
        frames = 60
        [[colliders]]
        ground = { height = -1.5 }
        thickness = 0.01
        [[colliders]]
        sphere = { center = [0.5, -1.3, 0.5], radius = 0.2 }
        thickness = 0.01
        [output]
        formats = ["npz"]
        """
    )
    report = run_job(mesh, recipe, tmp_path / "out").report
    steps, speeds = report["frame_substeps"], report["max_speed"]
    assert len(steps) == 60 and set(steps) == {4, 8}
    fast = [step for step, speed in zip(steps[1:], speeds, strict=False) if speed > 3.0]
    assert fast and set(fast) == {8}
    assert steps[-12:] == [4] * 12  # lying still
    assert max(report["max_stretch"]) < 1.08
    with np.load(tmp_path / "out" / "positions.npz") as data:
        positions = data["positions"].astype(np.float64)
    assert positions[..., 1].min() > -1.5 + 0.01 - 0.001
    assert (np.linalg.norm(positions - [0.5, -1.3, 0.5], axis=-1) - 0.2).min() > 0.01 - 0.001


def test_in_between_states_change_no_frame_of_a_run_at_slow_steps() -> None:
    """Motion blur's in-between states (up to the slow steps' 4) are kept from the steps each
    frame takes, slow or not: the frames are the bytes of the run without them, and each kept
    state lies between its frame and the one before."""
    cloth = grid_cloth(24, plane="xz")
    scene = Scene(constraints=[_ground(-1.0)])
    plain = list(simulate(cloth.model, scene, Settings(solver="implicit", frames=24)))
    assert {f.substeps for f in plain} == {ImplicitSolver.slow_steps[0], Settings(solver="implicit").substeps}
    for subframes in (2, 4):
        scene = Scene(constraints=[_ground(-1.0)])
        blurred = list(simulate(cloth.model, scene, Settings(solver="implicit", frames=24, subframes=subframes)))
        previous = 0.0
        for a, b in zip(plain, blurred, strict=True):
            assert a.positions.tobytes() == b.positions.tobytes() and a.substeps == b.substeps
            times = [t for t, _ in b.subframes]
            assert len(times) == subframes - 1 and previous < min(times) and max(times) < b.time
            previous = b.time


def test_fast_steps_only_where_the_cloth_touches_something_and_the_substeps_are_the_solvers() -> None:
    """More steps for a fast frame where a collider touches the cloth and the substeps were left to
    a solver that asks for them (implicit, xpbd, verlet); never in a calm scene, at given substeps,
    where the cloth tears, or with a solver that does not (springs: its stable explicit steps)."""
    touching = Scene(constraints=[_ground(0.0)])
    assert fast_steps_for(steps_for(Settings(solver="implicit"), touching), touching) == ImplicitSolver.fast_step_edges
    assert fast_steps_for(steps_for(Settings(solver="implicit"), Scene()), Scene()) is None
    assert fast_steps_for(steps_for(Settings(solver="implicit", substeps=8), touching), touching) is None
    assert fast_steps_for(Settings(solver="xpbd"), touching) == XPBDSolver.fast_step_edges
    assert fast_steps_for(Settings(solver="springs"), touching) is None
    mesh, model, _ = grid_cloth(4)
    cut = Cut.plane(0.1, point=[0, 0.45, 0], normal=[0, 1, 0])
    tearing = Scene(constraints=[_ground(0.0)], tearing=Tearer(mesh, model, None, [cut]))
    assert fast_steps_for(Settings(solver="implicit"), tearing) is None
    # whole multiples of the default steps, up to FAST_STEP_FACTOR of them
    edge, fps = 0.05, 24.0
    assert fast_substeps(0.0, edge, fps, 8, 3.0) == 8
    assert fast_substeps(3.0 * edge * fps * 8 * 1.5, edge, fps, 8, 3.0) == 16
    assert fast_substeps(1e6, edge, fps, 8, 3.0) == 8 * FAST_STEP_FACTOR


def test_a_sheet_shot_onto_bumpy_ground_takes_more_steps_and_keeps_its_springs() -> None:
    """A 20 x 20 sheet kicked down at 53 m/s onto an open bumpy ground: at implicit's 8 steps a
    frame the fastest vertices moved 7 edges a step, those the ground stopped were left 4.5 times
    their springs' length from their neighbours and a finer sheet diverged (checked through the
    CLI: 22.7x at frame 1). The frames of the impact now take more steps; every vertex stays above
    the ground (its height under the vertex, interpolated in the grid's triangle) by the thickness."""
    n, size, thickness = 17, 1.6, 0.01
    vertices, triangles = bumpy_ground(n, size)
    cloth = grid_cloth(20, plane="xz", centred=True, offset=(0.0, 2.2, 0.0))
    ground = Collider(TriangleMesh(vertices, triangles), friction=0.5, thickness=thickness)
    kick = Impact(time=0.0, radius=1e6, strength=53.0, duration=0.002, point=(0, 100, 0), direction=(0, -1, 0))
    scene = Scene(gravity=(0.0, -GRAVITY, 0.0), forces=[kick], constraints=[ground])
    frames = list(simulate(cloth.model, scene, Settings(solver="implicit", frames=6)))
    impact_steps = max(f.substeps for f in frames[:2])
    assert impact_steps > ImplicitSolver.default_substeps
    assert frames[-1].substeps < impact_steps  # fewer once it lies
    assert max(f.max_stretch for f in frames) < 2.5
    for frame in frames:
        x = frame.welded_positions
        clearance = x[:, 1] - height_over_grid(vertices, n, size, x)
        assert clearance.min() > thickness - 1e-3, frame.index


def test_the_report_lists_the_fast_frames_among_those_that_took_extra_work(tmp_path: Path) -> None:
    """Through a job: a 1 m sheet of 12 x 12 kicked down at 20 m/s onto the ground 1 m below takes
    more than its 8 steps in the frames it moves fast in (`frame_substeps`), and the report counts
    each of those among the frames that needed extra work (`contact_extra_work_frames`)."""
    mesh = write_grid(tmp_path / "sheet.obj", 12, plane="xz")
    recipe = parse_recipe(
        """
        [simulation]
        frames = 6
        [[colliders]]
        ground = { height = -1.0 }
        [[impacts]]
        time = 0.0
        point = [0, 100, 0]
        radius = 1000.0
        strength = 20.0
        duration = 0.002
        direction = [0, -1, 0]
        [output]
        formats = ["npz"]
        """
    )
    report = run_job(mesh, recipe, tmp_path / "out").report
    fast = [index for index, steps in enumerate(report["frame_substeps"], start=1) if steps > report["substeps"]]
    assert fast and set(fast) <= set(report["contact_extra_work_frames"])


def test_a_sheet_falling_from_high_up_takes_more_steps_only_in_the_frames_it_may_land_in() -> None:
    """A 40 x 40 sheet falling flat from 3 m onto the ground (air damping holds it below 4 m/s)
    moves more than half an edge a step from 0.4 s on, but takes implicit's default steps until
    the frame in which it may reach the ground (its fastest vertex's travel in the frame against
    its distance from the ground's thickness, `meshdeform.scene.colliders.nearest_obstacle`); that
    frame takes more."""
    cloth = grid_cloth(40, plane="xz", offset=(0.0, 3.0, 0.0))
    frames = list(simulate(cloth.model, Scene(constraints=[_ground(0.0)]), Settings(solver="implicit", frames=32)))
    heights = [cloth.model.rest_positions[:, 1].min()] + [f.welded_positions[:, 1].min() for f in frames]
    speeds = [0.0] + [f.max_speed for f in frames]
    for k, frame in enumerate(frames):
        out_of_reach = heights[k] - 0.01 > (speeds[k] + 0.5) / 24.0  # (0.5 m/s: what gravity adds in a frame)
        if out_of_reach:
            assert frame.substeps <= ImplicitSolver.default_substeps, frame.index
    assert max(f.substeps for f in frames) > ImplicitSolver.default_substeps  # the landing
