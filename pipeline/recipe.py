"""Recipes: the scripted scene (TOML) a batch applies to every asset, parsed into a typed `Recipe`.

`load_recipe` / `parse_recipe` read TOML with `tomllib`, validate it with pydantic models
(unknown keys, wrong types and out-of-range values are errors) and raise `RecipeError` with one
line: `<file>: <key.path> (line N): <what>`. tomllib gives no positions, so `_Locator` scans the
text once for the line of every table header, key and array element. The schema is documented
in docs/recipes.md; `pipeline.build` turns a Recipe plus a mesh into a runnable simulation.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import difflib
import fnmatch
import hashlib
import json
import math
import re
import tomllib
import types
import typing
from bisect import bisect_right
from collections.abc import Mapping, Sequence
from functools import cache
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Literal, Union

from pydantic import (
    AfterValidator,
    AllowInfNan,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    Strict,
    StrictBool,
    StrictInt,
    StrictStr,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from meshdeform import selection as sel
from meshdeform.errors import MeshdeformError, RecipeError
from meshdeform.io.files import special_file_kind
from meshdeform.material import KindMaterial, Material
from meshdeform.pins import Keyframe
from meshdeform.solvers import SOLVERS, solver_class
from meshdeform.solvers.options import ANCHOR_FRAMES, AnchorOptions, XPBDOptions


@dataclasses.dataclass(frozen=True)
class SolverOptions(XPBDOptions, AnchorOptions):
    """Transitional: every solver's options in the flat [simulation] table, until the recipe reads
    per-solver tables; `build_simulation` hands the solver its own `options_class`."""


__all__ = [
    "KNOWN_FORMATS",
    "LIMITS",
    "AssetRule",
    "Limit",
    "Recipe",
    "apply_overrides",
    "format_path",
    "load_recipe",
    "merge_recipe_data",
    "parse_recipe",
    "recipe_from_data",
    "recipe_hash",
]

#: solvers of DESIGN.md section 3; the registry may hold more (and must hold the one used to run)
DESIGN_SOLVERS = ("anchor", "verlet", "xpbd", "springs", "implicit")
#: output formats the exporters provide (meshdeform/export)
KNOWN_FORMATS = ("obj", "ply", "pc2", "mdd", "usd", "vtk", "xdmf", "npz")
SECTIONS = ("simulation", "material", "pins", "impacts", "wind", "colliders", "tears", "cuts", "output", "assets")
#: formats that need a fixed vertex count: refused when the recipe tears or cuts
POINT_CACHE_FORMATS = ("pc2", "mdd", "xdmf", "npz")

Path_ = tuple[str | int, ...]


def known_solvers() -> tuple[str, ...]:
    import meshdeform.solvers  # noqa: F401  (registers the built-in solvers)

    return tuple(sorted(set(DESIGN_SOLVERS) | set(SOLVERS)))


# ---------------------------------------------------------------------------------------------
# limits: bounds a real production never meets but a typo does (docs/recipes.md, "Limits")
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Limit:
    """A bound on a recipe value that stops runaway work: `minimum <= value <= maximum`, in `unit`."""

    maximum: float
    unit: str
    minimum: float | None = None

    def complaint(self, value: float) -> str | None:
        """The one-line complaint about `value`, or None when it is within the limit."""
        if value > self.maximum:
            return f"{_number(value)} is above the limit of {_number(self.maximum)} {self.unit}"
        if self.minimum is not None and value < self.minimum:
            return f"{_number(value)} is below the limit of {_number(self.minimum)} {self.unit}"
        return None


#: every limit, by the key path it applies to (`[]`: any element of an array of tables); the list in
#: docs/recipes.md gives the reason for each value
LIMITS: dict[str, Limit] = {
    "simulation.frames": Limit(1_000_000, "frames"),
    "simulation.substeps": Limit(100_000, "substeps per frame"),
    "simulation.iterations": Limit(100_000, "iterations per substep"),
    "simulation.substeps x iterations": Limit(100_000, "solver sweeps per frame"),
    "simulation.fps": Limit(10_000, "frames per second", minimum=0.01),
    "simulation.start_frame": Limit(1_000_000, "(first frame number)"),
    "simulation.tear_burst": Limit(100_000, "topology updates in a burst"),
    "simulation.strain_iterations": Limit(100_000, "strain passes per step"),
    "simulation.partitions": Limit(1024, "partitions"),
    "simulation.anchor_stiffness": Limit(1e6, "1/s^2"),
    "simulation.uniform_scale": Limit(1000, "(scale factor)"),
    "impacts[].count": Limit(1_000_000, "repeats"),
    "wind.turbulence": Limit(100, "(fraction of the wind speed)"),
    "output.preview.every": Limit(1_000_000, "frames"),
    "output.preview.sheet_tile_width": Limit(8192, "pixels"),
    "output.preview.sheet_columns": Limit(1000, "columns"),
    "any number": Limit(1e12, "(largest magnitude of any number in a recipe)"),
    "any integer": Limit(2**63 - 1, "(an integer must fit in 64 bits)", minimum=-(2**63)),
    "recipe file size": Limit(2 * 2**20, "bytes"),
    "tables in one array": Limit(10_000, "tables (pins, impacts, colliders, tears, cuts, regions, asset rules)"),
}


def _number(value: float) -> str:
    """A number for a message: integers in full, floats shortest (1e+12)."""
    if isinstance(value, int) or (value.is_integer() and abs(value) < 1e7):
        return str(int(value))
    return f"{value:g}"


def _limited(key: str) -> AfterValidator:
    """A pydantic validator enforcing `LIMITS[key]` (the message names the limit and its unit)."""
    limit = LIMITS[key]

    def check(value: Any) -> Any:
        complaint = limit.complaint(value)
        if complaint is not None:
            raise ValueError(complaint)
        return value

    return AfterValidator(check)


def _bounded(value: float) -> float:
    """Any float in a recipe: at most LIMITS['any number'] in magnitude (beyond it, squares overflow)."""
    limit = LIMITS["any number"].maximum
    if abs(value) > limit:
        raise ValueError(f"{_number(value)} is beyond the limit of {_number(limit)} for any number in a recipe")
    return value


def _too_many_tables(data: Any, path: Path_ = ()) -> typing.Iterator[tuple[Path_, str]]:
    """(key path, complaint) for every array of tables (`[[impacts]]`, ...) longer than the limit: a
    generated recipe gone wrong, refused before the schema spends seconds on each of its tables."""
    limit = LIMITS["tables in one array"].maximum
    if isinstance(data, dict):
        for key, value in data.items():
            if isinstance(value, list) and len(value) > limit and all(isinstance(v, dict) for v in value):
                yield (*path, key), f"{len(value)} tables is above the limit of {_number(limit)} tables in one array"
            elif isinstance(value, dict):
                yield from _too_many_tables(value, (*path, key))


def _bad_numbers(data: Any, path: Path_ = ()) -> typing.Iterator[tuple[Path_, str]]:
    """(key path, complaint) for every value of the parsed TOML, at any depth, that no key accepts:
    non-finite floats (TOML allows `inf` and `nan`) and integers that do not fit in 64 bits."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _bad_numbers(value, (*path, key))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            yield from _bad_numbers(value, (*path, i))
    elif isinstance(data, float) and not math.isfinite(data):
        yield path, f"must be a finite number, got {show(data)}"
    elif isinstance(data, int) and not isinstance(data, bool) and LIMITS["any integer"].complaint(data) is not None:
        yield path, f"{data} does not fit in 64 bits (integers range from -2^63 to 2^63 - 1)"


