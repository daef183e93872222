"""`Recipe`: a validated recipe document, one model per section, plus where it came from.

Besides the sections, a Recipe keeps the TOML data as written (`raw`, for merging [[assets]]
rules, sidecars and command-line overrides), the line of every key (`line_of`) and which keys
came from the command line, so that `error` names the file, key path and line, or the option.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from pydantic import Field, PrivateAttr, field_validator, model_validator

from meshdeform.errors import RecipeError
from meshdeform.export import EXPORTERS
from meshdeform.export.registry import topology_following
from pipeline.recipe.messages import KeyPath, line_at, message, parse_path
from pipeline.recipe.schema import (
    AssetRule,
    AssetRuleSpec,
    ColliderSpec,
    CutSpec,
    ImpactSpec,
    MaterialSpec,
    OutputSpec,
    PinSpec,
    SelfCollisionSpec,
    SimulationSpec,
    TearSpec,
    WindSpec,
)
from pipeline.recipe.values import Table


class Recipe(Table):
    """A validated recipe. Sections are immutable pydantic models; `source` is the file it came from."""

    simulation: SimulationSpec = Field(default_factory=SimulationSpec)
    material: MaterialSpec = Field(default_factory=MaterialSpec)
    pins: tuple[PinSpec, ...] = ()
    impacts: tuple[ImpactSpec, ...] = ()
    wind: WindSpec | None = None
    colliders: tuple[ColliderSpec, ...] = ()
    self_collision: SelfCollisionSpec | None = None
    tears: tuple[TearSpec, ...] = ()
    cuts: tuple[CutSpec, ...] = ()
    output: OutputSpec = Field(default_factory=OutputSpec)
    assets: tuple[AssetRuleSpec, ...] = ()
    source: Path | None = Field(None, exclude=True)

    _raw: dict[str, Any] = PrivateAttr(default_factory=dict)
    _lines: dict[KeyPath, int] = PrivateAttr(default_factory=dict)
    _cli: dict[KeyPath, str] = PrivateAttr(default_factory=dict)
    _label: str | None = PrivateAttr(default=None)
    #: key paths of the deprecated solver options written directly under [simulation]
    _flat: tuple[KeyPath, ...] = PrivateAttr(default=())
    _deprecation: str | None = PrivateAttr(default=None)

    @field_validator("colliders")
    @classmethod
    def _unique_names(cls, value: tuple[ColliderSpec, ...]) -> tuple[ColliderSpec, ...]:
        names = [c.name for c in value if c.name is not None]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"collider name {twice[0]!r} is given to more than one collider")
        return value

    @model_validator(mode="after")
    def _output_frames_in_the_run(self) -> Recipe:
        if self.output.frames is not None:
            first, last = self.output.frames
            start = self.simulation.start_frame
            end = start + self.simulation.frames
            if first < start or last > end:
                raise ValueError(
                    f"output: frames = [{first}, {last}] must lie within the run's scene frames {start} (the rest"
                    f" pose) to {end} (start_frame + frames)"
                )
        return self


    @property
    def label(self) -> str:
        """What errors call this recipe: its file, or the label it was validated under."""
        if self._label is not None:
            return self._label
        return str(self.source) if self.source is not None else "<recipe>"

    @property
    def deprecation(self) -> str | None:
        """One warning line when the recipe (or one of its [[assets]] rules) writes solver options
        directly under [simulation], naming the file, the first such key and the table each belongs
        in; None otherwise. The command line prints it on stderr, a batch writes it to its log."""
        return self._deprecation

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

    def attach_complaint(self) -> tuple[KeyPath, str] | None:
        """(key path, complaint) for the first pin whose `attach` names no collider of the recipe;
        None when every one does. Part of the recipe's validation (`pipeline.recipe.load.validate`),
        where the complaint gets the pin's line."""
        names = {c.name for c in self.colliders if c.name is not None}
        for i, pin in enumerate(self.pins):
            if pin.attach is not None and pin.attach not in names:
                known = ", ".join(sorted(names)) or "none has a name"
                return ("pins", i, "attach"), f"{pin.attach!r} names no collider (named colliders: {known})"
        return None

    def fixed_topology_complaint(self) -> tuple[KeyPath, str] | None:
        """(key path, complaint) when a recipe that tears or cuts asks for a format that needs a
        fixed vertex count (an exporter without `supports_topology_change`: point caches); None
        otherwise. Part of the recipe's validation (`pipeline.recipe.load.validate`), so `check`,
        `simulate` and `batch` refuse such a recipe alike, before anything is read or run."""
        if not self.changes_topology:
            return None
        for i, name in enumerate(self.output.formats):
            if not EXPORTERS[name].supports_topology_change:
                what = "[[tears]]" if self.tears else "[[cuts]]"
                return ("output", "formats", i), (
                    f"{name} needs a fixed vertex count, but this recipe opens the mesh ({what}) and adds "
                    f"vertices where it tears; write {topology_following()} instead, or remove the tearing"
                )
        return None

    @property
    def asset_rules(self) -> tuple[AssetRule, ...]:
        return tuple(
            AssetRule(a.glob, {k: v for k, v in a.model_dump(exclude_none=True).items() if k != "glob"})
            for a in self.assets
        )

    def line_of(self, path: KeyPath) -> int | None:
        """Line of the key path in the source (or of its nearest enclosing key), if known."""
        return line_at(self._lines, path)

    def error(self, path: KeyPath | str, what: str) -> RecipeError:
        """A RecipeError naming the file, key path and line (or the command-line option it came from)."""
        if isinstance(path, str):
            path = parse_path(path)
        for n in range(len(path), 0, -1):
            label = self._cli.get(tuple(path[:n]))
            if label is not None:
                return RecipeError(f"command line: {label}: {what}")
        return RecipeError(message(self.label, path, self.line_of(path), what))

    def for_asset(self, relative_path: str) -> Recipe:
        """The recipe for one asset: every matching [[assets]] rule merged in order (assets dropped)."""
        from pipeline.recipe.overrides import for_asset

        return for_asset(self, relative_path)


def resolve_path(recipe: Recipe, path: str) -> Path:
    """A path written in the recipe: relative to the recipe file's folder (or the working directory)."""
    p = Path(path).expanduser()
    if p.is_absolute() or recipe.source is None:
        return p
    return recipe.source.parent / p
