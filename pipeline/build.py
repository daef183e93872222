"""Recipe + Mesh -> a runnable simulation: SpringModel, Scene (forces, constraints, pin motion), Settings.

Selections are resolved here on the input vertices of the mesh (an empty one is a RecipeError
naming its key path and line), then carried to the welded vertices the model lives on.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from meshdeform.contact.self_collision import SelfCollision, SelfCollisionSettings, contact_thickness, median_edge
from meshdeform.errors import MeshdeformError
from meshdeform.io.caches import cache_timing, check_cache_covers, read_point_cache, sample
from meshdeform.material import Material
from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, lumped_mass
from meshdeform.scene import Constraint, Force, Scene, gravity_vector, up_vector
from meshdeform.scene import colliders as col
from meshdeform.scene.deforming import DeformingCollider, DeformingMesh, SurfaceAttachment
from meshdeform.scene.effects import NearestPinTethers, Plasticity, Pressure
from meshdeform.scene.forces import Impact, Wind, ray_hit
from meshdeform.scene.pins import HardPinMotion, Keyframes, Motion, SoftPins, pivot_of
from meshdeform.selection import BoundsFrame, SelectionContext, SelectionResolveError, vertex_property
from meshdeform.simulate import Settings, steps_for
from meshdeform.solvers.options import SweepOptions
from meshdeform.solvers.registry import solver_class
from meshdeform.tearing import DEFAULT_BURST, DEFAULT_INTERVAL, Cut, Tearer, TearRegion, TearSettings
from meshdeform.topology import SpringKind, Springs, Welding, boundary_edge_count, build_springs
from pipeline.recipe import (
    ColliderSpec,
    KeySpec,
    Recipe,
    SelectSpec,
    format_path,
    parse_path,
    resolve_path,
)

__all__ = ["BuiltSimulation", "build_simulation"]


@dataclass
class BuiltSimulation:
    """Everything `meshdeform.simulate` needs, plus figures for reports.

    selections: key path of each selection (e.g. "pins[0].select") -> input vertices it selects.
    warnings: what in the recipe will have no effect (a cut after the last frame), one sentence each.
    start_frame / up_axis: from the recipe, for the exporters.
    """

    model: SpringModel
    scene: Scene
    settings: Settings
    selections: dict[str, int]
    warnings: tuple[str, ...] = ()
    start_frame: int = 1
    up_axis: str = "y"


class _Resolver:
    """Evaluates recipe selections on one mesh, turning engine errors into recipe errors."""

    def __init__(self, recipe: Recipe, mesh: Mesh) -> None:
        self.recipe = recipe
        self.mesh = mesh
        self.ctx = SelectionContext.for_mesh(mesh)
        self.frame: BoundsFrame = self.ctx.frame
        self.counts: dict[str, int] = {}
        name = mesh.source.name if mesh.source is not None else "the mesh"
        self.mesh_name = name

    def select(self, spec: SelectSpec | None, path: tuple[str | int, ...], relative: bool = False) -> np.ndarray:
        """(V,) bool mask; None selects every vertex."""
        if spec is None:
            mask = np.ones(self.mesh.vertex_count, dtype=bool)
        else:
            node = spec.build(format_path(path), relative)
            try:
                mask = node.mask(self.ctx)
            except SelectionResolveError as exc:
                raise self.recipe.error(parse_path(exc.path) if exc.path else path, exc.detail) from None
        if not mask.any():
            raise self.recipe.error(path, f"selects no vertex of {self.mesh_name} ({self.mesh.vertex_count} vertices)")
        self.counts[format_path(path)] = int(np.count_nonzero(mask))
        return mask

    def property(self, name: str, channel: int | None, path: tuple[str | int, ...]) -> np.ndarray:
        try:
            return vertex_property(self.mesh, name, channel)
        except SelectionResolveError as exc:
            raise self.recipe.error(path, exc.detail) from None

    def point(self, value: tuple[float, float, float], relative: bool) -> np.ndarray:
        return self.frame.to_world(value) if relative else np.asarray(value, dtype=np.float64)

    def length(self, value: float, relative: bool) -> float:
        return self.frame.length(value) if relative else float(value)


def _keyframes(keys: tuple[KeySpec, ...], pivot: np.ndarray, loop: bool) -> Keyframes | None:
    if not keys:
        return None
    return Keyframes([k.to_keyframe() for k in keys], pivot, loop)


def _per_vertex_maps(
    recipe: Recipe, res: _Resolver, mesh: Mesh, material: Material, welding: Welding, springs: Springs
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(vertex_stiffness (V,) or None, vertex_mass (V,) or None) for SpringModel.from_mesh."""
    spec = recipe.material
    stiffness = None
    if spec.stiffness_map is not None:
        m = spec.stiffness_map
        values = res.property(m.attribute, m.channel, ("material", "stiffness_map", "attribute"))
        stiffness = np.maximum(m.offset + m.scale * values, 0.0)
    rep = welding.representative
    vmap = welding.vertex_map
    target = np.full(welding.count, np.nan)  # kg per welded vertex where set
    if spec.mass_map is not None:
        m = spec.mass_map
        values = res.property(m.attribute, m.channel, ("material", "mass_map", "attribute"))
        target = m.offset + m.scale * values[rep]
        if np.any(target <= 0):
            raise recipe.error(("material", "mass_map"), "gives a mass of zero or less to some vertices")
    base_mass = None
    for i, region in enumerate(spec.regions):
        mask = res.select(region.select, ("material", "regions", i, "select"))
        if region.stiffness is not None:
            stiffness = np.ones(mesh.vertex_count) if stiffness is None else stiffness
            stiffness[mask] = region.stiffness
        welded = np.zeros(welding.count, dtype=bool)
        welded[vmap[mask]] = True
        if region.mass is not None:
            target[welded] = region.mass
        elif region.mass_scale is not None:
            if base_mass is None:
                positions = mesh.positions[rep]
                triangles = vmap[mesh.triangles]
                structural = springs.pairs[springs.kinds == SpringKind.STRUCTURAL]
                base_mass = lumped_mass(positions, triangles, structural, material)
            current = np.where(np.isnan(target), base_mass, target)
            target[welded] = current[welded] * region.mass_scale
    vertex_mass = None
    if not np.all(np.isnan(target)):
        vertex_mass = np.zeros(mesh.vertex_count)
        given = ~np.isnan(target)
        vertex_mass[rep[given]] = target[given]
    return stiffness, vertex_mass


