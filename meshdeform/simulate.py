"""The fixed-step simulation loop: frames split into substeps, forces and constraints around a solver.

Per substep: external accelerations (gravity plus every force of the scene; filled once when
the scene has no forces) are evaluated, animated hard pins are moved to their targets, the
solver steps, then the scene's constraints (colliders, soft pins) are projected and hard pins
are restored exactly (bit-identical to the input, or to their animation targets). When nothing
happens between substeps (gravity only: no forces, constraints, pin animation or tearing), the
frame's substeps are one `Solver.advance(model, state, dt, control, count)` call (verlet and
xpbd run them in one compiled call that keeps the vertices in their scratch; the default is a
loop of `step`, the same bytes).

After every frame, before it is yielded, the divergence guard stops the run with
`SimulationDiverged` naming the frame, the solver, what went wrong and a hint (the solver's
`Solver.hint`), when
- positions are non-finite, or a vertex is farther from the mesh centre than a generous bound
  (1000 mesh diagonals plus twice the free-fall distance plus 100 m, `_runaway_limit`);
- a vertex moves faster than `_speed_limit` (1000 m/s plus 100 mesh diagonals per second plus
  twice the free-fall speed), or
- a structural spring is longer than `STRETCH_LIMIT` (10) times its current rest length
  (`_stretch_limit`: more with tearing).
The last two catch blow-ups that something keeps finite: tethers hold an exploding cloth
within reach of its pins, a collider with friction stops it running away. No frame with
non-finite positions is ever yielded. The guard costs one pass over the vertices and one over
the structural springs per frame (the spring pass is the frame's `max_stretch`).

Why these bounds: real scenes stay far below them and blow-ups cross them within a frame or
two, since an unstable step multiplies the error every substep. Cloth stretches a few percent
(the samples reach 1.29x; a torn curtain's edges 2.5x while the tear opens); 10x is a rope
or cloth that has exploded, been pulled apart by its pins or is made of a material far too
soft to hold itself, none of which gives a usable bake. The fastest scenes cloth meets stay
near 60 m/s (a 200 m free fall, cloth shot onto plates, hurricane wind; the samples peak at
17 m/s), 1000 m/s is three times the speed of sound. The mesh-diagonal term lifts the speed
bound for meshes modelled in centimetres or millimetres (their units per second are larger),
the free-fall term for long falls and gravity given in those units, as in the runaway bound.

Each frame reports its force residual (`Frame.force_residual`, `guard_kernels.force_residual`):
how far the free vertices are from the balance of their springs (Hooke forces with the
material's spring constants, `common.spring_constants`, the same for every solver) and the
external accelerations of the frame's last substep (gravity and the scene's forces), as the
norm of the imbalance over the norm of the load. Moving cloth is out of balance by its inertia
(1 in free fall); a cloth at rest in a converged solution is in balance, so at rest the figure
says whether the solver converged: a position based solver whose sweeps do not converge
settles, still, out of balance and softer than its material (`CONVERGED_RESIDUAL`). Contact,
soft pins, tethers and other constraints hold the cloth with forces it does not count: where
they act, a cloth at rest is out of balance by their share too.

Each frame reports its largest vertex speed and whether the model is at rest (`max_speed` below
`Settings.rest_speed`, default 1e-4 m/s, and no vertex farther from where it was at the frame
before than that speed over a frame: a sheet creeping down a slope ends every substep with the
velocity its friction removed, yet moves); `rest_frame` is the first frame of the current run of
frames at rest (None while moving), and `rest_frame(frames)` finds it in a list.

Tearing (`Scene.tearing`, a `meshdeform.tearing.Tearer`): after each substep the tearer tests
the springs, applies due cuts and, when the mesh opens, returns a new model and an index map
(new vertex -> old vertex); the loop then continues with that model (the state was resized in
place), re-derives its per-vertex arrays (pins, accelerations), calls the solver's `follow_tear` and
`remap(model, index_map)` on every `Remappable` force and constraint (`Scene.remappables()`), so
per-vertex data follow the split.
Hard-pinned vertices that a cut splits stay pinned to their original's target. Frames then
carry positions in the grown output layout, the output `mesh` when it changed, the `model` in
force, and the springs broken, vertices added and connected pieces.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from meshdeform.errors import MeshdeformError, SimulationDiverged
from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Scene
from meshdeform.scene.colliders import (
    contact_planes,
    hold_contacts_still,
    largest_surface_speed,
    nearest_obstacle,
    pushed_vertices,
    share_company,
    still_pushes,
)
from meshdeform.solvers import guard_kernels
from meshdeform.solvers.base import Control, Solver, SolverOptions
from meshdeform.solvers.common import spring_constants, structural_mask
from meshdeform.solvers.registry import DEFAULT_SOLVER, make_solver, solver_class, solver_options

if TYPE_CHECKING:
    from meshdeform.contact.self_collision import ContactWork
    from meshdeform.tearing import Tearer


@dataclass(frozen=True)
class Settings:
    """Time stepping: frames at fps, each split into substeps, and the solver's options.

    substeps: solver steps per frame; None (the default) takes the solver's `default_substeps`
        and is resolved on construction, so `settings.substeps` is always an int afterwards.
        Iterations likewise come from `options.iterations` or the solver's default (see
        `Settings.iterations`). Where both are the defaults and the scene lets the cloth touch
        nothing, `steps_for` gives the solver's calm steps instead (`Solver.calm_steps`):
        `simulate` runs with what it returns. A copy made by `dataclasses.replace` passes the
        resolved count on, so it counts as given: change a field of the settings before they
        are resolved (or pass `substeps=None` again) to keep the calm steps.
    options: the solver's own options (its `Solver.options_class`); None (the default) takes
        that class's defaults, resolved on construction like substeps. Options of another
        solver's class raise MeshdeformError.
    rest_speed: m/s; a frame whose largest vertex speed is below it, and whose vertices moved less
        than it times the frame's time since the frame before, is at rest.
    subframes: states per frame kept for motion blur: each frame also carries the `subframes - 1`
        states between it and the frame before, at the substeps nearest to j / subframes of the
        frame (`Frame.subframes`); 1 keeps none. At most `substeps`.
    """

    solver: str = DEFAULT_SOLVER
    fps: float = 24.0
    frames: int = 120
    substeps: int | None = None
    options: SolverOptions | None = None
    rest_speed: float = 1e-4
    subframes: int = 1
    #: substeps were None, left to the solver (set on construction: `steps_for` reads it)
    substeps_defaulted: bool = field(init=False, default=False)

    def __post_init__(self) -> None:
        cls = solver_class(self.solver)
        object.__setattr__(self, "substeps_defaulted", self.substeps is None)
        if self.substeps is None:
            object.__setattr__(self, "substeps", int(cls.default_substeps))
        object.__setattr__(self, "options", solver_options(cls, self.options))
        if not 1 <= int(self.subframes) <= int(self.substeps):
            raise MeshdeformError(
                f"subframes must be 1 to the {self.substeps} substeps a frame, not {self.subframes}"
            )

    def with_frames(self, frames: int) -> Settings:
        """These settings for `frames` frames, the substeps left to the solver where they were
        (`dataclasses.replace` would pass the resolved count on as given, and with it lose the
        calm and slow steps)."""
        return replace(self, frames=frames, substeps=None if self.substeps_defaulted else self.substeps)

    @property
    def subframe_substeps(self) -> tuple[int, ...]:
        """The substeps (1 .. substeps - 1, increasing) after which a frame's in-between states are
        kept: the nearest to j / subframes of the frame, j = 1 .. subframes - 1."""
        m, n = int(self.subframes), int(self.substeps)
        return tuple(sorted({max(1, min(n - 1, round(j * n / m))) for j in range(1, m)}))

    @property
    def dt(self) -> float:
        return 1.0 / (self.fps * self.substeps)

    @property
    def iterations(self) -> int:
        """Iterations per substep in force (0 for solvers without iterations)."""
        return self.options.iterations_for(solver_class(self.solver))


@dataclass(frozen=True)
class Frame:
    """One output frame: number (from 1; `initial_frame` is frame 0, the state before the first
    step), time, positions in the input layout and figures.

    max_stretch: largest structural spring length / rest length. max_speed: m/s.
    at_rest: max_speed below `Settings.rest_speed`, and no vertex moved farther than that speed
    times the frame's time since the frame before. rest_frame: the first frame of the
    current run of frames at rest, None when this frame is not at rest.
    With tearing (`Scene.tearing`): positions are in the output layout (the input's vertices,
    then the copies tearing added); mesh: the output mesh when its topology changed during
    this frame, else None (the last one given stays in force); model: the model in force at the
    end of the frame (welded_positions are its vertices); broken_springs / split_vertices: how
    many springs broke and vertices were added during the frame; pieces: connected pieces of
    the mesh at the end of it (None without tearing).
    contact: what self-collision did during the frame (`Scene.self_collision`; None when off).
    subframes: the states kept inside the frame for motion blur (`Settings.subframes`): (time in
    s, positions in the input layout (V, 3)) in time order, after the frame before and before
    this one; empty unless asked for.
    force_residual: the free vertices' force imbalance relative to their load at the end of the
        frame (see the module docstring); at rest above `CONVERGED_RESIDUAL`: not converged.
    substeps: the solver steps the frame took (the settings' substeps, or the solver's
        `slow_steps` where the cloth moved slowly: `slow_steps_for`); 0 for `initial_frame`.
    """

    index: int
    time: float
    positions: np.ndarray
    welded_positions: np.ndarray
    max_stretch: float
    max_speed: float
    at_rest: bool = False
    rest_frame: int | None = None
    mesh: Mesh | None = None
    model: SpringModel | None = None
    broken_springs: int = 0
    split_vertices: int = 0
    pieces: int | None = None
    contact: ContactWork | None = None
    subframes: tuple[tuple[float, np.ndarray], ...] = ()
    force_residual: float = 0.0
    substeps: int = 0


def initial_frame(model: SpringModel, state: State | None = None) -> Frame:
    """Frame 0: the model where `simulate` starts from it (its rest pose unless `state` is given),
    at time 0, before any step. Outputs write it as the first frame (the rest pose at the start
    frame, as Blender's own cloth cache does), so frame k is the state k / fps seconds later."""
    state = state or State.at_rest(model)
    welded = np.array(state.positions, dtype=np.float64)
    structural = _Structural.of(model)
    stretch = (
        float(guard_kernels.max_ratio(welded, structural.a, structural.b, structural.rest))
        if structural.a.size
        else 1.0
    )
    speed = float(np.sqrt(np.max(np.einsum("ij,ij->i", state.velocities, state.velocities), initial=0.0)))
    return Frame(
        index=0,
        time=float(state.time),
        positions=model.to_input_layout(welded),
        welded_positions=welded,
        max_stretch=stretch,
        max_speed=speed,
        model=model,
    )


#: force residual (`Frame.force_residual`) above which a cloth at rest has not converged: on the
#: 1 m cloth hanging from two corners the runs above it settled 2 % to 9x off the material's sag,
#: those below it within 4.5 % (docs/performance.md, "Convergence")
CONVERGED_RESIDUAL = 0.1
#: cells a side of the grid the force residual sums forces over (see `guard_kernels.force_residual`)
RESIDUAL_CELLS = 4


def converged(frame: Frame, scene: Scene) -> bool | None:
    """Whether a run that ended with `frame` settled on a converged shape: True or False when the
    cloth is at rest and nothing but springs and forces holds it (no constraints, self-collision
    or pin animation, whose forces the residual does not count: `Frame.force_residual`), by
    `CONVERGED_RESIDUAL`; None otherwise (still moving, or held by what the figure cannot see).
    A solver's own tethers are counted as its sweeps' work: their hold shows in the figure."""
    held = bool(scene.constraints) or scene.self_collision is not None or scene.pin_motion is not None
    if not frame.at_rest or held:
        return None
    return frame.force_residual <= CONVERGED_RESIDUAL


def convergence_warning(frame: Frame, scene: Scene, options: SolverOptions | None = None) -> str | None:
    """The report's sentence when a run settled unconverged (`converged` is False), else None. With
    the solver's tethers on (`options`, `SolverOptions.holds_beyond_springs`) the imbalance may be
    theirs: holding the cloth within its rest distances to the pins, they keep a soft cloth higher
    than its material would hang, and more iterations change nothing there."""
    if converged(frame, scene) is not False:
        return None
    balance = (
        f"not converged: at rest the cloth is out of force balance by {frame.force_residual:.3g} times "
        f"its weight (tolerance {CONVERGED_RESIDUAL:g})"
    )
    if options is not None and options.holds_beyond_springs:
        return (
            f"{balance}: the sweeps did not reach its material's equilibrium (it hangs softer: raise iterations or "
            "substeps), or the solver's tethers hold it above it (a soft cloth: set tethers = 0 in the solver's "
            "table to hang by its springs alone)"
        )
    return f"{balance}, so it hangs softer than its material; raise iterations or substeps"


def rest_frame(frames: Iterable[Frame]) -> int | None:
    """The frame from which the model stayed at rest to the last frame given (None if it did not)."""
    last = None
    for frame in frames:
        last = frame
    return last.rest_frame if last is not None else None


def _rest_diagonal(model: SpringModel) -> float:
    """Bounding-box diagonal of the rest shape (1.0 for an empty or point-like model)."""
    if not model.vertex_count:
        return 1.0
    extent = model.rest_positions.max(axis=0) - model.rest_positions.min(axis=0)
    return float(np.linalg.norm(extent)) or 1.0


def _runaway_limit(diagonal: float, gravity: np.ndarray, time: float) -> float:
    """How far from the rest centre positions may get before the run counts as exploded."""
    return 1000.0 * diagonal + float(np.linalg.norm(gravity)) * time * time + 100.0


#: largest structural spring length / rest length of a run that has not blown up (see the module docstring)
STRETCH_LIMIT = 10.0
#: with tearing, edges stretch past their break threshold while a tear waits for its update:
#: the stretch bound is at least this many times the largest break threshold
TEAR_STRETCH_FACTOR = 4.0
#: m/s: the fixed part of the speed bound (see the module docstring and `_speed_limit`)
SPEED_LIMIT = 1000.0
#: springs shorter than this fraction of the median structural rest length (slivers of CAD or
#: scanned meshes) are measured against that length by the guard, so a sliver drawn out to a
#: normal edge's length does not count as a blow-up (the frames' max_stretch stays exact)
SLIVER_FRACTION = 0.25
#: a frame takes the solver's slow steps (`slow_steps_for`) where the cloth's fastest vertex at the
#: end of the frame before moves at most this fraction of its median structural rest length in one
#: of them: a cloth landing on an obstacle (1-3 m/s in the contact benchmarks' 40 x 40 sheets,
#: 0.6 edges a step at 4 a frame) keeps the defaults, one lying or draping on it (0.2-0.5 m/s)
#: takes the slow steps (docs/performance.md, "Slow steps")
SLOW_STEP_EDGES = 0.35
#: a frame that takes more substeps for a fast cloth (`fast_substeps`) takes at most this many
#: times the settings' substeps
FAST_STEP_FACTOR = 8


def _speed_limit(diagonal: float, gravity: np.ndarray, time: float) -> float:
    """m/s a vertex may reach after `time` seconds before the run counts as exploded."""
    return SPEED_LIMIT + 100.0 * diagonal + 2.0 * float(np.linalg.norm(gravity)) * time


def _stretch_limit(tearing: Tearer | None) -> float:
    """The stretch bound: `STRETCH_LIMIT`, or with tearing at least `TEAR_STRETCH_FACTOR` times
    the largest break threshold (a recipe may let rubber tear at 5x)."""
    settings = tearing.initial_settings if tearing is not None else None
    if settings is None:
        return STRETCH_LIMIT
    thresholds = np.asarray(settings.thresholds)
    finite = thresholds[np.isfinite(thresholds)]
    return max(STRETCH_LIMIT, TEAR_STRETCH_FACTOR * float(finite.max())) if finite.size else STRETCH_LIMIT


def _stretch_hint(hint: str) -> str:
    """What to try when springs stretched past the bound: the solver's own advice (`Solver.hint`:
    an unstable step is the usual cause), then the scene's culprits."""
    return (
        f"{hint}; check that pins do not pull the mesh apart, that impacts and wind "
        "are not too strong and that the material is not far too soft"
    )


def _speed_hint(hint: str) -> str:
    """What to try when vertices moved faster than the bound: the solver's own advice
    (`Solver.hint`), then the scene's fast movers."""
    return (
        f"{hint}; check the strength of impacts and wind and the speed of animated pins "
        "and colliders (a looping animation jumps back to its start)"
    )


def calm(scene: Scene) -> bool:
    """Nothing in the scene touches the cloth: no constraint (a collider, an attachment, ...), no
    self-collision, no tearing; forces, impacts and pin animation may act."""
    return not scene.constraints and scene.self_collision is None and scene.tearing is None


def steps_for(settings: Settings, scene: Scene, model: SpringModel | None = None) -> Settings:
    """The settings a run of the scene uses: the solver's calm steps (`Solver.calm_steps`, with its
    `calm_options`) where the scene is `calm` and neither the substeps nor the iterations were
    given; where it is not calm and the substeps were not given, at least the substeps the solver
    needs under contact on `model` (`Solver.contact_substeps`; not asked without a model); else
    `settings` itself."""
    if not calm(scene):
        if settings.substeps_defaulted and model is not None:
            needed = make_solver(settings.solver, settings.options).contact_substeps(model, settings.fps)
            if needed > int(settings.substeps):
                return replace(settings, substeps=needed)
        return settings
    steps = solver_class(settings.solver).calm_steps
    if steps is None or not settings.substeps_defaulted or settings.options.iterations is not None:
        return settings
    substeps, iterations = steps
    if int(settings.subframes) > substeps:  # the in-between states kept need as many steps
        return settings
    options = solver_class(settings.solver).calm_options(replace(settings.options, iterations=iterations))
    return replace(settings, substeps=substeps, options=options)


def slow_steps_for(settings: Settings, scene: Scene) -> tuple[int, int] | None:
    """The (substeps, iterations) of a run's frames in which the cloth moves slowly
    (`moves_slowly`), for a run at `settings` as `steps_for` resolved them: the solver's
    `slow_steps` where the scene is not calm, nothing tears (a tear is decided substep by
    substep), the substeps and the iterations were both left to the solver (and not raised by
    `Solver.contact_substeps`) and the in-between states kept fit in them; None otherwise (every
    frame at the settings' steps).

    Why: a frame with contact needs short steps where an obstacle stops part of the cloth within a
    step (an impact: the implicit solver's few iterations cannot resolve a long one), but a cloth
    lying, draping or sliding slowly on its obstacles holds at half as many steps (with more
    iterations each), and each step saved is a collider and a self-collision pass saved
    (docs/performance.md, "Slow steps")."""
    steps = solver_class(settings.solver).slow_steps
    if steps is None or calm(scene) or scene.tearing is not None:
        return None
    if not settings.substeps_defaulted or settings.options.iterations is not None:
        return None
    return steps if int(settings.subframes) <= steps[0] else None


def fast_steps_for(settings: Settings, scene: Scene) -> float | None:
    """The solver's `fast_step_edges` for a run at `settings` as `steps_for` resolved them, where the
    scene is not calm, nothing tears and the substeps were left to the solver; None otherwise (no
    frame takes more steps for speed). Tearing keeps its steps: a tear is decided substep by
    substep, and a strip stretched to its breaking point snaps back the harder the more steps the
    frame after takes (a knit strip torn at 12x its length reached 1275 m/s under xpbd).

    Why: where an obstacle stops part of the cloth within a step, the springs to the vertices that
    move on stretch by what those move in the step: a cloth shot at 50 m/s onto bumpy ground
    moved 7 edges a step at implicit's 8 a frame and its few iterations could not pull the
    springs back from that (docs/performance.md, "Fast steps")."""
    edges = solver_class(settings.solver).fast_step_edges
    if edges is None or calm(scene) or scene.tearing is not None or not settings.substeps_defaulted:
        return None
    return edges


def fast_substeps(speed: float, edge: float, fps: float, substeps: int, edges: float) -> int:
    """The substeps of a frame at `fps` (frames/s) whose fastest vertex is expected at `speed` (m/s)
    on a cloth of median structural rest length `edge` (m): the fewest multiple of `substeps`
    (whole multiples: few step lengths in a run, each one met again) that keeps that vertex
    within `edges` rest lengths a step, at most `FAST_STEP_FACTOR` times `substeps`. (`simulate`
    keeps the settings' substeps where no collider is within the frame's reach of the cloth.)"""
    if edge <= 0.0 or edges <= 0.0:
        return substeps
    needed = math.ceil(speed / (edges * edge * fps * substeps) - 1e-9)
    return substeps * min(max(needed, 1), FAST_STEP_FACTOR)


def steps_vary(settings: Settings, scene: Scene) -> bool:
    """Whether the frames of a run at `settings` (as `steps_for` resolved them) may take other steps
    than the settings' (`slow_steps_for`, `fast_steps_for`): its frames then say theirs."""
    return slow_steps_for(settings, scene) is not None or fast_steps_for(settings, scene) is not None


def moves_slowly(speed: float, edge: float, fps: float, substeps: int) -> bool:
    """Whether a frame of `substeps` steps at `fps` (frames/s) moves a cloth whose fastest vertex
    goes at `speed` (m/s) by at most `SLOW_STEP_EDGES` of its median structural rest length
    `edge` (m) a step."""
    return speed <= SLOW_STEP_EDGES * edge * fps * substeps


def simulate(
    model: SpringModel,
    scene: Scene | None = None,
    settings: Settings | None = None,
    solver: Solver | None = None,
    state: State | None = None,
) -> Iterator[Frame]:
    """Yield `settings.frames` frames of the model moving under the scene, starting at rest."""
    scene = scene or Scene()
    settings = steps_for(settings or Settings(), scene, model)
    solver = solver or make_solver(settings.solver, settings.options)
    name, hint = solver.name, solver.hint
    state = state or State.at_rest(model)
    # the scene's initial velocity: in the state's velocities (the implicit and explicit solvers'
    # own), and for the solvers that read a vertex's velocity as (x - previous) / dt (verlet,
    # xpbd) in its previous position at the first step, once that step's length is known
    launch = None if scene.initial_velocity is None else np.asarray(scene.initial_velocity, dtype=np.float64)
    free = np.asarray(model.inv_mass) > 0.0
    if launch is not None:
        state.velocities[free] = launch
    substeps = int(settings.substeps)
    dt = 1.0 / (settings.fps * substeps)
    start_time = state.time
    gravity = np.asarray(scene.gravity, dtype=np.float64)
    diagonal = _rest_diagonal(model)  # tearing splits vertices but keeps the rest shape
    pinned_idx = np.flatnonzero(model.pinned)
    pinned_rest = np.array(model.rest_positions[pinned_idx])
    accelerations = np.empty_like(state.positions)
    accelerations[:] = gravity
    control = Control(accelerations=accelerations, pulled=scene.pulled(model.vertex_count))
    forces = [force for force in scene.forces if not force.kicks]
    kicks = [force for force in scene.forces if force.kicks]
    control.kicks = np.zeros_like(accelerations) if kicks else None
    constraints = list(scene.constraints)
    share_company(constraints)  # which compiled contact pipelines the colliders run
    hold_contacts_still(constraints, not solver.holds_contacts)  # static friction's hold: the solver's, where it holds
    remappable = scene.remappables()  # the forces and constraints with per-vertex data (follow tears)
    pin_motion = scene.pin_motion if pinned_idx.size else None
    center = model.rest_positions.mean(axis=0) if model.vertex_count else np.zeros(3)
    structural = _Structural.of(model)
    balance = _Balance.of(model)
    tearing = scene.tearing
    stretch_limit = _stretch_limit(tearing)
    pin_slot: np.ndarray | None = None  # after a cut splits pins: current pinned -> original pin target
    if tearing is not None:
        tearing.start(model)
        original_pins = np.flatnonzero(tearing.initial_model.pinned)
    step = solver.step
    resting_since: int | None = None
    # nothing between the substeps (no forces, constraints, pin motion or tearing): the solver
    # runs a whole frame in one call (`Solver.advance`), with the same result as substep by substep
    self_collision = scene.self_collision
    whole_frames = not (forces or kicks or constraints) and all(
        item is None for item in (pin_motion, tearing, self_collision)
    )
    keep_after = settings.subframe_substeps  # substeps whose state the frame keeps (motion blur)
    # frames in which the cloth moves slowly at the solver's slow steps (`slow_steps_for`), judged
    # by its speed at the end of the frame before
    slow = slow_steps_for(settings, scene)
    fast = fast_steps_for(settings, scene)
    edge = float(np.median(structural.rest)) if structural.rest.size else 0.0
    speed = float(guard_kernels.guard_figures(state.positions, state.velocities, center)[2])
    last_positions = state.positions.copy()  # the frame before's, to tell a creeping cloth from a still one
    for frame in range(1, settings.frames + 1):
        kept: list[tuple[float, np.ndarray]] = []
        frame_substeps, control.iterations, frame_keep_after = substeps, None, keep_after
        if slow is not None or fast is not None:
            # the fastest vertex expected in the frame: as fast as at the end of the frame before or
            # as a moving collider would carry it, plus what the kicks in the frame may add
            frame_start = start_time + (frame - 1) / settings.fps
            frame_end = frame_start + 1.0 / settings.fps
            carried = largest_surface_speed(constraints, state.positions, frame_start, frame_end)
            kicked = sum(force.largest_kick(frame_start, frame_end) for force in kicks)
            expected = max(speed, carried) + kicked
            if slow is not None and moves_slowly(expected, edge, settings.fps, slow[0]):
                frame_substeps, control.iterations = slow
            elif fast is not None:
                frame_substeps = fast_substeps(expected, edge, settings.fps, substeps, fast)
                # only where the cloth can meet an obstacle within the frame (a sheet falling
                # from high up keeps its steps until the frame it may land in)
                reach = (speed + carried + kicked) / settings.fps
                if frame_substeps > substeps and nearest_obstacle(constraints, state.positions, frame_start) > reach:
                    frame_substeps = substeps
            if frame_substeps != substeps:
                frame_keep_after = replace(settings, substeps=frame_substeps).subframe_substeps
        dt = 1.0 / (settings.fps * frame_substeps)
        if launch is not None:  # the first step's start: where the velocity came from a step back
            state.previous[free] = state.positions[free] - launch * dt
            launch = None
        if whole_frames:  # in runs of substeps between the states kept: the same bytes
            done = 0
            for until in (*frame_keep_after, frame_substeps):
                solver.advance(model, state, dt, control, until - done)
                if pinned_idx.size:
                    state.positions[pinned_idx] = pinned_rest
                state.time = start_time + ((frame - 1) * frame_substeps + until) * dt
                done = until
                if until < frame_substeps:
                    kept.append((state.time, model.to_input_layout(state.positions.copy())))
        for substep in range(1, 1 + (0 if whole_frames else frame_substeps)):
            t0 = state.time
            # counted in this frame's steps (the bytes of steps counted one by one where every frame has as many)
            t1 = start_time + ((frame - 1) * frame_substeps + substep) * dt
            if forces or kicks:
                accelerations[:] = gravity
                for force in forces:
                    force.accumulate(model, state, t0, dt, accelerations)
            if control.kicks is not None:
                control.kicks[:] = 0.0
                for force in kicks:
                    force.accumulate(model, state, t0, dt, control.kicks)
                accelerations += control.kicks
            if pin_motion is not None:
                targets = np.asarray(pin_motion(t1), dtype=np.float64)
                if pin_slot is not None:
                    targets = targets[pin_slot]
                state.previous[pinned_idx] = state.positions[pinned_idx]
                state.positions[pinned_idx] = targets
            step(model, state, dt, control)
            for constraint in constraints:
                constraint.project(model, state, t1, dt)
            if solver.holds_contacts and constraints:
                control.still_contact, control.friction = still_pushes(constraints, model.vertex_count)
            if self_collision is not None:
                self_collision.project(model, state, t1, dt)
                control.self_contact = self_collision.moved
            if pin_motion is not None:
                state.positions[pinned_idx] = targets
            elif pinned_idx.size:
                state.positions[pinned_idx] = pinned_rest
            if solver.reads_planes and constraints:  # from where the substep leaves the cloth
                control.planes = contact_planes(constraints, model, state)
            if solver.reads_pushes and constraints:
                control.pushed = pushed_vertices(constraints, model.vertex_count)
            state.time = t1
            if tearing is not None:
                event = tearing.after_substep(model, state, t1)
                if event is not None:
                    solver.follow_tear(model, event.model, event.index_map, event.parent)
                    model = event.model
                    for item in remappable:
                        item.remap(model, event.index_map)
                    if self_collision is not None:  # the sides of the tear start apart
                        self_collision.part_seams(model, state)
                    pinned_idx = np.flatnonzero(model.pinned)
                    pinned_rest = np.array(model.rest_positions[pinned_idx])
                    pin_slot = np.searchsorted(original_pins, tearing.origin[pinned_idx])
                    accelerations = np.empty_like(state.positions)
                    accelerations[:] = gravity
                    control = Control(accelerations=accelerations, pulled=scene.pulled(model.vertex_count))
                    control.kicks = np.zeros_like(accelerations) if kicks else None
                    structural = _Structural.of(model)
                    balance = _Balance.of(model)
            if substep in frame_keep_after:
                kept.append((state.time, model.to_input_layout(state.positions.copy())))
        positions = state.positions
        finite, reach, speed = guard_kernels.guard_figures(positions, state.velocities, center)
        diverged = f"simulation diverged at frame {frame} with solver {name!r}"
        if not finite:
            raise SimulationDiverged(
                f"{diverged}: positions became non-finite; try: {hint}", frame=frame, solver=name
            )
        elapsed = state.time - start_time
        if reach > _runaway_limit(diagonal, gravity, elapsed):
            raise SimulationDiverged(
                f"{diverged}: positions ran away ({reach:.3g} from the mesh centre); try: {hint}",
                frame=frame,
                solver=name,
            )
        speed_limit = _speed_limit(diagonal, gravity, elapsed)
        if speed > speed_limit:
            raise SimulationDiverged(
                f"{diverged}: vertices moved at {speed:.4g} m/s (limit {speed_limit:.4g} m/s); "
                f"try: {_speed_hint(hint)}",
                frame=frame,
                solver=name,
            )
        stretch = float(guard_kernels.max_ratio(positions, structural.a, structural.b, structural.rest))
        if stretch > stretch_limit:
            guarded = structural.guarded_stretch(positions, stretch)
            if guarded > stretch_limit:
                raise SimulationDiverged(
                    f"{diverged}: springs stretched to {guarded:.3g}x their rest length "
                    f"(limit {stretch_limit:.3g}x); try: {_stretch_hint(hint)}",
                    frame=frame,
                    solver=name,
                )
        residual = balance.residual(positions, accelerations)
        still = _still(positions, last_positions, settings.rest_speed / settings.fps)
        at_rest = bool(speed < settings.rest_speed) and still
        if not at_rest:
            resting_since = None
        elif resting_since is None:
            resting_since = frame
        welded = positions.copy()
        last_positions = welded
        torn: dict = {}
        if tearing is not None:
            broken, split, changed = tearing.frame_stats()
            torn = {
                "mesh": tearing.mesh if changed else None,
                "broken_springs": broken,
                "split_vertices": split,
                "pieces": tearing.pieces,
            }
        yield Frame(
            index=frame,
            time=state.time,
            positions=model.to_input_layout(welded),
            welded_positions=welded,
            max_stretch=stretch,
            max_speed=float(speed),
            at_rest=at_rest,
            rest_frame=resting_since,
            model=model,
            contact=self_collision.take_work() if self_collision is not None else None,
            subframes=tuple(kept),
            force_residual=residual,
            substeps=frame_substeps,
            **torn,
        )


def _still(positions: np.ndarray, before: np.ndarray, distance: float) -> bool:
    """Whether no vertex of positions (W, 3) is `distance` (m) or farther from where it was in
    before (W, 3); False where a tear changed the vertex count."""
    if before.shape != positions.shape:
        return False
    moved = positions - before
    return bool(np.einsum("ij,ij->i", moved, moved).max(initial=0.0) < distance * distance)


@dataclass(frozen=True)
class _Structural:
    """The structural springs of a model, for the frames' max_stretch and the stretch guard.

    a, b: spring ends (S,) int64; rest: rest lengths (S,) (at least 1e-300, so a zero-length
    spring gives a huge ratio, never a division by zero); guard_rest: rest lengths raised to
    `SLIVER_FRACTION` of their median, or None when no spring is that short.
    """

    a: np.ndarray
    b: np.ndarray
    rest: np.ndarray
    guard_rest: np.ndarray | None

    @classmethod
    def of(cls, model: SpringModel) -> _Structural:
        structural = np.flatnonzero(structural_mask(model))
        a = np.ascontiguousarray(model.springs[structural, 0], dtype=np.int64)
        b = np.ascontiguousarray(model.springs[structural, 1], dtype=np.int64)
        rest = np.ascontiguousarray(np.maximum(model.rest_lengths[structural], 1e-300), dtype=np.float64)
        guard_rest = None
        if rest.size:
            floor = SLIVER_FRACTION * float(np.median(rest))
            if float(rest.min()) < floor:
                guard_rest = np.maximum(rest, floor)
        return cls(a, b, rest, guard_rest)

    def guarded_stretch(self, positions: np.ndarray, stretch: float) -> float:
        """The stretch the guard judges, given the exact `stretch` of these positions: the same
        unless slivers are measured against their floor (a second pass, only when over the bound)."""
        if self.guard_rest is None:
            return stretch
        return float(guard_kernels.max_ratio(positions, self.a, self.b, self.guard_rest))


@dataclass(frozen=True)
class _Balance:
    """A model's springs, masses and cells for the frames' force residual
    (`guard_kernels.force_residual`).

    a, b: spring ends (S,) int64; rest (S,); kt, kc: spring constants under tension and
    compression (S,) N/m (`common.spring_constants`); mass, inv_mass (W,); cell (W,) int64: the
    vertex's cell of a grid of `RESIDUAL_CELLS` cells a side over the rest shape's bounding box
    (one along an axis it does not extend in), so its cells are the same on any mesh of a shape;
    cells: how many. crossing: (a, b, rest, kt, kc) of the K springs whose forces do not cancel
    within a cell (ends in two cells, or a pinned end), the only ones the residual of a loaded
    cloth sums (2 % of them on a 256 x 256 sheet).
    """

    a: np.ndarray
    b: np.ndarray
    rest: np.ndarray
    kt: np.ndarray
    kc: np.ndarray
    mass: np.ndarray
    inv_mass: np.ndarray
    cell: np.ndarray
    cells: int
    crossing: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    @classmethod
    def of(cls, model: SpringModel) -> _Balance:
        kt, kc = spring_constants(model)
        rest = np.asarray(model.rest_positions, dtype=np.float64)
        cell = np.zeros(model.vertex_count, dtype=np.int64)
        cells = 1
        if model.vertex_count:
            low = rest.min(axis=0)
            extent = rest.max(axis=0) - low
            size = float(extent.max())
            for axis in range(3):
                if extent[axis] > 1e-9 * size:
                    index = np.floor((rest[:, axis] - low[axis]) / extent[axis] * RESIDUAL_CELLS).astype(np.int64)
                    cell = cell * RESIDUAL_CELLS + np.clip(index, 0, RESIDUAL_CELLS - 1)
                    cells *= RESIDUAL_CELLS
        a = np.ascontiguousarray(model.springs[:, 0], dtype=np.int64)
        b = np.ascontiguousarray(model.springs[:, 1], dtype=np.int64)
        rest_lengths = np.ascontiguousarray(model.rest_lengths, dtype=np.float64)
        kt, kc = np.ascontiguousarray(kt), np.ascontiguousarray(kc)
        inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        part = np.flatnonzero((cell[a] != cell[b]) | (inv_mass[a] == 0.0) | (inv_mass[b] == 0.0))
        crossing = (a[part], b[part], rest_lengths[part], kt[part], kc[part])
        return cls(
            a, b, rest_lengths, kt, kc, np.ascontiguousarray(model.mass, dtype=np.float64), inv_mass, cell, cells,
            crossing,
        )

    def residual(self, positions: np.ndarray, accelerations: np.ndarray) -> float:
        """The force residual of welded positions (W, 3) under accelerations (W, 3) m/s^2: |R| / |L|
        (`guard_kernels.force_residual`) from the crossing springs; without any load |R| / |M| from
        every spring; 0 when there is neither."""
        r2, load2, _ = self._sums(positions, accelerations, self.crossing, False)
        if load2 > 0.0:
            return float(np.sqrt(r2 / load2))
        r2, _, magnitude2 = self._sums(positions, accelerations, (self.a, self.b, self.rest, self.kt, self.kc), True)
        return float(np.sqrt(r2 / magnitude2)) if magnitude2 > 0.0 else 0.0

    def _sums(
        self, positions: np.ndarray, accelerations: np.ndarray, springs: tuple[np.ndarray, ...], magnitudes: bool
    ) -> tuple[float, float, float]:
        """`guard_kernels.force_residual` over springs (a, b, rest, kt, kc)."""
        force, load, magnitude = np.zeros((self.cells, 3)), np.zeros((self.cells, 3)), np.zeros(self.cells)
        return guard_kernels.force_residual(
            positions, *springs, self.mass, self.inv_mass, accelerations, self.cell, force, load, magnitude,
            magnitudes,
        )
