"""The recipe's sections as pydantic models: [simulation], [material], [[pins]], [[impacts]],
[wind], [[colliders]], [[tears]], [[cuts]], [output] and [[assets]] (docs/recipes.md).

Each model validates one TOML table: unknown keys, wrong types and out-of-range values are
errors (the words of each message: `pipeline.recipe.messages`). `Recipe` (document.py) holds
one of each.
"""

from __future__ import annotations

import copy
import dataclasses
import fnmatch
import json
from collections.abc import Mapping
from pathlib import PurePosixPath
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictBool,
    StrictInt,
    StrictStr,
    field_validator,
    model_validator,
)

from meshdeform.export import EXPORTERS
from meshdeform.export.usd import DEFAULT_UV_SET, LAYERS, UV_SET_PATTERN
from meshdeform.material import KindMaterial, Material
from meshdeform.scene.forces import AIR_DENSITY
from meshdeform.scene.pins import Keyframe
from meshdeform.solvers import SOLVERS, solver_class
from meshdeform.solvers.options import SolverOptions
from meshdeform.solvers.registry import DEFAULT_SOLVER
from pipeline.recipe.limits import bounded, limited
from pipeline.recipe.messages import close_match, show, toml_type
from pipeline.recipe.selection import PlaneSpec, SelectSpec, SphereSpec
from pipeline.recipe.solver_options import options_class
from pipeline.recipe.values import Direction3, Float, Scale3, Table, Vec3, is_number, nonzero_vec3, one_of

if TYPE_CHECKING:
    from meshdeform.simulate import Settings


# ---------------------------------------------------------------------------------------------
# [simulation]
# ---------------------------------------------------------------------------------------------


class SimulationSpec(Table):
    """[simulation]: the keys every solver takes.

    Each solver's own options are in a table named after it, `[simulation.<solver>]` (for example
    `[simulation.xpbd] tethers = 1.05`), whose keys are the fields of that solver's options class
    (meshdeform/solvers/options.py: `XPBDOptions`, `AnchorOptions`, ...). `solver_options.py` reads
    those tables before this model validates the rest; the options given are kept here, by solver.
    """

    solver: StrictStr = DEFAULT_SOLVER
    fps: Annotated[Float, limited("simulation.fps")] = Field(24.0, gt=0)
    frames: Annotated[StrictInt, limited("simulation.frames")] = Field(120, ge=1)
    substeps: Annotated[StrictInt, limited("simulation.substeps")] | None = Field(None, ge=1)
    iterations: Annotated[StrictInt, limited("simulation.iterations")] | None = Field(None, ge=1)
    damping: Float | None = Field(None, ge=0, lt=1)
    gravity: Vec3 | None = None
    initial_velocity: Vec3 | None = None
    up: Literal["y", "z"] = "y"
    seed: StrictInt = Field(0, ge=0)
    start_frame: Annotated[StrictInt, limited("simulation.start_frame")] = Field(1, ge=0)
    tear_interval: Float | None = Field(None, ge=0)
    tear_burst: Annotated[StrictInt, limited("simulation.tear_burst")] | None = Field(None, ge=1)

    #: solver -> {option: value} of its [simulation.<solver>] table (validated, the keys given);
    #: set by `pipeline.recipe.load.validate`
    _options: dict[str, dict[str, Any]] = PrivateAttr(default_factory=dict)

    @field_validator("solver")
    @classmethod
    def _known_solver(cls, value: str) -> str:
        names = tuple(sorted(SOLVERS))
        if value not in names:
            raise ValueError(f"unknown solver {value!r}{close_match(value, names)}; choose one of: {', '.join(names)}")
        return value

    @property
    def duration(self) -> float:
        return self.frames / self.fps

    def given_options(self, solver: str | None = None) -> dict[str, Any]:
        """The options `[simulation.<solver>]` gives (the solver in force by default), validated."""
        return dict(self._options.get(self.solver if solver is None else solver, {}))

    def solver_options(self) -> SolverOptions:
        """The options object of the solver in force: its table, with [simulation]'s iterations and
        damping; what neither gives takes the options class's defaults."""
        shared = {k: v for k, v in (("iterations", self.iterations), ("damping", self.damping)) if v is not None}
        return options_class(self.solver)(**shared, **self.given_options())

    def sweeps_per_frame(self, settings: Settings | None = None) -> tuple[int, int]:
        """(substeps, iterations) per frame in force: as given, else the solver's defaults, or those
        of the resolved `settings` of a built scene (its calm steps: `meshdeform.simulate.steps_for`);
        iterations is 1 for solvers without constraint sweeps (springs, anchor)."""
        cls = solver_class(self.solver)
        if settings is not None:
            substeps, iterations = int(settings.substeps), int(settings.iterations)
        else:
            substeps = self.substeps if self.substeps is not None else int(cls.default_substeps)
            iterations = self.iterations if self.iterations is not None else int(cls.default_iterations)
        return (substeps, 1) if int(cls.default_iterations) == 0 else (substeps, iterations)