def _collider(spec: ColliderSpec, i: int, recipe: Recipe, res: _Resolver, warnings: list[str]) -> col.Collider:
    rel = spec.relative
    path = ("colliders", i, spec.kind)
    shape: col.Shape
    if spec.ground is not None:
        up = up_vector(recipe.simulation.up)
        axis = int(np.argmax(up))
        height = spec.ground.height
        if rel:
            height = res.frame.origin[axis] + height * res.frame.scale[axis]
        shape = col.Plane(up * height, up)
    elif spec.plane is not None:
        normal = np.asarray(spec.plane.normal, dtype=np.float64)
        if rel:
            normal = normal / res.frame.scale  # planes map with the inverse transpose
        shape = col.Plane(res.point(spec.plane.point, rel), normal)
    elif spec.sphere is not None:
        shape = col.Sphere(res.point(spec.sphere.center, rel), res.length(spec.sphere.radius, rel))
    elif spec.box is not None:
        shape = col.Box(res.point(spec.box.min, rel), res.point(spec.box.max, rel))
    elif spec.capsule is not None:
        c = spec.capsule
        shape = col.Capsule(res.point(c.a, rel), res.point(c.b, rel), res.length(c.radius, rel))
    else:
        assert spec.mesh is not None
        from meshdeform.io import load

        file = resolve_path(recipe, spec.mesh.path)
        try:
            other = load(file)
        except MeshdeformError as exc:
            raise recipe.error(path, f"cannot load collider mesh: {exc}") from None
        if other.triangles.shape[0] == 0:
            raise recipe.error(path, f"collider mesh {file} has no faces")
        if spec.mesh.cache is not None:
            return _deforming_collider(spec, i, recipe, other.positions, other.triangles, warnings)
        shape = col.TriangleMesh(other.positions, other.triangles)
    pivot = res.point(spec.pivot, rel) if spec.pivot is not None else shape.center
    thickness = spec.thickness if spec.thickness is not None else recipe.material.thickness
    return col.Collider(shape, spec.friction, thickness, _keyframes(spec.animate, pivot, spec.loop))


def _attachment(collider: col.Collider) -> Motion | None:
    """How pins attached to `collider` move: with a deforming body's surface, with a rigid
    collider's keyframes, not at all with a collider that stays still."""
    if isinstance(collider, DeformingCollider):
        return SurfaceAttachment(collider.shape)
    return collider.keys


