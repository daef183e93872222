"""Recipes: the scripted scene (TOML) a batch applies to every asset, parsed into a typed `Recipe`.

`load_recipe` / `parse_recipe` read TOML with `tomllib`, validate it with pydantic models (unknown
keys, wrong types and out-of-range values are errors) and raise `RecipeError` with one line:
`<file>: <key.path> (line N): <what>`. The schema is documented in docs/recipes.md;
`pipeline.build` turns a Recipe plus a mesh into a runnable simulation.

| module      | what                                                                          |
|-------------|-------------------------------------------------------------------------------|
| `schema`    | the section models ([simulation], [material], [[pins]], ... [[assets]])        |
| `solver_options` | `[simulation.<solver>]`: each solver's options, read into its options class |
| `selection` | selection tables (`select = { box = ... }`) and their engine selection trees   |
| `values`    | strict value types (numbers, vectors) and the `Table` base model               |
| `limits`    | `LIMITS`: bounds that stop runaway work, and the checks over the whole document |
| `document`  | `Recipe`: the sections plus the data as written, key lines, command-line keys  |
| `load`      | bytes -> text -> TOML -> Recipe; `validate` reports the first problem by line  |
| `locate`    | the line of every key of the TOML text (tomllib gives no positions)            |
| `messages`  | key paths and the one-line error wording                                       |
| `overrides` | [[assets]] rules for one asset, command-line options                           |
| `digest`    | `recipe_hash`, the identity of a recipe for resuming                           |
"""

from pipeline.recipe.digest import recipe_hash
from pipeline.recipe.document import Recipe, resolve_path
from pipeline.recipe.limits import LIMITS, Limit
from pipeline.recipe.load import decode_recipe, load_recipe, parse_recipe, recipe_from_data
from pipeline.recipe.messages import format_path, parse_path
from pipeline.recipe.overrides import apply_overrides
from pipeline.recipe.schema import (
    AssetRule,
    ColliderSpec,
    KeySpec,
    SimulationSpec,
    merge_recipe_data,
)
from pipeline.recipe.selection import SelectSpec

__all__ = [
    "LIMITS",
    "AssetRule",
    "ColliderSpec",
    "KeySpec",
    "Limit",
    "Recipe",
    "SelectSpec",
    "SimulationSpec",
    "apply_overrides",
    "decode_recipe",
    "format_path",
    "load_recipe",
    "merge_recipe_data",
    "parse_path",
    "parse_recipe",
    "recipe_from_data",
    "recipe_hash",
    "resolve_path",
]