# ---------------------------------------------------------------------------------------------
# [material]
# ---------------------------------------------------------------------------------------------

_DEFAULT_MATERIAL = Material()
#: a fraction of a spring kind's full strength or damping
Fraction = Annotated[Float, Field(ge=0, le=1)]


class KindSpec(Table):
    """One kind of spring (`[material.structural]`, `.shear`, `.bending`); the subclasses give each
    kind its defaults (`meshdeform.material.Material`)."""

    stiffness: Fraction
    compression: Fraction | None = None
    damping: Fraction
    enabled: StrictBool = True

    def to_material(self) -> KindMaterial:
        return KindMaterial(self.stiffness, self.compression, self.damping, self.enabled)


class StructuralSpec(KindSpec):
    stiffness: Fraction = _DEFAULT_MATERIAL.structural.stiffness
    damping: Fraction = _DEFAULT_MATERIAL.structural.damping


class ShearSpec(KindSpec):
    stiffness: Fraction = _DEFAULT_MATERIAL.shear.stiffness
    damping: Fraction = _DEFAULT_MATERIAL.shear.damping


class BendingSpec(KindSpec):
    stiffness: Fraction = _DEFAULT_MATERIAL.bending.stiffness
    damping: Fraction = _DEFAULT_MATERIAL.bending.damping


class PropertyMap(Table):
    """A per-vertex value from a mesh property: offset + scale * property[channel]."""

    attribute: StrictStr
    channel: StrictInt | None = Field(None, ge=0)
    scale: Float = 1.0
    offset: Float = 0.0


def _property_map(value: Any) -> Any:
    return {"attribute": value} if isinstance(value, str) else value


class RegionSpec(Table):
    select: SelectSpec
    stiffness: Float | None = Field(None, ge=0)
    mass: Float | None = Field(None, gt=0)
    mass_scale: Float | None = Field(None, gt=0)

    @model_validator(mode="after")
    def _something(self) -> RegionSpec:
        if self.stiffness is None and self.mass is None and self.mass_scale is None:
            raise ValueError("a material region needs at least one of stiffness, mass, mass_scale")
        if self.mass is not None and self.mass_scale is not None:
            raise ValueError("give either mass or mass_scale, not both")
        return self


class PressureSpec(Table):
    stiffness: Float = Field(50.0, gt=0)
    volume: Float = Field(1.0, gt=0)


class PlasticitySpec(Table):
    yield_: Float = Field(0.02, ge=0, alias="yield")
    rate: Float = Field(5.0, ge=0)
    stiffness: Float = Field(100.0, gt=0)
    damping: Float = Field(2.0, ge=0)
    relative: StrictBool = False


class TetherSpec(Table):
    max_stretch: Float = Field(1.05, ge=1)


class MaterialSpec(Table):
    structural: StructuralSpec = Field(default_factory=StructuralSpec)
    shear: ShearSpec = Field(default_factory=ShearSpec)
    bending: BendingSpec = Field(default_factory=BendingSpec)
    density: Float = Field(_DEFAULT_MATERIAL.density, gt=0)
    vertex_mass: Float | None = Field(None, gt=0)
    stretch_modulus: Float = Field(_DEFAULT_MATERIAL.stretch_modulus, gt=0)
    stiffness_map: Annotated[PropertyMap | None, BeforeValidator(_property_map)] = None
    mass_map: Annotated[PropertyMap | None, BeforeValidator(_property_map)] = None
    regions: tuple[RegionSpec, ...] = ()
    pressure: PressureSpec | None = None
    plasticity: PlasticitySpec | None = None
    tethers: TetherSpec | None = None
    #: m: the cloth's own thickness, kept from colliders and (with [self_collision]) between its own parts
    thickness: Float = Field(0.005, gt=0)

    def to_material(self) -> Material:
        return Material(
            structural=self.structural.to_material(),
            shear=self.shear.to_material(),
            bending=self.bending.to_material(),
            density=self.density,
            vertex_mass=self.vertex_mass,
            stretch_modulus=self.stretch_modulus,
        )