# ---------------------------------------------------------------------------------------------
# value types with clear messages
# ---------------------------------------------------------------------------------------------

Float = Annotated[float, Strict(), AllowInfNan(False), AfterValidator(_bounded)]


def toml_type(value: Any) -> str:
    """The TOML name of a parsed value's type, for messages."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, list | tuple):
        return "array"
    return "date-time"


def show(value: Any) -> str:
    """A parsed value as TOML would spell it (short)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array" if len(value) > 6 else "[" + ", ".join(show(v) for v in value) + "]"
    return repr(value)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _vec3(value: Any) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple):
        raise ValueError(f"expected an array of 3 numbers, got {toml_type(value)} {show(value)}")
    if len(value) != 3:
        raise ValueError(f"expected 3 numbers [x, y, z], got {len(value)}: {show(value)}")
    for v in value:
        if not _is_number(v):
            raise ValueError(f"expected 3 numbers [x, y, z], got {toml_type(v)} {show(v)} in {show(value)}")
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"expected finite numbers, got {show(value)}")
        _bounded(v)
    return (float(value[0]), float(value[1]), float(value[2]))


def _nonzero_vec3(value: Any) -> tuple[float, float, float]:
    v = _vec3(value)
    if v == (0.0, 0.0, 0.0):
        raise ValueError("must not be the zero vector")
    return v


def _scale(value: Any) -> tuple[float, float, float]:
    if _is_number(value):
        v: tuple[float, float, float] | None = (float(_bounded(value)),) * 3
    else:
        v = _vec3(value) if isinstance(value, list | tuple) else None
    if v is None:
        raise ValueError(f"expected a number or an array of 3 numbers, got {toml_type(value)} {show(value)}")
    if min(v) <= 0:
        raise ValueError(f"scale must be positive, got {show(value)}")
    return v


Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_vec3)]
Direction3 = Annotated[tuple[float, float, float], BeforeValidator(_nonzero_vec3)]
Scale3 = Annotated[tuple[float, float, float], BeforeValidator(_scale)]


def _one_of(obj: BaseModel, names: Sequence[str], what: str) -> str:
    """The one key of `names` that is set (keys that are Python words live in `name_` attributes)."""
    given = [n for n in names if getattr(obj, f"{n}_" if n in ("any", "all", "not") else n) is not None]
    if len(given) != 1:
        listed = ", ".join(names)
        found = " and ".join(given) if given else "none"
        raise ValueError(f"{what} needs exactly one of {listed} (found {found})")
    return given[0]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=False)


# ---------------------------------------------------------------------------------------------
# selections
# ---------------------------------------------------------------------------------------------


class BoxSpec(_Model):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> BoxSpec:
        if any(a > b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {show(list(self.min))} must not exceed max {show(list(self.max))}")
        return self


class SphereSpec(_Model):
    center: Vec3
    radius: Float = Field(gt=0)


class PlaneSpec(_Model):
    point: Vec3
    normal: Direction3


class AttributeSpec(_Model):
    name: StrictStr
    channel: StrictInt | None = Field(None, ge=0)
    min: Float | None = None
    max: Float | None = None

    @model_validator(mode="after")
    def _range(self) -> AttributeSpec:
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"attribute min {self.min} must not exceed max {self.max}")
        return self


def _names(value: Any) -> Any:
    return [value] if isinstance(value, str) else value


SELECTION_KINDS = ("indices", "box", "sphere", "plane", "group", "attribute", "any", "all", "not")


class SelectSpec(_Model):
    """One selection node: exactly one kind key, plus `relative` (inherited by the parts)."""

    indices: tuple[Annotated[StrictInt, Field(ge=0)], ...] | None = Field(None, min_length=1)
    box: BoxSpec | None = None
    sphere: SphereSpec | None = None
    plane: PlaneSpec | None = None
    group: Annotated[tuple[StrictStr, ...] | None, BeforeValidator(_names)] = Field(None, min_length=1)
    attribute: AttributeSpec | None = None
    any_: tuple[SelectSpec, ...] | None = Field(None, alias="any", min_length=1)
    all_: tuple[SelectSpec, ...] | None = Field(None, alias="all", min_length=1)
    not_: SelectSpec | None = Field(None, alias="not")
    relative: StrictBool | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> SelectSpec:
        _one_of(self, SELECTION_KINDS, "a selection")
        return self

    def build(self, path: str, relative: bool = False) -> sel.Selection:
        """The engine selection tree; `path` names nodes in errors, `relative` is the inherited default."""
        rel = relative if self.relative is None else self.relative
        if self.indices is not None:
            return sel.Indices(tuple(self.indices), path=f"{path}.indices")
        if self.box is not None:
            return sel.Box(self.box.min, self.box.max, relative=rel, path=f"{path}.box")
        if self.sphere is not None:
            return sel.Sphere(self.sphere.center, self.sphere.radius, relative=rel, path=f"{path}.sphere")
        if self.plane is not None:
            return sel.HalfSpace(self.plane.point, self.plane.normal, relative=rel, path=f"{path}.plane")
        if self.group is not None:
            return sel.Group(tuple(self.group), path=f"{path}.group")
        if self.attribute is not None:
            a = self.attribute
            return sel.Attribute(a.name, a.channel, a.min, a.max, path=f"{path}.attribute")
        if self.any_ is not None:
            return sel.AnyOf(
                tuple(p.build(f"{path}.any[{i}]", rel) for i, p in enumerate(self.any_)), path=f"{path}.any"
            )
        if self.all_ is not None:
            return sel.AllOf(
                tuple(p.build(f"{path}.all[{i}]", rel) for i, p in enumerate(self.all_)), path=f"{path}.all"
            )
        assert self.not_ is not None
        return sel.Not(self.not_.build(f"{path}.not", rel), path=f"{path}.not")


# ---------------------------------------------------------------------------------------------
# sections
# ---------------------------------------------------------------------------------------------


