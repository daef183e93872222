"""Solver options in a recipe: one table per solver, `[simulation.<solver>]`, read into the fields
of that solver's options class (meshdeform/solvers/options.py).

`[simulation]` holds the keys every solver takes (`SimulationSpec`: solver, fps, frames,
substeps, iterations, damping, ...); each solver's own options go in a table named after it:

    [simulation]
    solver = "xpbd"
    [simulation.xpbd]
    tethers = 1.05
    [simulation.anchor]       # validated, and used when `--solver anchor` switches to it
    anchor_stiffness = 30

The keys of `[simulation.<solver>]` are the fields of the solver's options class beyond those of
`SolverOptions` (iterations, damping: keys of [simulation]). Each value is validated against the
field's annotation in strict mode (no boolean or string for a number, no float for an integer),
with its declared range (the `annotated_types` constraints) and the recipe's own checks: the
LIMITS of `simulation.<solver>.<option>`, the magnitude bound of any number, and `_RULES`. A key
of another solver's class is an error naming that solver. The tables of every registered solver
are validated; only the one of the solver in force is used.

Deprecated, for one release: options of the solver in force written directly under [simulation]
(`tethers = 1.05`) are read as if they were in its table, and the recipe carries one warning line
(`deprecation_note`); an option of another solver there is an error.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Collection, Mapping, Sequence
from functools import cache
from typing import Any

from pydantic import ConfigDict, TypeAdapter, ValidationError

from meshdeform.solvers import SOLVERS
from meshdeform.solvers.options import (
    SolverOptions,
)
from pipeline.recipe.limits import LIMITS, magnitude_complaint
from pipeline.recipe.messages import (
    KeyPath,
    close_match,
    describe,
    format_path,
    line_at,
    message,
    number,
    show,
    toml_type,
)

#: a complaint about the data: (key path, what is wrong, other key paths it is about)
Problem = tuple[KeyPath, str, tuple[KeyPath, ...]]

#: the options every solver takes: keys of [simulation] itself, not of a solver's table
SHARED_OPTIONS = tuple(f.name for f in dataclasses.fields(SolverOptions))


def options_class(solver: str) -> type[SolverOptions]:
    """The options class of a registered solver (`Solver.options_class`); `SolverOptions` for a
    name the registry does not hold (the solver key's own check reports that)."""
    cls = SOLVERS.get(solver)
    return cls.options_class if cls is not None else SolverOptions


def own_options(solver: str) -> tuple[str, ...]:
    """The keys of `[simulation.<solver>]`: the fields of its options class beyond `SolverOptions`'."""
    return tuple(f.name for f in dataclasses.fields(options_class(solver)) if f.name not in SHARED_OPTIONS)


def all_options() -> tuple[str, ...]:
    """Every key of any registered solver's table, sorted."""
    return tuple(sorted({option for solver in SOLVERS for option in own_options(solver)}))


def owners(option: str) -> list[str]:
    """The registered solvers whose table takes `option`, sorted."""
    return [solver for solver in sorted(SOLVERS) if option in own_options(solver)]


def _tether_ratio(value: Any) -> str | None:
    if 0 < value < 1:
        return f"must be 0 (no tethers) or at least 1 (1: no stretch along the path to a pin), got {value:g}"
    return None


#: checks beyond the options classes' annotations, by option (`SweepOptions.tethers`: values between
#: 0 and 1 would pull vertices closer than their rest distance)
_RULES = {"tethers": _tether_ratio}


@cache
def _adapter(cls: type[SolverOptions], option: str) -> TypeAdapter[Any]:
    """A strict validator of one field of an options class, from its annotation."""
    return TypeAdapter(typing.get_type_hints(cls, include_extras=True)[option], config=ConfigDict(strict=True))


def _listing(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def _tables(names: Sequence[str]) -> str:
    return " or ".join(f"[simulation.{name}]" for name in names)


def check_option(solver: str, option: str, value: Any) -> tuple[Any, str | None]:
    """(the validated value, None) of one option of `solver`'s table, or (None, the complaint)."""
    try:
        value = _adapter(options_class(solver), option).validate_python(value)
    except ValidationError as exc:
        error = exc.errors(include_url=False)[0]
        ctx = {k: number(v) if isinstance(v, float) else v for k, v in (error.get("ctx") or {}).items()}
        return None, describe({**error, "ctx": ctx}, None)
    if isinstance(value, float):
        complaint = magnitude_complaint(value)
        if complaint is not None:
            return None, complaint
    limit = LIMITS.get(f"simulation.<solver>.{option}")
    if limit is not None and isinstance(value, int | float) and (complaint := limit.complaint(value)) is not None:
        return None, complaint
    rule = _RULES.get(option)
    if rule is not None and value is not None and (complaint := rule(value)) is not None:
        return None, complaint
    return value, None


def _table_key_complaint(solver: str, option: str, common: Collection[str]) -> str | None:
    """Why `option` is not a key of `[simulation.<solver>]`, or None when it is."""
    own = own_options(solver)
    if option in own:
        return None
    if option in common:
        return f"{option} is a key of [simulation] (every solver takes it), not of [simulation.{solver}]"
    others = owners(option)
    if others:
        return f"{option} is an option of {_listing(others)}, not of {solver}: put it in {_tables(others)}"
    if not own:
        return f"unknown key {option!r}; {solver} has no options of its own (its keys are those of [simulation])"
    return f"unknown key {option!r}{close_match(option, own)}; allowed keys: {', '.join(own)}"


@dataclasses.dataclass
class SolverTables:
    """What the [simulation] table of parsed TOML says about solver options.

    rest: the [simulation] data without solver tables and solver options (for `SimulationSpec`);
        the data itself when it is not a table.
    values: solver -> {option: validated value}, the options given (flat keys of the solver in
        force included); the keys left out take the options class's defaults.
    flat: key paths of the deprecated flat options read, in the order written.
    problems: what is wrong, with the key paths (within the data read).
    """

    rest: Any
    values: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    flat: list[KeyPath] = dataclasses.field(default_factory=list)
    problems: list[Problem] = dataclasses.field(default_factory=list)


def read_solver_tables(simulation: Any, common: Sequence[str], default_solver: str) -> SolverTables:
    """Split the [simulation] data of a recipe into its common keys (`common`, SimulationSpec's) and
    the solver options, validated; `default_solver` is in force when the data names none."""
    out = SolverTables(rest=simulation)
    if not isinstance(simulation, dict):
        return out  # the schema says "expected a table"
    solver = simulation.get("solver", default_solver)
    in_force = solver if isinstance(solver, str) and solver in SOLVERS else None  # else the schema complains
    out.rest = {}
    given: dict[str, dict[str, tuple[Any, KeyPath]]] = {}  # solver -> option -> (value, key path)
    for key, value in simulation.items():
        path: KeyPath = ("simulation", key)
        if key in common:
            out.rest[key] = value
        elif key in SOLVERS:
            if isinstance(value, dict):
                given.setdefault(key, {}).update({o: (v, (*path, o)) for o, v in value.items()})
            else:
                what = f"expected a table of {key}'s options, got {toml_type(value)} {show(value)}"
                out.problems.append((path, what, ()))
        elif key in all_options():
            if in_force is None:
                continue
            if key not in own_options(in_force):
                others = owners(key)
                what = (
                    f"{key} is an option of {_listing(others)}, not of {in_force} (the solver in force): "
                    f"put it in {_tables(others)}"
                )
                out.problems.append((path, what, (("simulation", "solver"),)))
            elif isinstance(simulation.get(in_force), dict) and key in simulation[in_force]:
                what = f"{key} is given twice, here and in [simulation.{in_force}]: keep the one in the table"
                out.problems.append((path, what, ()))
            else:
                given.setdefault(in_force, {})[key] = (value, path)
                out.flat.append(path)
        else:
            allowed = [*common, *sorted(SOLVERS)]
            what = (
                f"unknown key {key!r}{close_match(key, [*allowed, *all_options()])}; allowed keys: "
                f"{', '.join(common)}, and a table of options per solver: {', '.join(sorted(SOLVERS))}"
            )
            out.problems.append((path, what, ()))
    for name, options in given.items():
        for option, (value, path) in options.items():
            complaint = _table_key_complaint(name, option, common)
            if complaint is None:
                value, complaint = check_option(name, option, value)
            if complaint is not None:
                out.problems.append((path, complaint, ()))
            else:
                out.values.setdefault(name, {})[option] = value
    return out


def flat_options(simulation: Mapping[str, Any], solver: str) -> dict[str, Any]:
    """[simulation] data (as written, or as an [[assets]] rule gives it) in the shape it had before
    the solver tables: the table of `solver` merged in as flat keys, the other solvers' tables left
    out (for `recipe_hash`, so that a recipe moved to tables keeps its hash)."""
    out = {k: v for k, v in simulation.items() if k not in SOLVERS}
    table = simulation.get(solver)
    if isinstance(table, dict):
        out.update(table)
    return out


#: deprecated flat options found: (key path of the [simulation] table holding them, the solver in
#: force there, the options)
FlatPlace = tuple[KeyPath, str, Sequence[str]]


def deprecation_note(label: str, places: Sequence[FlatPlace], lines: Mapping[KeyPath, int]) -> str:
    """The one warning line about deprecated flat options, at the first one (located by `lines`)."""
    moves = []
    for table, solver, options in places:
        target = format_path((*table, solver))
        moves.append(f"move {', '.join(options)} to {f'[{target}]' if len(table) == 1 else target}")
    first = (*places[0][0], places[0][2][0])
    what = (
        "solver options directly under [simulation] are deprecated and will be refused in the next release: "
        + "; ".join(moves)
    )
    return message(label, first, line_at(lines, first), what)