# ---------------------------------------------------------------------------------------------
# [[pins]] and keyframes
# ---------------------------------------------------------------------------------------------


class KeySpec(Table):
    """One keyframe: time plus any of translate, rotate (Euler XYZ degrees), scale."""

    time: Float = Field(ge=0)
    translate: Vec3 | None = None
    rotate: Vec3 | None = None
    scale: Scale3 | None = None

    def to_keyframe(self) -> Keyframe:
        return Keyframe(self.time, self.translate, self.rotate, self.scale)


def _check_keys(keys: tuple[KeySpec, ...]) -> tuple[KeySpec, ...]:
    for i in range(1, len(keys)):
        if keys[i].time <= keys[i - 1].time:
            raise ValueError(f"keyframe times must increase: key {i} has time {keys[i].time} after {keys[i - 1].time}")
    return keys


class WeightSpec(Table):
    attribute: StrictStr
    channel: StrictInt | None = Field(None, ge=0)


class PinSpec(Table):
    select: SelectSpec
    stiffness: Float = Field(1.0, gt=0, le=1)
    weight: Annotated[WeightSpec | None, BeforeValidator(_property_map)] = None
    damping: Float = Field(0.0, ge=0, lt=1)
    animate: tuple[KeySpec, ...] = ()
    pivot: Vec3 | None = None
    loop: StrictBool = False
    relative: StrictBool = False
    #: the name of a collider the pinned vertices ride on (they follow its keyframes, or the
    #: surface points of a deforming body they were bound to at rest)
    attach: StrictStr | None = Field(None, min_length=1)

    @field_validator("animate")
    @classmethod
    def _keys_increase(cls, value: tuple[KeySpec, ...]) -> tuple[KeySpec, ...]:
        return _check_keys(value)

    @model_validator(mode="after")
    def _one_motion(self) -> PinSpec:
        if self.attach is not None and self.animate:
            raise ValueError(f"a pin attached to {self.attach!r} moves with it: animate does not apply")
        return self

    @property
    def is_hard(self) -> bool:
        return self.stiffness >= 1.0 and self.weight is None


# ---------------------------------------------------------------------------------------------
# [[impacts]] and [wind]
# ---------------------------------------------------------------------------------------------


class RaySpec(Table):
    origin: Vec3
    direction: Direction3


def _direction(value: Any) -> Any:
    if isinstance(value, str):
        if value not in ("radial", "normal"):
            raise ValueError(f'direction must be "radial", "normal" or [x, y, z], got {show(value)}')
        return value
    return nonzero_vec3(value)


class ImpactSpec(Table):
    time: Float = Field(ge=0)
    point: Vec3 | None = None
    ray: RaySpec | None = None
    radius: Float = Field(gt=0)
    strength: Float
    duration: Float = Field(0.05, gt=0)
    direction: Annotated[Any, BeforeValidator(_direction)] = "radial"
    falloff: Literal["inverse_square", "smooth"] = "inverse_square"
    every: Float | None = Field(None, gt=0)
    count: Annotated[StrictInt, limited("impacts[].count")] | None = Field(None, ge=1)
    select: SelectSpec | None = None
    relative: StrictBool = False

    @model_validator(mode="after")
    def _consistent(self) -> ImpactSpec:
        one_of((("point", self.point), ("ray", self.ray)), "an impact")
        if self.every is not None and self.every < self.duration:
            raise ValueError(f"every ({self.every} s) must not be shorter than duration ({self.duration} s)")
        if self.count is not None and self.every is None:
            raise ValueError("count needs every (the repeat interval)")
        return self


class WindSpec(Table):
    velocity: Vec3 = (0.0, 0.0, 0.0)
    turbulence: Annotated[Float, limited("wind.turbulence")] = Field(0.0, ge=0)
    turbulence_scale: Float = Field(1.0, gt=0)
    turbulence_frequency: Float = Field(0.5, ge=0)
    drag: Float = Field(1.0, ge=0)
    lift: Float = Field(0.3, ge=0)
    air_density: Float = Field(AIR_DENSITY, gt=0)
    air_damping: Float = Field(0.0, ge=0)

    @model_validator(mode="after")
    def _gusts_need_wind(self) -> WindSpec:
        if self.turbulence > 0 and self.velocity == (0.0, 0.0, 0.0):
            raise ValueError("turbulence is a fraction of the wind speed: it needs a non-zero velocity")
        return self


