"""Selections in a recipe: which vertices a pin, impact, tear, cut or material region acts on.

A selection is a table with exactly one kind key (`indices`, `box`, `sphere`, `plane`, `group`,
`attribute`, or the combinations `any`, `all`, `not`) plus `relative` (coordinates as fractions
of the mesh's bounding box, inherited by the parts). `SelectSpec.build` turns it into the
engine's selection tree (`meshdeform.selection`), which `pipeline.build` evaluates on a mesh.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BeforeValidator, Field, StrictBool, StrictInt, StrictStr, model_validator

from meshdeform import selection as sel
from pipeline.recipe.messages import show
from pipeline.recipe.values import Direction3, Float, Table, Vec3, one_of


class BoxSpec(Table):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> BoxSpec:
        if any(a > b for a, b in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {show(list(self.min))} must not exceed max {show(list(self.max))}")
        return self


class SphereSpec(Table):
    center: Vec3
    radius: Float = Field(gt=0)


class PlaneSpec(Table):
    point: Vec3
    normal: Direction3


class AttributeSpec(Table):
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


class SelectSpec(Table):
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
        kinds = (
            ("indices", self.indices),
            ("box", self.box),
            ("sphere", self.sphere),
            ("plane", self.plane),
            ("group", self.group),
            ("attribute", self.attribute),
            ("any", self.any_),
            ("all", self.all_),
            ("not", self.not_),
        )
        one_of(kinds, "a selection")
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