class SimulationSpec(_Model):
    """[simulation]; solver options beyond these are added from SolverOptions at run time."""

    solver: StrictStr = "xpbd"
    fps: Annotated[Float, _limited("simulation.fps")] = Field(24.0, gt=0)
    frames: Annotated[StrictInt, _limited("simulation.frames")] = Field(120, ge=1)
    substeps: Annotated[StrictInt, _limited("simulation.substeps")] | None = Field(None, ge=1)
    iterations: Annotated[StrictInt, _limited("simulation.iterations")] | None = Field(None, ge=1)
    damping: Float | None = Field(None, ge=0, lt=1)
    gravity: Vec3 | None = None
    up: Literal["y", "z"] = "y"
    seed: StrictInt = Field(0, ge=0)
    start_frame: Annotated[StrictInt, _limited("simulation.start_frame")] = Field(1, ge=0)
    tear_interval: Float | None = Field(None, ge=0)
    tear_burst: Annotated[StrictInt, _limited("simulation.tear_burst")] | None = Field(None, ge=1)

    @field_validator("solver")
    @classmethod
    def _known_solver(cls, value: str) -> str:
        names = known_solvers()
        if value not in names:
            close = difflib.get_close_matches(value, names, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"unknown solver {value!r}{hint}; choose one of: {', '.join(names)}")
        return value

    @property
    def gravity_vector(self) -> tuple[float, float, float]:
        """The gravity in force: as given, else 9.81 m/s^2 down the `up` axis."""
        if self.gravity is not None:
            return self.gravity
        return (0.0, -9.81, 0.0) if self.up == "y" else (0.0, 0.0, -9.81)

    @property
    def duration(self) -> float:
        return self.frames / self.fps

    def option_values(self) -> dict[str, Any]:
        """Solver options given in the recipe (SolverOptions field name -> value)."""
        names = {f.name for f in dataclasses.fields(SolverOptions)}
        return {n: getattr(self, n) for n in sorted(names) if getattr(self, n, None) is not None}

    def solver_options(self) -> SolverOptions:
        return SolverOptions(**self.option_values())

    def sweeps_per_frame(self) -> tuple[int, int] | None:
        """(substeps, iterations) per frame in force: as given, else the solver's defaults; iterations
        is 1 for solvers without constraint sweeps (springs, anchor). None when the solver is not
        available in this build (building the simulation reports that)."""
        try:
            cls = solver_class(self.solver)
        except MeshdeformError:
            return None
        substeps = self.substeps if self.substeps is not None else int(cls.default_substeps)
        if int(cls.default_iterations) == 0:
            return substeps, 1
        return substeps, self.solver_options().iterations_for(cls)

    @model_validator(mode="after")
    def _options_accepted(self) -> SimulationSpec:
        try:
            self.solver_options()
        except (TypeError, ValueError) as exc:
            raise ValueError(f"invalid solver options: {exc}") from None
        return self


def _kind(default: KindMaterial) -> type[_Model]:
    class KindSpec(_Model):
        stiffness: Float = Field(default=default.stiffness, ge=0, le=1)  # type: ignore[valid-type]
        compression: Float | None = Field(None, ge=0, le=1)
        damping: Float = Field(default.damping, ge=0, le=1)
        enabled: StrictBool = True

        def to_material(self) -> KindMaterial:
            return KindMaterial(self.stiffness, self.compression, self.damping, self.enabled)

    return KindSpec


_DEFAULT_MATERIAL = Material()
StructuralSpec = _kind(_DEFAULT_MATERIAL.structural)
ShearSpec = _kind(_DEFAULT_MATERIAL.shear)
BendingSpec = _kind(_DEFAULT_MATERIAL.bending)


class PropertyMap(_Model):
    """A per-vertex value from a mesh property: offset + scale * property[channel]."""

    attribute: StrictStr
    channel: StrictInt | None = Field(None, ge=0)
    scale: Float = 1.0
    offset: Float = 0.0


def _property_map(value: Any) -> Any:
    return {"attribute": value} if isinstance(value, str) else value


class RegionSpec(_Model):
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


class PressureSpec(_Model):
    stiffness: Float = Field(50.0, gt=0)
    volume: Float = Field(1.0, gt=0)


class PlasticitySpec(_Model):
    yield_: Float = Field(0.02, ge=0, alias="yield")
    rate: Float = Field(5.0, ge=0)
    stiffness: Float = Field(100.0, gt=0)
    damping: Float = Field(2.0, ge=0)
    relative: StrictBool = False


class TetherSpec(_Model):
    max_stretch: Float = Field(1.05, ge=1)


class MaterialSpec(_Model):
    structural: StructuralSpec = Field(default_factory=StructuralSpec)  # type: ignore[valid-type]
    shear: ShearSpec = Field(default_factory=ShearSpec)  # type: ignore[valid-type]
    bending: BendingSpec = Field(default_factory=BendingSpec)  # type: ignore[valid-type]
    density: Float = Field(_DEFAULT_MATERIAL.density, gt=0)
    vertex_mass: Float | None = Field(None, gt=0)
    stretch_modulus: Float = Field(_DEFAULT_MATERIAL.stretch_modulus, gt=0)
    stiffness_map: Annotated[PropertyMap | None, BeforeValidator(_property_map)] = None
    mass_map: Annotated[PropertyMap | None, BeforeValidator(_property_map)] = None
    regions: tuple[RegionSpec, ...] = ()
    pressure: PressureSpec | None = None
    plasticity: PlasticitySpec | None = None
    tethers: TetherSpec | None = None

    def to_material(self) -> Material:
        return Material(
            structural=self.structural.to_material(),  # type: ignore[attr-defined]
            shear=self.shear.to_material(),  # type: ignore[attr-defined]
            bending=self.bending.to_material(),  # type: ignore[attr-defined]
            density=self.density,
            vertex_mass=self.vertex_mass,
            stretch_modulus=self.stretch_modulus,
        )


class KeySpec(_Model):
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


class WeightSpec(_Model):
    attribute: StrictStr
    channel: StrictInt | None = Field(None, ge=0)


class PinSpec(_Model):
    select: SelectSpec
    stiffness: Float = Field(1.0, gt=0, le=1)
    weight: Annotated[WeightSpec | None, BeforeValidator(_property_map)] = None
    damping: Float = Field(0.0, ge=0, lt=1)
    animate: tuple[KeySpec, ...] = ()
    pivot: Vec3 | None = None
    loop: StrictBool = False
    relative: StrictBool = False

    @field_validator("animate")
    @classmethod
    def _keys_increase(cls, value: tuple[KeySpec, ...]) -> tuple[KeySpec, ...]:
        return _check_keys(value)

    @property
    def is_hard(self) -> bool:
        return self.stiffness >= 1.0 and self.weight is None


class RaySpec(_Model):
    origin: Vec3
    direction: Direction3


def _direction(value: Any) -> Any:
    if isinstance(value, str):
        if value not in ("radial", "normal"):
            raise ValueError(f'direction must be "radial", "normal" or [x, y, z], got {show(value)}')
        return value
    return _nonzero_vec3(value)