# ---------------------------------------------------------------------------------------------
# [[colliders]]
# ---------------------------------------------------------------------------------------------


class GroundSpec(Table):
    height: Float = 0.0


class CapsuleSpec(Table):
    a: Vec3
    b: Vec3
    radius: Float = Field(gt=0)


class ColliderBoxSpec(Table):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> ColliderBoxSpec:
        if any(a >= b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {show(list(self.min))} must be below max {show(list(self.max))} on every axis")
        return self


class MeshColliderSpec(Table):
    """`mesh = "body.obj"` or `mesh = { path = "body.obj", cache = "body.pc2" }`: a triangle mesh
    collider, deforming when `cache` names its animation (`meshdeform.io.caches`: a .pc2, .mdd,
    .usd/.usdc/.usda file or a glob of per-frame .obj/.ply files, relative to the recipe's folder)."""

    path: StrictStr
    cache: StrictStr | None = None


def _mesh_path(value: Any) -> Any:
    return {"path": value} if isinstance(value, str) else value


class ColliderSpec(Table):
    #: what pins attach to (`attach = "<name>"`); unique among the recipe's colliders
    name: StrictStr | None = Field(None, min_length=1)
    ground: GroundSpec | None = None
    plane: PlaneSpec | None = None
    sphere: SphereSpec | None = None
    box: ColliderBoxSpec | None = None
    capsule: CapsuleSpec | None = None
    mesh: Annotated[MeshColliderSpec | None, BeforeValidator(_mesh_path)] = None
    friction: Float = Field(0.2, ge=0)
    #: m kept between the collider and the cloth's surface; None: the cloth's [material] thickness
    thickness: Float | None = Field(None, ge=0)
    relative: StrictBool = False
    animate: tuple[KeySpec, ...] = ()
    pivot: Vec3 | None = None
    loop: StrictBool = False
    #: a mesh cache's frame rate and first frame, when they differ from what its file says (or,
    #: when the file says nothing, from the simulation's)
    fps: Float | None = Field(None, gt=0)
    start_frame: Float | None = None

    @field_validator("animate")
    @classmethod
    def _keys_increase(cls, value: tuple[KeySpec, ...]) -> tuple[KeySpec, ...]:
        return _check_keys(value)

    @property
    def cache(self) -> str | None:
        """The mesh collider's animation cache, None for any other collider."""
        return self.mesh.cache if self.mesh is not None else None

    def _shapes(self) -> tuple[tuple[str, object], ...]:
        return (
            ("ground", self.ground),
            ("plane", self.plane),
            ("sphere", self.sphere),
            ("box", self.box),
            ("capsule", self.capsule),
            ("mesh", self.mesh),
        )

    @property
    def kind(self) -> str:
        """The shape key given: ground, plane, sphere, box, capsule or mesh."""
        return next(name for name, value in self._shapes() if value is not None)

    @model_validator(mode="after")
    def _consistent(self) -> ColliderSpec:
        kind = one_of(self._shapes(), "a collider")
        if self.relative and kind == "mesh":
            raise ValueError("relative does not apply to mesh colliders (their file gives the coordinates)")
        for i, key in enumerate(self.animate):
            if key.scale is not None and len(set(key.scale)) != 1:
                raise ValueError(f"animate[{i}].scale: colliders scale uniformly: give one number")
        if self.cache is None:
            for key, value in (("fps", self.fps), ("start_frame", self.start_frame)):
                if value is not None:
                    raise ValueError(f"{key} is the timing of a mesh cache: give mesh = {{ path = ..., cache = ... }}")
        elif self.animate:
            raise ValueError("a mesh with a cache moves by its cache: animate does not apply")
        return self


class SelfCollisionSpec(Table):
    """[self_collision]: the cloth keeps `thickness` metres between its parts (None: the cloth's
    [material] thickness) and never passes through itself; `friction` between touching parts;
    `sweeps` of the proximity step per substep; `enabled = false` keeps the table but turns it off."""

    enabled: StrictBool = True
    thickness: Float | None = Field(None, gt=0)
    friction: Float = Field(0.1, ge=0)
    sweeps: StrictInt = Field(2, ge=1, le=32)


# ---------------------------------------------------------------------------------------------
# [[tears]] and [[cuts]]
# ---------------------------------------------------------------------------------------------

SPRING_KINDS = ("structural", "shear", "bending")


class KindStretchSpec(Table):
    """Break stretch per spring kind; kinds left out never break by themselves."""

    structural: Float | None = Field(None, gt=1)
    shear: Float | None = Field(None, gt=1)
    bending: Float | None = Field(None, gt=1)

    def as_mapping(self) -> dict[str, float]:
        given = (("structural", self.structural), ("shear", self.shear), ("bending", self.bending))
        return {k: float(v) for k, v in given if v is not None}


def _stretch(value: Any) -> Any:
    """max_stretch: a number > 1 (structural springs) or a table of numbers > 1 per spring kind."""
    if is_number(value):
        if not value > 1:
            raise ValueError(f"must be greater than 1 (1 is the rest length), got {show(value)}")
        return float(bounded(value))
    if isinstance(value, dict):
        for key, v in value.items():
            if key not in SPRING_KINDS:
                hint = close_match(str(key), SPRING_KINDS)
                raise ValueError(f"unknown spring kind {key!r}{hint}; allowed keys: {', '.join(SPRING_KINDS)}")
            if not is_number(v):
                raise ValueError(f"{key}: expected a number, got {toml_type(v)} {show(v)}")
            if not v > 1:
                raise ValueError(f"{key}: must be greater than 1 (1 is the rest length), got {show(v)}")
            bounded(v)
        if not value:
            raise ValueError("the table needs at least one of structural, shear, bending")
        return KindStretchSpec(**{k: float(v) for k, v in value.items()})
    raise ValueError(f"expected a number or a table {{ structural = ..., shear = ... }}, got {show(value)}")


class TearSpec(Table):
    """[[tears]]: where the cloth may tear and at what stretch (see meshdeform.tearing)."""

    select: SelectSpec | None = None
    max_stretch: Annotated[Float | KindStretchSpec | None, BeforeValidator(_stretch)] = None
    map: Annotated[PropertyMap | None, BeforeValidator(_property_map)] = None
    average: StrictInt = Field(1, ge=1, le=64)

    @model_validator(mode="after")
    def _threshold_given(self) -> TearSpec:
        if self.max_stretch is None and self.map is None:
            raise ValueError("a tear needs max_stretch (a number or a per-kind table) or a map")
        return self

    def kind_stretch(self) -> float | dict[str, float] | None:
        """max_stretch for the engine: a number (structural) or {kind: ratio}."""
        if isinstance(self.max_stretch, KindStretchSpec):
            return self.max_stretch.as_mapping()
        return self.max_stretch


class CutPlaneSpec(Table):
    point: Vec3
    normal: Direction3


class CutPolylineSpec(Table):
    points: tuple[Vec3, ...] = Field(min_length=2)
    direction: Direction3


class CutSpec(Table):
    """[[cuts]]: a scripted cut at a time along a plane or a polyline swept along a direction."""

    time: Float = Field(ge=0)
    plane: CutPlaneSpec | None = None
    polyline: CutPolylineSpec | None = None
    select: SelectSpec | None = None
    relative: StrictBool = False

    @model_validator(mode="after")
    def _one_shape(self) -> CutSpec:
        one_of((("plane", self.plane), ("polyline", self.polyline)), "a cut")
        return self


# ---------------------------------------------------------------------------------------------
# [output]
# ---------------------------------------------------------------------------------------------


class PreviewSpec(BaseModel):
    """Known preview keys are type-checked; others pass through to the previewer, which checks them."""

    model_config = ConfigDict(extra="allow", frozen=True)

    every: Annotated[StrictInt, limited("output.preview.every")] | None = Field(None, ge=1)
    video: StrictStr | None = None
    color: StrictStr | None = None
    sheet_tile_width: Annotated[StrictInt, limited("output.preview.sheet_tile_width")] | None = Field(None, ge=16)
    sheet_columns: Annotated[StrictInt, limited("output.preview.sheet_columns")] | None = Field(None, ge=1)


def _preview(value: Any) -> Any:
    if value is False:
        return None
    if value is True:
        return {}
    return value


def _formats(value: Any) -> Any:
    if isinstance(value, str):
        example = f"formats = [{json.dumps(value)}]"
        raise ValueError(f"expected an array of format names, e.g. {example}, got string {show(value)}")
    return value


class UsdOutputSpec(Table):
    """[output.usd]: the USD exporter's options (`meshdeform.export.usd.UsdExporter`, docs/recipes.md "USD")."""

    #: "single": one scene.usdc; "split": rest.usdc (the rest asset), animation.usdc (its time samples,
    #: over rest.usdc) and scene.usdc (the stage to open, over animation.usdc)
    layers: StrictStr = "single"
    #: the UV primvar's name: "st" (USD's convention) or, say, "UVMap" (Blender's name for an OBJ's UVs)
    uv_set: StrictStr = DEFAULT_UV_SET
    #: text layers (.usda) instead of crate (.usdc)
    ascii: StrictBool = False

    @field_validator("layers")
    @classmethod
    def _known_layers(cls, value: str) -> str:
        if value not in LAYERS:
            raise ValueError(f"expected one of {', '.join(map(repr, LAYERS))}, got {show(value)}")
        return value

    @field_validator("uv_set")
    @classmethod
    def _primvar_name(cls, value: str) -> str:
        if not UV_SET_PATTERN.fullmatch(value):
            raise ValueError(
                f"expected a name of ASCII letters, digits and '_' not starting with a digit, got {show(value)}"
            )
        return value


class OutputSpec(Table):
    """[output]: `formats` are names of the export registry (`meshdeform.export.EXPORTERS`)."""

    formats: Annotated[tuple[StrictStr, ...], BeforeValidator(_formats)] = ("obj",)
    preview: Annotated[PreviewSpec | None, BeforeValidator(_preview)] = None
    up_axis: Literal["y", "z"] | None = None
    #: the scene frames written, first and last included (None: the rest pose at
    #: [simulation] start_frame and every simulated frame after it)
    frames: tuple[StrictInt, StrictInt] | None = None
    #: time samples per frame in USD (motion blur): the frame and the states between it and the
    #: one before; the other formats write whole frames
    subframes: StrictInt = Field(1, ge=1, le=16)
    #: [output.usd]: the USD exporter's options (None: its defaults; left out of `recipe_hash` then)
    usd: UsdOutputSpec | None = None

    @field_validator("frames")
    @classmethod
    def _ordered_frames(cls, value: tuple[int, int] | None) -> tuple[int, int] | None:
        if value is not None and value[0] > value[1]:
            raise ValueError(f"frames = [{value[0]}, {value[1]}]: the first frame comes after the last")
        return value

    @field_validator("formats")
    @classmethod
    def _known_formats(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for name in value:
            if name not in EXPORTERS:
                hint = close_match(name, tuple(EXPORTERS))
                raise ValueError(f"unknown format {name!r}{hint}; choose from: {', '.join(EXPORTERS)}")
        if len(set(value)) != len(value):
            raise ValueError("a format is listed twice")
        return value

    @property
    def exporter_options(self) -> dict[str, dict[str, Any]]:
        """format -> keyword options for its exporter (`make_exporter`), for the formats with a table here."""
        return {} if self.usd is None else {"usd": self.usd.model_dump()}

    @property
    def preview_options(self) -> dict[str, Any] | None:
        """The preview table as given (None when there is no preview)."""
        if self.preview is None:
            return None
        return self.preview.model_dump(exclude_none=True)


# ---------------------------------------------------------------------------------------------
# [[assets]]
# ---------------------------------------------------------------------------------------------


class AssetRuleSpec(Table):
    glob: StrictStr
    simulation: dict[str, Any] | None = None
    material: dict[str, Any] | None = None
    pins: list[Any] | None = None
    impacts: list[Any] | None = None
    wind: dict[str, Any] | None = None
    colliders: list[Any] | None = None
    self_collision: dict[str, Any] | None = None
    tears: list[Any] | None = None
    cuts: list[Any] | None = None
    output: dict[str, Any] | None = None


@dataclasses.dataclass(frozen=True)
class AssetRule:
    """An [[assets]] rule: assets whose path matches `glob` get `override` merged into the recipe."""

    glob: str
    override: Mapping[str, Any]

    def matches(self, relative_path: str) -> bool:
        """fnmatch on the asset's path relative to the input folder ('/' separators); a pattern
        without '/' also matches the file name alone."""
        p = PurePosixPath(relative_path.replace("\\", "/"))
        return fnmatch.fnmatchcase(str(p), self.glob) or (
            "/" not in self.glob and fnmatch.fnmatchcase(p.name, self.glob)
        )


def merge_recipe_data(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge recipe data as [[assets]] rules, sidecars and overrides apply: tables merge key by
    key, arrays and scalars from `override` replace."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_recipe_data(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out
