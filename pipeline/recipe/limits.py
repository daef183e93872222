"""Limits: bounds on recipe values that a real production never meets but a typo does.

`LIMITS` holds every one, by the key path it applies to (docs/recipes.md, "Limits", gives the
reason for each value). Most are enforced by the schema (`limited`, `bounded`); the checks here
that look at the whole document run before it (`too_many_tables`, `bad_numbers`) or after it
(`work_complaint`: substeps x iterations, which needs the solver's defaults).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from pydantic import AfterValidator

from pipeline.recipe.messages import KeyPath, number, show

if TYPE_CHECKING:
    from pipeline.recipe.document import Recipe


@dataclasses.dataclass(frozen=True)
class Limit:
    """A bound on a recipe value that stops runaway work: `minimum <= value <= maximum`, in `unit`."""

    maximum: float
    unit: str
    minimum: float | None = None

    def complaint(self, value: float) -> str | None:
        """The one-line complaint about `value`, or None when it is within the limit."""
        if value > self.maximum:
            return f"{number(value)} is above the limit of {number(self.maximum)} {self.unit}"
        if self.minimum is not None and value < self.minimum:
            return f"{number(value)} is below the limit of {number(self.minimum)} {self.unit}"
        return None


#: every limit, by the key path it applies to (`[]`: any element of an array of tables, `<solver>`: the
#: table of any solver that has the option); the list in docs/recipes.md gives the reason for each value
LIMITS: dict[str, Limit] = {
    "simulation.frames": Limit(1_000_000, "frames"),
    "simulation.substeps": Limit(100_000, "substeps per frame"),
    "simulation.iterations": Limit(100_000, "iterations per substep"),
    "simulation.substeps x iterations": Limit(100_000, "solver sweeps per frame"),
    "simulation.fps": Limit(10_000, "frames per second", minimum=0.01),
    "simulation.start_frame": Limit(1_000_000, "(first frame number)"),
    "simulation.tear_burst": Limit(100_000, "topology updates in a burst"),
    "simulation.<solver>.strain_iterations": Limit(100_000, "strain passes per step"),
    "simulation.<solver>.partitions": Limit(1024, "partitions"),
    "simulation.<solver>.anchor_stiffness": Limit(1e6, "1/s^2"),
    "simulation.<solver>.uniform_scale": Limit(1000, "(scale factor)"),
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


def limited(key: str) -> AfterValidator:
    """A pydantic validator enforcing `LIMITS[key]` (the message names the limit and its unit)."""
    limit = LIMITS[key]

    def check(value: Any) -> Any:
        complaint = limit.complaint(value)
        if complaint is not None:
            raise ValueError(complaint)
        return value

    return AfterValidator(check)


def magnitude_complaint(value: float) -> str | None:
    """The complaint about a number beyond LIMITS['any number'] in magnitude (beyond it, squares
    overflow), or None."""
    limit = LIMITS["any number"].maximum
    if abs(value) > limit:
        return f"{number(value)} is beyond the limit of {number(limit)} for any number in a recipe"
    return None


def bounded(value: float) -> float:
    """Any float in a recipe: `value`, or ValueError beyond LIMITS['any number'] in magnitude."""
    complaint = magnitude_complaint(value)
    if complaint is not None:
        raise ValueError(complaint)
    return value


def too_many_tables(data: Any, path: KeyPath = ()) -> Iterator[tuple[KeyPath, str]]:
    """(key path, complaint) for every array of tables (`[[impacts]]`, ...) longer than the limit: a
    generated recipe gone wrong, refused before the schema spends seconds on each of its tables."""
    limit = LIMITS["tables in one array"].maximum
    if isinstance(data, dict):
        for key, value in data.items():
            if isinstance(value, list) and len(value) > limit and all(isinstance(v, dict) for v in value):
                yield (*path, key), f"{len(value)} tables is above the limit of {number(limit)} tables in one array"
            elif isinstance(value, dict):
                yield from too_many_tables(value, (*path, key))


def bad_numbers(data: Any, path: KeyPath = ()) -> Iterator[tuple[KeyPath, str]]:
    """(key path, complaint) for every value of the parsed TOML, at any depth, that no key accepts:
    non-finite floats (TOML allows `inf` and `nan`) and integers that do not fit in 64 bits."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield from bad_numbers(value, (*path, key))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            yield from bad_numbers(value, (*path, i))
    elif isinstance(data, float) and not math.isfinite(data):
        yield path, f"must be a finite number, got {show(data)}"
    elif isinstance(data, int) and not isinstance(data, bool) and LIMITS["any integer"].complaint(data) is not None:
        yield path, f"{data} does not fit in 64 bits (integers range from -2^63 to 2^63 - 1)"


def work_complaint(recipe: Recipe) -> tuple[KeyPath, str, tuple[KeyPath, ...]] | None:
    """(key path, complaint, related key paths) when substeps x iterations per frame is above its limit."""
    sim = recipe.simulation
    substeps, iterations = sim.sweeps_per_frame()
    limit = LIMITS["simulation.substeps x iterations"]
    complaint = limit.complaint(substeps * iterations)
    if complaint is None:
        return None
    given = [k for k, v in (("substeps", sim.substeps), ("iterations", sim.iterations)) if v is not None]
    path: KeyPath = ("simulation", given[0] if given else "solver")
    words = [f"{substeps} substeps" + ("" if sim.substeps is not None else f" ({sim.solver}'s default)")]
    words.append(f"{iterations} iterations" + ("" if sim.iterations is not None else f" ({sim.solver}'s default)"))
    detail = f"{' x '.join(words)} = {complaint}"
    return path, detail, tuple(("simulation", k) for k in given)