class ImpactSpec(_Model):
    time: Float = Field(ge=0)
    point: Vec3 | None = None
    ray: RaySpec | None = None
    radius: Float = Field(gt=0)
    strength: Float
    duration: Float = Field(0.05, gt=0)
    direction: Annotated[Any, BeforeValidator(_direction)] = "radial"
    falloff: Literal["inverse_square", "smooth"] = "inverse_square"
    every: Float | None = Field(None, gt=0)
    count: Annotated[StrictInt, _limited("impacts[].count")] | None = Field(None, ge=1)
    select: SelectSpec | None = None
    relative: StrictBool = False

    @model_validator(mode="after")
    def _consistent(self) -> ImpactSpec:
        _one_of(self, ("point", "ray"), "an impact")
        if self.every is not None and self.every < self.duration:
            raise ValueError(f"every ({self.every} s) must not be shorter than duration ({self.duration} s)")
        if self.count is not None and self.every is None:
            raise ValueError("count needs every (the repeat interval)")
        return self


class WindSpec(_Model):
    velocity: Vec3 = (0.0, 0.0, 0.0)
    turbulence: Annotated[Float, _limited("wind.turbulence")] = Field(0.0, ge=0)
    turbulence_scale: Float = Field(1.0, gt=0)
    turbulence_frequency: Float = Field(0.5, ge=0)
    drag: Float = Field(1.0, ge=0)
    lift: Float = Field(0.3, ge=0)
    air_density: Float = Field(1.2, gt=0)
    air_damping: Float = Field(0.0, ge=0)

    @model_validator(mode="after")
    def _gusts_need_wind(self) -> WindSpec:
        if self.turbulence > 0 and self.velocity == (0.0, 0.0, 0.0):
            raise ValueError("turbulence is a fraction of the wind speed: it needs a non-zero velocity")
        return self


class GroundSpec(_Model):
    height: Float = 0.0


class CapsuleSpec(_Model):
    a: Vec3
    b: Vec3
    radius: Float = Field(gt=0)


