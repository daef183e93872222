"""Value types of the recipe schema, strict as TOML is typed, with messages in TOML's words.

`Float` takes a TOML float or integer (never a boolean or a string), finite and within
`LIMITS['any number']`; `Vec3` an array of three of them; `Direction3` one that is not the zero
vector; `Scale3` a number or three, positive. `Table` is the base of every section model:
unknown keys are errors, and a validated recipe is immutable.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any

from pydantic import AfterValidator, AllowInfNan, BaseModel, BeforeValidator, ConfigDict, Strict

from pipeline.recipe.limits import bounded
from pipeline.recipe.messages import show, toml_type

Float = Annotated[float, Strict(), AllowInfNan(False), AfterValidator(bounded)]


class Table(BaseModel):
    """A TOML table of the recipe: unknown keys are errors; the validated model is frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=False)


def is_number(value: Any) -> bool:
    """A TOML integer or float (a boolean is neither)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _vec3(value: Any) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple):
        raise ValueError(f"expected an array of 3 numbers, got {toml_type(value)} {show(value)}")
    if len(value) != 3:
        raise ValueError(f"expected 3 numbers [x, y, z], got {len(value)}: {show(value)}")
    for v in value:
        if not is_number(v):
            raise ValueError(f"expected 3 numbers [x, y, z], got {toml_type(v)} {show(v)} in {show(value)}")
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"expected finite numbers, got {show(value)}")
        bounded(v)
    return (float(value[0]), float(value[1]), float(value[2]))


def nonzero_vec3(value: Any) -> tuple[float, float, float]:
    """Three numbers, not all zero (a direction or a normal)."""
    v = _vec3(value)
    if v == (0.0, 0.0, 0.0):
        raise ValueError("must not be the zero vector")
    return v


def _scale(value: Any) -> tuple[float, float, float]:
    if is_number(value):
        v: tuple[float, float, float] | None = (float(bounded(value)),) * 3
    else:
        v = _vec3(value) if isinstance(value, list | tuple) else None
    if v is None:
        raise ValueError(f"expected a number or an array of 3 numbers, got {toml_type(value)} {show(value)}")
    if min(v) <= 0:
        raise ValueError(f"scale must be positive, got {show(value)}")
    return v


Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_vec3)]
Direction3 = Annotated[tuple[float, float, float], BeforeValidator(nonzero_vec3)]
Scale3 = Annotated[tuple[float, float, float], BeforeValidator(_scale)]


def one_of(given: Sequence[tuple[str, object]], what: str) -> str:
    """The one key of `given` ((key, value) pairs) whose value is set; ValueError unless exactly one is."""
    names = [name for name, _ in given]
    found = [name for name, value in given if value is not None]
    if len(found) != 1:
        listed = ", ".join(names)
        words = " and ".join(found) if found else "none"
        raise ValueError(f"{what} needs exactly one of {listed} (found {words})")
    return found[0]
