"""Reading a recipe: bytes -> text -> TOML data -> a validated `Recipe`, or one located error.

`load_recipe` reads a file (at most `LIMITS['recipe file size']`, UTF-8), `parse_recipe` parses
TOML text and validates it, also validating every [[assets]] rule against the recipe it produces,
and `recipe_from_data` validates data already parsed or merged (sidecars, overrides). All raise
RecipeError with one line: `<file>: <key.path> (line N): <what>`.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from meshdeform.errors import RecipeError
from meshdeform.io.files import special_file_kind
from pipeline.recipe.document import Recipe
from pipeline.recipe.limits import LIMITS, bad_numbers, too_many_tables, work_complaint
from pipeline.recipe.locate import key_lines
from pipeline.recipe.messages import KeyPath, LocatedError, describe, line_at
from pipeline.recipe.schema import SimulationSpec, merge_recipe_data
from pipeline.recipe.solver_options import FlatPlace, Problem, SolverTables, deprecation_note, read_solver_tables

#: the keys of [simulation] itself (the solver tables aside), and the solver when it names none
SIMULATION_KEYS = tuple(SimulationSpec.model_fields)
DEFAULT_SOLVER: str = SimulationSpec.model_fields["solver"].default


def validate(
    data: dict[str, Any],
    label: str,
    source: Path | None,
    lines: Mapping[KeyPath, int],
    path_prefix: KeyPath = (),
    error_lines: bool = True,
) -> Recipe:
    """The Recipe of parsed TOML `data`, or LocatedError about its first problem (by line when
    `error_lines`); `label` names the data in errors, `lines` locates its keys, `path_prefix` is
    where `data` sits in the document `lines` is of (an [[assets]] rule's merged recipe)."""
    # too many tables first (the schema would take seconds over them), then values no key accepts,
    # the solver tables, then what the schema says about the rest
    problems: list[Problem] = [(path, what, ()) for path, what in too_many_tables(data)]
    recipe: Recipe | None = None
    tables = SolverTables(rest=None)
    if not problems:
        problems = [(path, what, ()) for path, what in bad_numbers(data)]
        tables = read_solver_tables(data.get("simulation"), SIMULATION_KEYS, DEFAULT_SOLVER)
        problems += tables.problems
        try:
            rest = {**data, "simulation": tables.rest} if "simulation" in data else data
            recipe = Recipe.model_validate(rest)
        except ValidationError as exc:
            problems += [(tuple(e["loc"]), describe(e, Recipe), ()) for e in exc.errors(include_url=False)]
    if problems:

        def where(problem: Problem) -> tuple[int, int]:
            loc = (*path_prefix, *problem[0])
            for n in range(len(loc), 0, -1):
                if tuple(loc[:n]) in lines:
                    return (lines[tuple(loc[:n])], -n)
            return (10**9, 0)

        path, detail, related = min(problems, key=where) if error_lines else problems[0]
        loc = (*path_prefix, *path)
        line = line_at(lines, loc) if error_lines else None
        raise LocatedError(label, loc, line, detail, [(*path_prefix, *r) for r in related]) from None
    assert recipe is not None
    recipe.simulation._options = tables.values
    work = work_complaint(recipe)
    if work is not None:
        path, detail, related = work
        loc = (*path_prefix, *path)
        line = line_at(lines, loc) if error_lines else None
        raise LocatedError(label, loc, line, detail, [(*path_prefix, *r) for r in related])
    for complaint in (recipe.attach_complaint(), recipe.fixed_topology_complaint()):
        if complaint is not None:
            path, detail = complaint
            loc = (*path_prefix, *path)
            raise LocatedError(label, loc, line_at(lines, loc) if error_lines else None, detail)
    recipe = recipe.model_copy(update={"source": source})
    recipe._raw = copy.deepcopy(data)
    recipe._lines = dict(lines)
    recipe._label = label
    recipe._flat = tuple(tables.flat)
    place = _flat_place((*path_prefix, "simulation"), recipe)
    if place is not None:
        recipe._deprecation = deprecation_note(label, [place], lines if error_lines else {})
    return recipe


def _flat_place(table: KeyPath, recipe: Recipe, within: Collection[str] | None = None) -> FlatPlace | None:
    """Where `recipe` (validated from the [simulation] table at `table`) has deprecated flat options
    (those in `within` only, when given), for `deprecation_note`; None when it has none."""
    options = [str(path[-1]) for path in recipe._flat if within is None or path[-1] in within]
    return (table, recipe.simulation.solver, options) if options else None


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
    lines = key_lines(text)
    source_path = None if source.startswith("<") else Path(source)
    recipe = validate(data, source, source_path, lines)
    # every [[assets]] override must give a valid recipe once merged (errors point into the rule);
    # the deprecation line covers the flat options of the rules too
    places = [_flat_place(("simulation",), recipe)]
    for i, rule in enumerate(recipe.asset_rules):
        merged = merge_recipe_data({k: v for k, v in data.items() if k != "assets"}, dict(rule.override))
        layered = validate(merged, source, source_path, lines, path_prefix=("assets", i))
        places.append(_flat_place(("assets", i, "simulation"), layered, rule.override.get("simulation") or {}))
    given = [place for place in places if place is not None]
    if given:
        recipe._deprecation = deprecation_note(source, given, lines)
    return recipe


def recipe_from_data(data: Mapping[str, Any], label: str = "<recipe>", source: Path | str | None = None) -> Recipe:
    """Validate recipe data already parsed or merged (sidecars, [[assets]] layers): errors name
    `label` and the key path, without line numbers. `source` anchors relative paths (mesh colliders)."""
    return validate(copy.deepcopy(dict(data)), label, None if source is None else Path(source), {}, error_lines=False)


def load_recipe(path: Path | str | None) -> Recipe:
    """Read and validate a recipe file; None gives the all-defaults recipe."""
    if path is None:
        return Recipe()
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