def _deforming_collider(
    spec: ColliderSpec, i: int, recipe: Recipe, rest: np.ndarray, triangles: np.ndarray, warnings: list[str]
) -> DeformingCollider:
    """A mesh collider driven by its cache (`meshdeform.io.caches`), read and checked against the
    rest mesh and the run's length here, before anything runs. A warning where the cache at the
    run's start puts the body farther from the mesh's own pose than its thickness: the cloth was
    made around that pose, so it starts inside the body or apart from it."""
    assert spec.mesh is not None and spec.mesh.cache is not None
    sim = recipe.simulation
    base = recipe.source.parent if recipe.source is not None else Path.cwd()
    try:
        cache = read_point_cache(spec.mesh.cache, base, rest.shape[0])
        timing = cache_timing(cache, sim.fps, sim.start_frame, spec.fps, spec.start_frame)
        check_cache_covers(cache, timing, sim.frames)
    except (MeshdeformError, ValueError) as exc:
        raise recipe.error(("colliders", i, "mesh", "cache"), str(exc)) from None

    def track(time: float) -> np.ndarray:
        return sample(cache, timing, time)

    thickness = spec.thickness if spec.thickness is not None else recipe.material.thickness
    offset = float(np.linalg.norm(track(0.0) - rest, axis=1).max(initial=0.0))
    if offset > thickness:
        warnings.append(
            f"colliders[{i}].mesh.cache: at the run's start the body lies up to {offset * 1000:.3g} mm from the pose "
            f"of its mesh {spec.mesh.path}, which the cloth is made around: the cloth starts inside the body or "
            "apart from it; make the cache's first frame the mesh's pose"
        )
    return DeformingCollider(DeformingMesh(rest, triangles, track), spec.friction, thickness)


def _self_collision(
    recipe: Recipe, colliders: list[col.Collider], model: SpringModel, warnings: list[str]
) -> SelfCollision | None:
    """The [self_collision] table as the scene's SelfCollision (None when absent or disabled); a
    warning when the mesh is too fine for the thickness asked (`contact_thickness`)."""
    spec = recipe.self_collision
    if spec is None or not spec.enabled:
        return None
    thickness = spec.thickness if spec.thickness is not None else recipe.material.thickness
    edge = median_edge(model)
    kept = contact_thickness(thickness, edge)
    if kept < thickness:
        warnings.append(
            f"self_collision: the thickness {thickness * 1000:g} mm is more than half the mesh's median edge "
            f"({edge * 1000:.3g} mm): its parts keep {kept * 1000:.3g} mm apart instead"
        )
    settings = SelfCollisionSettings(thickness=thickness, friction=spec.friction, sweeps=spec.sweeps)
    return SelfCollision(settings, colliders)


def _tearing(
    recipe: Recipe, res: _Resolver, mesh: Mesh, model: SpringModel, settings: Settings, warnings: list[str]
) -> Tearer | None:
    """The Tearer for [[tears]] and [[cuts]] (None when the recipe has neither)."""
    if not recipe.changes_topology:
        return None
    vmap = model.vertex_map
    n = model.vertex_count
    regions = []
    for i, tear in enumerate(recipe.tears):
        path: tuple[str | int, ...] = ("tears", i)
        selected = res.select(tear.select, (*path, "select"))
        mask = np.zeros(n, dtype=bool)
        mask[vmap[selected]] = True
        vertex_max = None
        if tear.map is not None:
            m = tear.map
            values = m.offset + m.scale * res.property(m.attribute, m.channel, (*path, "map", "attribute"))
            vertex_max = np.full(n, np.inf)
            np.minimum.at(vertex_max, vmap, values)  # the weakest input copy of a welded vertex
            if not np.any(mask & np.isfinite(vertex_max) & (vertex_max > 1.0)):
                raise recipe.error((*path, "map"), "gives no selected vertex a break stretch above 1: nothing can tear")
        try:
            regions.append(TearRegion(mask, tear.kind_stretch(), vertex_max, tear.average))
        except ValueError as exc:
            raise recipe.error(path, str(exc)) from None
    tear_settings = None
    if regions:
        interval, burst = recipe.simulation.tear_interval, recipe.simulation.tear_burst
        tear_settings = TearSettings.from_regions(
            model,
            regions,
            DEFAULT_INTERVAL if interval is None else interval,
            DEFAULT_BURST if burst is None else burst,
        )
        if not tear_settings.tearable.any():
            warnings.append("tears: every selected vertex is hard-pinned, and pinned vertices never tear")
    cuts = []
    duration = settings.frames / settings.fps
    for i, spec in enumerate(recipe.cuts):
        path = ("cuts", i)
        rel = spec.relative
        mask = None
        if spec.select is not None:
            selected = res.select(spec.select, (*path, "select"), rel)
            mask = np.zeros(n, dtype=bool)
            mask[vmap[selected]] = True
        if spec.plane is not None:
            normal = np.asarray(spec.plane.normal, dtype=np.float64)
            if rel:
                normal = normal / res.frame.scale  # planes map with the inverse transpose
            cuts.append(Cut.plane(spec.time, res.point(spec.plane.point, rel), normal, mask))
        else:
            assert spec.polyline is not None
            points = np.array([res.point(p, rel) for p in spec.polyline.points])
            direction = np.asarray(spec.polyline.direction, dtype=np.float64)
            if rel:
                direction = direction * res.frame.scale
            cuts.append(Cut.polyline(spec.time, points, direction, mask))
        if spec.time > duration:
            warnings.append(f"cuts[{i}] at {spec.time:g} s is after the last frame ({duration:g} s): it never happens")
    return Tearer(mesh, model, tear_settings, cuts)