class ColliderBoxSpec(_Model):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> ColliderBoxSpec:
        if any(a >= b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {show(list(self.min))} must be below max {show(list(self.max))} on every axis")
        return self


class MeshColliderSpec(_Model):
    path: StrictStr


def _mesh_path(value: Any) -> Any:
    return {"path": value} if isinstance(value, str) else value


COLLIDER_KINDS = ("ground", "plane", "sphere", "box", "capsule", "mesh")


class ColliderSpec(_Model):
    ground: GroundSpec | None = None
    plane: PlaneSpec | None = None
    sphere: SphereSpec | None = None
    box: ColliderBoxSpec | None = None
    capsule: CapsuleSpec | None = None
    mesh: Annotated[MeshColliderSpec | None, BeforeValidator(_mesh_path)] = None
    friction: Float = Field(0.2, ge=0)
    thickness: Float = Field(0.01, ge=0)
    relative: StrictBool = False
    animate: tuple[KeySpec, ...] = ()
    pivot: Vec3 | None = None
    loop: StrictBool = False

    @field_validator("animate")
    @classmethod
    def _keys_increase(cls, value: tuple[KeySpec, ...]) -> tuple[KeySpec, ...]:
        return _check_keys(value)

    @property
    def kind(self) -> str:
        return next(k for k in COLLIDER_KINDS if getattr(self, k) is not None)

    @model_validator(mode="after")
    def _consistent(self) -> ColliderSpec:
        kind = _one_of(self, COLLIDER_KINDS, "a collider")
        if self.relative and kind == "mesh":
            raise ValueError("relative does not apply to mesh colliders (their file gives the coordinates)")
        for i, key in enumerate(self.animate):
            if key.scale is not None and len(set(key.scale)) != 1:
                raise ValueError(f"animate[{i}].scale: colliders scale uniformly: give one number")
        return self


SPRING_KINDS = ("structural", "shear", "bending")


class KindStretchSpec(_Model):
    """Break stretch per spring kind; kinds left out never break by themselves."""

    structural: Float | None = Field(None, gt=1)
    shear: Float | None = Field(None, gt=1)
    bending: Float | None = Field(None, gt=1)

    def as_mapping(self) -> dict[str, float]:
        return {k: float(v) for k in SPRING_KINDS if (v := getattr(self, k)) is not None}


def _stretch(value: Any) -> Any:
    """max_stretch: a number > 1 (structural springs) or a table of numbers > 1 per spring kind."""
    if _is_number(value):
        if not value > 1:
            raise ValueError(f"must be greater than 1 (1 is the rest length), got {show(value)}")
        return float(_bounded(value))
    if isinstance(value, dict):
        for key, v in value.items():
            if key not in SPRING_KINDS:
                close = difflib.get_close_matches(str(key), SPRING_KINDS, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ValueError(f"unknown spring kind {key!r}{hint}; allowed keys: {', '.join(SPRING_KINDS)}")
            if not _is_number(v):
                raise ValueError(f"{key}: expected a number, got {toml_type(v)} {show(v)}")
            if not v > 1:
                raise ValueError(f"{key}: must be greater than 1 (1 is the rest length), got {show(v)}")
            _bounded(v)
        if not value:
            raise ValueError("the table needs at least one of structural, shear, bending")
        return KindStretchSpec(**{k: float(v) for k, v in value.items()})
    raise ValueError(f"expected a number or a table {{ structural = ..., shear = ... }}, got {show(value)}")


class TearSpec(_Model):
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


class CutPlaneSpec(_Model):
    point: Vec3
    normal: Direction3


class CutPolylineSpec(_Model):
    points: tuple[Vec3, ...] = Field(min_length=2)
    direction: Direction3


class CutSpec(_Model):
    """[[cuts]]: a scripted cut at a time along a plane or a polyline swept along a direction."""

    time: Float = Field(ge=0)
    plane: CutPlaneSpec | None = None
    polyline: CutPolylineSpec | None = None
    select: SelectSpec | None = None
    relative: StrictBool = False

    @model_validator(mode="after")
    def _one_shape(self) -> CutSpec:
        _one_of(self, ("plane", "polyline"), "a cut")
        return self


class PreviewSpec(BaseModel):
    """Known preview keys are type-checked; others pass through to the previewer, which checks them."""

    model_config = ConfigDict(extra="allow", frozen=True)

    every: Annotated[StrictInt, _limited("output.preview.every")] | None = Field(None, ge=1)
    video: StrictStr | None = None
    color: StrictStr | None = None
    sheet_tile_width: Annotated[StrictInt, _limited("output.preview.sheet_tile_width")] | None = Field(None, ge=16)
    sheet_columns: Annotated[StrictInt, _limited("output.preview.sheet_columns")] | None = Field(None, ge=1)


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


class OutputSpec(_Model):
    formats: Annotated[tuple[StrictStr, ...], BeforeValidator(_formats)] = ("obj",)
    preview: Annotated[PreviewSpec | None, BeforeValidator(_preview)] = None
    up_axis: Literal["y", "z"] | None = None

    @field_validator("formats")
    @classmethod
    def _known_formats(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for name in value:
            if name not in KNOWN_FORMATS:
                close = difflib.get_close_matches(name, KNOWN_FORMATS, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ValueError(f"unknown format {name!r}{hint}; choose from: {', '.join(KNOWN_FORMATS)}")
        if len(set(value)) != len(value):
            raise ValueError("a format is listed twice")
        return value

    @property
    def preview_options(self) -> dict[str, Any] | None:
        """The preview table as given (None when there is no preview)."""
        if self.preview is None:
            return None
        return self.preview.model_dump(exclude_none=True)


class AssetRuleSpec(_Model):
    glob: StrictStr
    simulation: dict[str, Any] | None = None
    material: dict[str, Any] | None = None
    pins: list[Any] | None = None
    impacts: list[Any] | None = None
    wind: dict[str, Any] | None = None
    colliders: list[Any] | None = None
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


class Recipe(_Model):
    """A validated recipe. Sections are immutable pydantic models; `source` is the file it came from."""

    simulation: SimulationSpec = Field(default_factory=SimulationSpec)
    material: MaterialSpec = Field(default_factory=MaterialSpec)
    pins: tuple[PinSpec, ...] = ()
    impacts: tuple[ImpactSpec, ...] = ()
    wind: WindSpec | None = None
    colliders: tuple[ColliderSpec, ...] = ()
    tears: tuple[TearSpec, ...] = ()
    cuts: tuple[CutSpec, ...] = ()
    output: OutputSpec = Field(default_factory=OutputSpec)
    assets: tuple[AssetRuleSpec, ...] = ()
    source: Path | None = Field(None, exclude=True)

    _raw: dict[str, Any] = PrivateAttr(default_factory=dict)
    _lines: dict[Path_, int] = PrivateAttr(default_factory=dict)
    _cli: dict[Path_, str] = PrivateAttr(default_factory=dict)
    _label: str | None = PrivateAttr(default=None)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickle as the data it was validated from (the model class is built at run time)."""
        return (_rebuild, (self._raw, self.label, self.source, self._lines, self._cli))

    # -- convenience -----------------------------------------------------------------------------
    @property
    def label(self) -> str:
        """What errors call this recipe: its file, or the label it was validated under."""
        if self._label is not None:
            return self._label
        return str(self.source) if self.source is not None else "<recipe>"

    @property
    def raw(self) -> dict[str, Any]:
        """A deep copy of the TOML data as written (for merging and overrides)."""
        return copy.deepcopy(self._raw)

    @property
    def up_axis(self) -> str:
        return self.output.up_axis or self.simulation.up

    @property
    def changes_topology(self) -> bool:
        """Whether the mesh may open during the run ([[tears]] or [[cuts]])."""
        return bool(self.tears or self.cuts)

    def check_fixed_topology_formats(self) -> None:
        """RecipeError naming output.formats when a point cache is asked of a recipe that tears."""
        if not self.changes_topology:
            return
        for i, name in enumerate(self.output.formats):
            if name in POINT_CACHE_FORMATS:
                what = "[[tears]]" if self.tears else "[[cuts]]"
                raise self.error(
                    ("output", "formats", i),
                    f"{name} needs a fixed vertex count, but this recipe opens the mesh ({what}) and adds "
                    "vertices where it tears; write obj, ply, usd or vtk instead, or remove the tearing",
                )

    @property
    def asset_rules(self) -> tuple[AssetRule, ...]:
        return tuple(
            AssetRule(a.glob, {k: v for k, v in a.model_dump(exclude_none=True).items() if k != "glob"})
            for a in self.assets
        )

    def line_of(self, path: Path_) -> int | None:
        """Line of the key path in the source (or of its nearest enclosing key), if known."""
        for n in range(len(path), 0, -1):
            line = self._lines.get(tuple(path[:n]))
            if line is not None:
                return line
        return None

    def error(self, path: Path_ | str, message: str) -> RecipeError:
        """A RecipeError naming the file, key path and line (or the command-line option it came from)."""
        if isinstance(path, str):
            path = parse_path(path)
        for n in range(len(path), 0, -1):
            label = self._cli.get(tuple(path[:n]))
            if label is not None:
                return RecipeError(f"command line: {label}: {message}")
        return RecipeError(_message(self.label, path, self.line_of(path), message))

    def for_asset(self, relative_path: str) -> Recipe:
        """The recipe for one asset: every matching [[assets]] rule merged in order (assets dropped)."""
        data = self.raw
        data.pop("assets", None)
        matched = False
        for rule in self.asset_rules:
            if rule.matches(relative_path):
                data = merge_recipe_data(data, dict(rule.override))
                matched = True
        if not matched and not self.assets:
            return self
        recipe = _validate(data, self.label, self.source, self._lines, path_prefix=())
        recipe._cli = dict(self._cli)
        return recipe


# ---------------------------------------------------------------------------------------------
# solver options added at run time from SolverOptions
# ---------------------------------------------------------------------------------------------

_STRICT = {float: Float, int: StrictInt, bool: StrictBool, str: StrictStr}


def _tether_ratio(value: float) -> float:
    if 0 < value < 1:
        raise ValueError(f"must be 0 (no tethers) or at least 1 (1: no stretch along the path to a pin), got {value:g}")
    return value


#: the recipe type of each SolverOptions field beyond the ones SimulationSpec declares (iterations,
#: damping): strict types with ranges and limits; a field missing here falls back to `_strictify`
#: of its annotation (tests/test_limits.py asserts there is none)
SOLVER_OPTION_FIELDS: dict[str, Any] = {
    "strain_limit": Annotated[Float, Field(ge=1)],
    "strain_iterations": Annotated[StrictInt, Field(ge=0), _limited("simulation.strain_iterations")],
    "stable_substeps": StrictBool,
    "anchor_stiffness": Annotated[Float, Field(ge=0), _limited("simulation.anchor_stiffness")],
    "anchor_damping": Annotated[Float, Field(ge=0)],
    "uniform_scale": Annotated[Float, Field(gt=0), _limited("simulation.uniform_scale")],
    "anchor_frame": Literal[ANCHOR_FRAMES],
    "neighbour_springs": StrictBool,
    "partitions": Annotated[StrictInt, Field(ge=0), _limited("simulation.partitions")],
    "tethers": Annotated[Float, Field(ge=0), AfterValidator(_tether_ratio)],
}


def _strictify(tp: Any) -> Any:
    if tp in _STRICT:
        return _STRICT[tp]
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = tuple(_strictify(a) for a in typing.get_args(tp))
        return Union[args]  # noqa: UP007
    return tp


@cache
def _recipe_class(option_fields: tuple[str, ...]) -> type[Recipe]:
    hints = typing.get_type_hints(SolverOptions)
    extra: dict[str, Any] = {}
    for name in option_fields:
        if name in SimulationSpec.model_fields:
            continue
        spec = SOLVER_OPTION_FIELDS.get(name)
        extra[name] = ((_strictify(hints.get(name, Any)) if spec is None else spec) | None, None)
    simulation = create_model("SimulationSpec", __base__=SimulationSpec, **extra) if extra else SimulationSpec
    return create_model("Recipe", __base__=Recipe, simulation=(simulation, Field(default_factory=simulation)))  # type: ignore[call-overload]


def recipe_class() -> type[Recipe]:
    """The Recipe model for the SolverOptions fields of this build (solver options checked by name)."""
    return _recipe_class(tuple(f.name for f in dataclasses.fields(SolverOptions)))


# ---------------------------------------------------------------------------------------------
# key paths, lines and messages
# ---------------------------------------------------------------------------------------------


def format_path(path: Sequence[str | int]) -> str:
    """('pins', 0, 'select', 'box') -> 'pins[0].select.box'."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            name = part if part.replace("_", "").replace("-", "").isalnum() else json.dumps(part)
            out += f".{name}" if out else name
    return out


def parse_path(text: str) -> Path_:
    """'pins[0].select.box' -> ('pins', 0, 'select', 'box') (bare keys only)."""
    out: list[str | int] = []
    for piece in text.split("."):
        name, *indices = piece.split("[")
        if name:
            out.append(name)
        out.extend(int(i.rstrip("]")) for i in indices)
    return tuple(out)


def _message(label: str, path: Sequence[str | int], line: int | None, what: str) -> str:
    where = format_path(path)
    parts = [label]
    if where:
        parts.append(where + (f" (line {line})" if line else ""))
    elif line:
        parts.append(f"line {line}")
    return ": ".join(parts) + f": {what}"


_BARE = set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")


class _Locator:
    """Finds the line of every table header, key and array element of a TOML text (already valid)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.pos = 0
        self.lines: dict[Path_, int] = {}
        self.aot: dict[Path_, int] = {}
        self.starts = [0] + [i + 1 for i, c in enumerate(text) if c == "\n"]
        with contextlib.suppress(IndexError, ValueError):  # best effort: keep what was found
            self._document()

    def line(self, offset: int) -> int:
        return bisect_right(self.starts, offset)

    def _record(self, path: Path_, offset: int) -> None:
        self.lines.setdefault(path, self.line(offset))

    def _skip(self, newlines: bool = True) -> None:
        t = self.text
        while self.pos < len(t):
            c = t[self.pos]
            if c in " \t\r" or (newlines and c == "\n"):
                self.pos += 1
            elif c == "#":
                while self.pos < len(t) and t[self.pos] != "\n":
                    self.pos += 1
            else:
                break

    def _string(self) -> str:
        t = self.text
        for quote in ('"""', "'''"):
            if t.startswith(quote, self.pos):
                end = t.index(quote, self.pos + 3)
                while t.startswith(quote[0], end + 3):
                    end += 1
                value = t[self.pos + 3 : end]
                self.pos = end + 3
                return value
        q = t[self.pos]
        i = self.pos + 1
        out = []
        while t[i] != q:
            if q == '"' and t[i] == "\\":
                out.append(t[i : i + 2])
                i += 2
                continue
            out.append(t[i])
            i += 1
        self.pos = i + 1
        raw = "".join(out)
        return json.loads(f'"{raw}"') if q == '"' else raw

    def _key(self) -> list[str]:
        keys = []
        t = self.text
        while True:
            self._skip(newlines=False)
            if t[self.pos] in "\"'":
                keys.append(self._string())
            else:
                start = self.pos
                while t[self.pos] in _BARE:
                    self.pos += 1
                keys.append(t[start : self.pos])
            self._skip(newlines=False)
            if t[self.pos] == ".":
                self.pos += 1
                continue
            return keys

    def _resolve(self, keys: Sequence[str]) -> Path_:
        path: Path_ = ()
        for k in keys:
            path = (*path, k)
            if path in self.aot:
                path = (*path, self.aot[path] - 1)
        return path

    def _document(self) -> None:
        t = self.text
        current: Path_ = ()
        while True:
            self._skip()
            if self.pos >= len(t):
                return
            start = self.pos
            if t.startswith("[[", self.pos):
                self.pos += 2
                keys = self._key()
                self.pos += 2
                parent = self._resolve(keys[:-1])
                array = (*parent, keys[-1])
                self.aot[array] = self.aot.get(array, 0) + 1
                current = (*array, self.aot[array] - 1)
                for n in range(1, len(current) + 1):
                    self._record(current[:n], start)
            elif t[self.pos] == "[":
                self.pos += 1
                keys = self._key()
                self.pos += 1
                current = self._resolve(keys)
                for n in range(1, len(current) + 1):
                    self._record(current[:n], start)
            else:
                self._keyval(current)

    def _keyval(self, prefix: Path_) -> None:
        start = self.pos
        keys = self._key()
        self.pos += 1  # '='
        path = (*prefix, *keys)
        for n in range(len(prefix) + 1, len(path) + 1):
            self._record(path[:n], start)
        self._value(path)

    def _value(self, path: Path_) -> None:
        t = self.text
        self._skip(newlines=False)
        c = t[self.pos]
        if c == "{":
            self.pos += 1
            while True:
                self._skip()
                if t[self.pos] == "}":
                    self.pos += 1
                    return
                if t[self.pos] == ",":
                    self.pos += 1
                    continue
                self._keyval(path)
        elif c == "[":
            self.pos += 1
            i = 0
            while True:
                self._skip()
                if t[self.pos] == "]":
                    self.pos += 1
                    return
                if t[self.pos] == ",":
                    self.pos += 1
                    continue
                self._record((*path, i), self.pos)
                self._value((*path, i))
                i += 1
        elif c in "\"'":
            self._string()
        else:
            while self.pos < len(t) and t[self.pos] not in ",]}\n#":
                self.pos += 1


def _model_at(cls: type[BaseModel], loc: Sequence[str | int]) -> type[BaseModel] | None:
    """The model class that validates the table at `loc` (for listing its allowed keys)."""
    current: type[BaseModel] | None = cls
    for part in loc:
        if current is None:
            return None
        if isinstance(part, int):
            continue
        field = next((f for n, f in current.model_fields.items() if (f.alias or n) == part), None)
        if field is None:
            return None
        current = _find_model(field.annotation)
    return current


def _find_model(tp: Any) -> type[BaseModel] | None:
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return tp
    for arg in typing.get_args(tp):
        found = _find_model(arg)
        if found is not None:
            return found
    return None


def _allowed(cls: type[BaseModel]) -> list[str]:
    return [f.alias or n for n, f in cls.model_fields.items() if n != "source"]


_OPS = {
    "greater_than": ("greater than", "gt"),
    "greater_than_equal": ("at least", "ge"),
    "less_than": ("less than", "lt"),
    "less_than_equal": ("at most", "le"),
}

_TYPES = {
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "an integer",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "bool_type": "true or false",
    "bool_parsing": "true or false",
    "string_type": "a string",
    "model_type": "a table",
    "model_attributes_type": "a table",
    "dict_type": "a table",
    "tuple_type": "an array",
    "list_type": "an array",
}


def _describe(error: Mapping[str, Any], model: type[BaseModel]) -> str:
    kind = error["type"]
    loc = error["loc"]
    value = error.get("input")
    ctx = error.get("ctx") or {}
    if kind == "extra_forbidden":
        key = loc[-1]
        parent = _model_at(model, loc[:-1])
        text = f"unknown key {key!r}"
        if parent is not None:
            allowed = _allowed(parent)
            close = difflib.get_close_matches(str(key), allowed, n=1)
            text += f" (did you mean {close[0]!r}?)" if close else ""
            text += f"; allowed keys: {', '.join(allowed)}"
        return text
    if kind == "missing":
        return f"missing required key {loc[-1]!r}" if loc else "missing required key"
    if kind in _TYPES:
        return f"expected {_TYPES[kind]}, got {toml_type(value)} {show(value)}"
    if kind in _OPS:
        words, key = _OPS[kind]
        return f"must be {words} {ctx.get(key)}, got {show(value)}"
    if kind == "finite_number":
        return f"must be a finite number, got {show(value)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected')}, got {show(value)}"
    if kind == "too_short":
        return f"needs at least {ctx.get('min_length')} item(s)"
    if kind == "value_error":
        msg = str(error["msg"])
        return msg.removeprefix("Value error, ")
    return str(error["msg"]).lower()


# ---------------------------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------------------------


class _LocatedError(RecipeError):
    """A RecipeError that also keeps the key path and the bare complaint (for command-line overrides);
    `related` are other key paths the complaint is about (a limit on a product of two keys)."""

    def __init__(
        self,
        label: str,
        path: Sequence[str | int],
        line: int | None,
        detail: str,
        related: Sequence[Path_] = (),
    ) -> None:
        super().__init__(_message(label, path, line, detail))
        self.path = tuple(path)
        self.detail = detail
        self.related = tuple(related)


def _work_complaint(recipe: Recipe) -> tuple[Path_, str, tuple[Path_, ...]] | None:
    """(key path, complaint, related key paths) when substeps x iterations per frame is above its limit."""
    sim = recipe.simulation
    sweeps = sim.sweeps_per_frame()
    if sweeps is None:
        return None
    substeps, iterations = sweeps
    limit = LIMITS["simulation.substeps x iterations"]
    complaint = limit.complaint(substeps * iterations)
    if complaint is None:
        return None
    given = [k for k in ("substeps", "iterations") if getattr(sim, k) is not None]
    path: Path_ = ("simulation", given[0] if given else "solver")
    words = [f"{substeps} substeps" + ("" if sim.substeps is not None else f" ({sim.solver}'s default)")]
    words.append(f"{iterations} iterations" + ("" if sim.iterations is not None else f" ({sim.solver}'s default)"))
    detail = f"{' x '.join(words)} = {complaint}"
    return path, detail, tuple(("simulation", k) for k in given)


def _validate(
    data: dict[str, Any],
    label: str,
    source: Path | None,
    lines: Mapping[Path_, int],
    path_prefix: Path_ = (),
    error_lines: bool = True,
) -> Recipe:
    cls = recipe_class()
    # (key path, complaint): too many tables first (the schema would take seconds over them), then
    # values no key accepts, then what the schema says
    problems: list[tuple[Path_, str]] = list(_too_many_tables(data))
    recipe: Recipe | None = None
    if not problems:
        problems = list(_bad_numbers(data))
        try:
            recipe = cls.model_validate(data)
        except ValidationError as exc:
            problems += [(tuple(e["loc"]), _describe(e, cls)) for e in exc.errors(include_url=False)]
    if problems:

        def where(problem: tuple[Path_, str]) -> tuple[int, int]:
            loc = (*path_prefix, *problem[0])
            for n in range(len(loc), 0, -1):
                if tuple(loc[:n]) in lines:
                    return (lines[tuple(loc[:n])], -n)
            return (10**9, 0)

        first = min(problems, key=where) if error_lines else problems[0]
        loc = (*path_prefix, *first[0])
        line = None
        if error_lines:
            for n in range(len(loc), 0, -1):
                if tuple(loc[:n]) in lines:
                    line = lines[tuple(loc[:n])]
                    break
        raise _LocatedError(label, loc, line, first[1]) from None
    assert recipe is not None
    work = _work_complaint(recipe)
    if work is not None:
        path, detail, related = work
        loc = (*path_prefix, *path)
        line = None
        if error_lines:
            line = next((lines[loc[:n]] for n in range(len(loc), 0, -1) if loc[:n] in lines), None)
        raise _LocatedError(label, loc, line, detail, [(*path_prefix, *r) for r in related])
    recipe = recipe.model_copy(update={"source": source})
    recipe._raw = copy.deepcopy(data)
    recipe._lines = dict(lines)
    recipe._label = label
    return recipe


def _rebuild(
    data: dict[str, Any], label: str, source: Path | None, lines: dict[Path_, int], cli: dict[Path_, str]
) -> Recipe:
    recipe = _validate(data, label, source, lines)
    recipe._cli = dict(cli)
    return recipe


def parse_recipe(text: str, source: str = "<recipe>") -> Recipe:
    """Parse and validate recipe TOML text; `source` names it in errors (and anchors relative paths)."""
    text = text.removeprefix("\ufeff")
    nul = text.find("\x00")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise RecipeError(f"{source}: line {line}: a NUL byte: a recipe is text (is it a binary file?)")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        line = None
        if "(at line " in msg:
            line = int(msg.rsplit("(at line ", 1)[1].split(",")[0].rstrip(")"))
            msg = msg.rsplit(" (at line ", 1)[0]
        where = f"line {line}: " if line else ""
        raise RecipeError(f"{source}: {where}invalid TOML: {msg}") from None
    lines = _Locator(text).lines
    source_path = None if source.startswith("<") else Path(source)
    recipe = _validate(data, source, source_path, lines)
    # every [[assets]] override must give a valid recipe once merged (errors point into the rule)
    for i, rule in enumerate(recipe.asset_rules):
        merged = merge_recipe_data({k: v for k, v in data.items() if k != "assets"}, dict(rule.override))
        _validate(merged, source, source_path, lines, path_prefix=("assets", i))
    return recipe


def recipe_from_data(data: Mapping[str, Any], label: str = "<recipe>", source: Path | str | None = None) -> Recipe:
    """Validate recipe data already parsed or merged (sidecars, [[assets]] layers): errors name
    `label` and the key path, without line numbers. `source` anchors relative paths (mesh colliders)."""
    return _validate(copy.deepcopy(dict(data)), label, None if source is None else Path(source), {}, error_lines=False)


def load_recipe(path: Path | str | None) -> Recipe:
    """Read and validate a recipe file; None gives the all-defaults recipe."""
    if path is None:
        return recipe_class()()
    p = Path(path)
    limit = int(LIMITS["recipe file size"].maximum)
    if (kind := special_file_kind(p)) is not None:
        raise RecipeError(f"{p}: is {kind}, not a recipe file")
    try:
        with open(p, "rb") as handle:
            data = handle.read(limit + 1)
    except FileNotFoundError:
        raise RecipeError(f"{p}: no such recipe file") from None
    except IsADirectoryError:
        raise RecipeError(f"{p}: is a directory, not a recipe file") from None
    except OSError as exc:
        raise RecipeError(f"{p}: cannot read recipe: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise RecipeError(f"{p}: is larger than {limit // 2**20} MB, the limit for a recipe (is it a recipe file?)")
    return parse_recipe(decode_recipe(data, str(p)), str(p))


#: byte order marks of encodings a recipe is not in (TOML is UTF-8)
_BOMS = (
    (b"\x00\x00\xfe\xff", "UTF-32"),
    (b"\xff\xfe\x00\x00", "UTF-32"),
    (b"\xfe\xff", "UTF-16"),
    (b"\xff\xfe", "UTF-16"),
)


def decode_recipe(data: bytes, source: str) -> str:
    """Recipe bytes as text: UTF-8, a UTF-8 byte order mark skipped; UTF-16/32 and invalid UTF-8
    raise RecipeError naming the file and the line (NUL bytes are refused by `parse_recipe`)."""
    name = next((name for bom, name in _BOMS if data.startswith(bom)), None)
    if name is None and len(data) >= 4 and max(data[0::2].count(0), data[1::2].count(0)) > len(data) // 4:
        name = "UTF-16"  # without a byte order mark: every other byte of ASCII text is NUL
    if name is not None:
        raise RecipeError(f"{source}: is {name} text; a recipe must be UTF-8 (save it as UTF-8)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise RecipeError(f"{source}: line {line}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def merge_recipe_data(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge recipe data: tables merge key by key, arrays and scalars from `override` replace."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_recipe_data(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _cli_pin(text: str) -> dict[str, Any]:
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    tokens = [v.strip() for v in rest.split(",") if v.strip()]
    if kind == "indices":
        if not tokens or not all(re.fullmatch(r"[0-9]{1,18}", v) for v in tokens):
            raise RecipeError(f"command line: --pin {text!r}: expected vertex indices like indices:0,5,9")
        return {"select": {"indices": [int(v) for v in tokens]}}
    try:
        values = [float(v) for v in tokens]
    except ValueError:
        raise RecipeError(f"command line: --pin {text!r}: expected numbers after '{kind}:'") from None
    if not all(math.isfinite(v) for v in values):
        raise RecipeError(f"command line: --pin {text!r}: expected finite numbers after '{kind}:'")
    if kind == "box":
        if len(values) != 6:
            raise RecipeError(
                f"command line: --pin {text!r}: expected 6 numbers box:x0,y0,z0,x1,y1,z1 (0..1 of the mesh bounds)"
            )
        lo = [min(a, b) for a, b in zip(values[:3], values[3:], strict=True)]
        hi = [max(a, b) for a, b in zip(values[:3], values[3:], strict=True)]
        return {"select": {"box": {"min": lo, "max": hi}, "relative": True}}
    raise RecipeError(f"command line: --pin {text!r}: expected indices:I,J,... or box:x0,y0,z0,x1,y1,z1")


def apply_overrides(
    recipe: Recipe,
    *,
    solver: str | None = None,
    frames: int | None = None,
    fps: float | None = None,
    substeps: int | None = None,
    iterations: int | None = None,
    damping: float | None = None,
    gravity: Sequence[float] | None = None,
    pins: Sequence[str] = (),
    formats: Sequence[str] = (),
) -> Recipe:
    """The recipe with command-line options in force (they win); `pins` are added as hard pins,
    `formats` replace output.formats. Bad values raise RecipeError naming the option."""
    sim: dict[str, Any] = {}
    options = {
        "solver": (solver, "--solver"),
        "frames": (frames, "--frames"),
        "fps": (fps, "--fps"),
        "substeps": (substeps, "--substeps"),
        "iterations": (iterations, "--iterations"),
        "damping": (damping, "--damping"),
        "gravity": (list(gravity) if gravity is not None else None, "--gravity"),
    }
    labels: dict[Path_, str] = {}
    for key, (value, flag) in options.items():
        if value is not None:
            sim[key] = value
            labels[("simulation", key)] = flag
    data = recipe.raw
    if sim:
        data = merge_recipe_data(data, {"simulation": sim})
    if formats:
        data = merge_recipe_data(data, {"output": {"formats": list(formats)}})
        labels[("output", "formats")] = "--format"
    if pins:
        existing = list(data.get("pins", []))
        for text in pins:
            labels[("pins", len(existing))] = f"--pin {text!r}"
            existing.append(_cli_pin(text))
        data["pins"] = existing
    if not labels:
        return recipe
    try:
        new = _validate(data, recipe.label, recipe.source, {}, error_lines=False)
    except _LocatedError as exc:
        # name the option rather than the file when the complaint is about an override
        for path in (exc.path, *exc.related):
            for n in range(len(path), 0, -1):
                flag = labels.get(path[:n])
                if flag is not None:
                    raise RecipeError(f"command line: {flag}: {exc.detail}") from None
        raise
    new._lines = dict(recipe._lines)
    new._cli = {**recipe._cli, **labels}
    return new


def recipe_hash(recipe: Recipe) -> str:
    """sha256 of the normalised recipe (defaults filled in, key order irrelevant) plus the contents
    of files it references (mesh colliders), so a changed collider file changes the hash."""
    content = recipe.model_dump(mode="json", by_alias=True, exclude={"source"})
    digest = hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    for collider in recipe.colliders:
        if collider.mesh is not None:
            path = resolve_path(recipe, collider.mesh.path)
            try:
                digest.update(hashlib.sha256(path.read_bytes()).digest())
            except OSError:
                digest.update(b"missing:" + collider.mesh.path.encode("utf-8"))
    return digest.hexdigest()


def resolve_path(recipe: Recipe, path: str) -> Path:
    """A path written in the recipe: relative to the recipe file's folder (or the working directory)."""
    p = Path(path).expanduser()
    if p.is_absolute() or recipe.source is None:
        return p
    return recipe.source.parent / p
