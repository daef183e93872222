"""Solver options added to [simulation] at run time from SolverOptions (to be replaced by tables)."""

from __future__ import annotations

import dataclasses
import types
import typing
from functools import cache
from typing import Annotated, Any, Literal, Union

from pydantic import AfterValidator, Field, StrictBool, StrictInt, StrictStr, create_model

from meshdeform.solvers.anchor import ANCHOR_FRAMES
from meshdeform.solvers.base import SolverOptions
from pipeline.recipe.document import Recipe
from pipeline.recipe.limits import limited
from pipeline.recipe.schema import SimulationSpec
from pipeline.recipe.values import Float

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
    "strain_iterations": Annotated[StrictInt, Field(ge=0), limited("simulation.strain_iterations")],
    "stable_substeps": StrictBool,
    "anchor_stiffness": Annotated[Float, Field(ge=0), limited("simulation.anchor_stiffness")],
    "anchor_damping": Annotated[Float, Field(ge=0)],
    "uniform_scale": Annotated[Float, Field(gt=0), limited("simulation.uniform_scale")],
    "anchor_frame": Literal[ANCHOR_FRAMES],
    "neighbour_springs": StrictBool,
    "partitions": Annotated[StrictInt, Field(ge=0), limited("simulation.partitions")],
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