def build_simulation(recipe: Recipe, mesh: Mesh) -> BuiltSimulation:
    """Resolve the recipe on a mesh: material, model with hard pins, forces, colliders, effects, settings."""
    sim = recipe.simulation
    options = sim.solver_options()
    if recipe.tears and isinstance(options, SweepOptions) and "tethers" not in sim.given_options():
        # the solvers' tethers tie every vertex to every pin group within its rest distance: with
        # pins moving apart they stretch the cloth at the pins without limit and yank torn pieces,
        # so a recipe that tears runs without them unless it asks for them
        options = dataclasses.replace(options, tethers=None)
    if recipe.output.subframes > 1 and recipe.changes_topology:
        raise recipe.error(("output", "subframes"), "subframes need a fixed topology: this recipe tears the mesh")
    settings = Settings(
        solver=sim.solver,
        fps=sim.fps,
        frames=sim.frames,
        substeps=sim.substeps,
        options=options,
        subframes=recipe.output.subframes,
    )
    res = _Resolver(recipe, mesh)
    material = recipe.material.to_material()
    welding, springs = build_springs(mesh)
    vmap = welding.vertex_map
    n_welded = welding.count
    warnings: list[str] = []
    if sim.iterations is not None and not solver_class(sim.solver).default_iterations:
        warnings.append(
            f"simulation.iterations: the {sim.solver} solver has no iterations (its steps are explicit), so "
            f"iterations = {sim.iterations} has no effect"
        )

    # -- colliders first: pins attach to them (they run last, see below) ---------------------------
    colliders = [_collider(c, i, recipe, res, warnings) for i, c in enumerate(recipe.colliders)]
    named = {spec.name: collider for spec, collider in zip(recipe.colliders, colliders, strict=True) if spec.name}

    # -- pins (input layout first: the hard ones go into the model) -------------------------------
    pin_sets = []
    hard_input = np.zeros(mesh.vertex_count, dtype=bool)
    for i, pin in enumerate(recipe.pins):
        mask = res.select(pin.select, ("pins", i, "select"), pin.relative)
        strength = np.full(mesh.vertex_count, pin.stiffness)
        if pin.weight is not None:
            weight = res.property(pin.weight.attribute, pin.weight.channel, ("pins", i, "weight"))
            strength = np.clip(pin.stiffness * weight, 0.0, 1.0)
        hard = mask & (strength >= 1.0)
        soft = mask & (strength > 0.0) & (strength < 1.0)
        if not (hard.any() or soft.any()):
            raise recipe.error(("pins", i, "weight"), "every selected vertex has weight 0: nothing is pinned")
        pivot = res.point(pin.pivot, pin.relative) if pin.pivot is not None else pivot_of(mesh.positions[mask])
        keys = _keyframes(pin.animate, pivot, pin.loop) if pin.attach is None else _attachment(named[pin.attach])
        pin_sets.append((hard, soft, strength, keys, pin.damping))
        hard_input |= hard

    vertex_stiffness, vertex_mass = _per_vertex_maps(recipe, res, mesh, material, welding, springs)
    model = SpringModel.from_mesh(
        mesh,
        material,
        pinned_input=hard_input if hard_input.any() else None,
        welding_and_springs=(welding, springs),
        vertex_stiffness=vertex_stiffness,
        vertex_mass=vertex_mass,
    )

    forces: list[Force] = []
    constraints: list[Constraint] = []
    hard_groups = []
    anchors = [np.flatnonzero(model.pinned)]
    for hard, soft, strength, keys, damping in pin_sets:
        if hard.any():
            hard_groups.append((np.unique(vmap[hard]), keys))
        if soft.any():
            per_welded = np.zeros(n_welded)
            np.maximum.at(per_welded, vmap[soft], strength[soft])
            idx = np.flatnonzero((per_welded > 0) & ~model.pinned)
            if idx.size:
                constraints.append(SoftPins(idx, model.rest_positions[idx], per_welded[idx], keys, damping))
                anchors.append(idx)
    pin_motion = None
    if any(keys is not None for _, keys in hard_groups):
        pin_motion = HardPinMotion(model, hard_groups)

    # -- forces -------------------------------------------------------------------------------------
    if recipe.wind is not None:
        w = recipe.wind
        forces.append(
            Wind(
                w.velocity,
                drag=w.drag,
                lift=w.lift,
                air_density=w.air_density,
                turbulence=w.turbulence,
                turbulence_scale=w.turbulence_scale,
                turbulence_frequency=w.turbulence_frequency,
                air_damping=w.air_damping,
                seed=sim.seed,
            )
        )
    for i, imp in enumerate(recipe.impacts):
        rel = imp.relative
        mask = None
        if imp.select is not None:
            selected = res.select(imp.select, ("impacts", i, "select"), rel)
            mask = np.zeros(n_welded, dtype=bool)
            mask[vmap[selected]] = True
        ray = None
        fallback = None
        point = None
        if imp.ray is not None:
            origin = res.point(imp.ray.origin, rel)
            hit = ray_hit(model.rest_positions, model.triangles, origin, imp.ray.direction)
            if hit is None:
                raise recipe.error(("impacts", i, "ray"), f"the ray misses {res.mesh_name}")
            ray = (origin, imp.ray.direction)
            fallback = hit[0]
        else:
            assert imp.point is not None
            point = res.point(imp.point, rel)
        forces.append(
            Impact(
                time=imp.time,
                radius=res.length(imp.radius, rel),
                strength=imp.strength,
                duration=imp.duration,
                point=point,
                ray=ray,
                direction=imp.direction,
                falloff=imp.falloff,
                every=imp.every,
                count=imp.count,
                mask=mask,
                fallback_point=fallback,
            )
        )

    # -- material effects ----------------------------------------------------------------------------
    spec = recipe.material
    if spec.pressure is not None:
        open_edges = boundary_edge_count(model.triangles)
        if model.triangles.shape[0] == 0 or open_edges:
            raise recipe.error(
                ("material", "pressure"),
                f"pressure needs a closed mesh; {res.mesh_name} has {open_edges} boundary edges",
            )
        forces.append(Pressure(model, spec.pressure.stiffness, spec.pressure.volume))
    if spec.plasticity is not None:
        p = spec.plasticity
        plastic = Plasticity(model, p.stiffness, res.length(p.yield_, p.relative), p.rate, p.damping)
        forces.append(plastic)
        constraints.append(plastic)
    if spec.tethers is not None:
        anchor_idx = np.unique(np.concatenate(anchors))
        if anchor_idx.size == 0:
            raise recipe.error(("material", "tethers"), "tethers need pins to attach to; the recipe pins nothing")
        constraints.append(NearestPinTethers(model, anchor_idx, spec.tethers.max_stretch))

    # -- colliders last, so nothing is left inside one after a substep --------------------------------
    constraints.extend(colliders)

    gravity = sim.gravity if sim.gravity is not None else gravity_vector(sim.up)
    scene = Scene(
        gravity=gravity,
        forces=forces,
        constraints=constraints,
        pin_motion=pin_motion,
        initial_velocity=sim.initial_velocity,
    )
    scene.self_collision = _self_collision(recipe, colliders, model, warnings)
    scene.tearing = _tearing(recipe, res, mesh, model, settings, warnings)
    return BuiltSimulation(
        model=model,
        scene=scene,
        settings=steps_for(settings, scene, model),
        selections=dict(res.counts),
        warnings=tuple(warnings),
        start_frame=sim.start_frame,
        up_axis=recipe.up_axis,
    )
