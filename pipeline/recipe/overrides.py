"""Layers over a loaded recipe: its [[assets]] rules for one asset, and command-line options.

Both merge into the recipe's data as written (`merge_recipe_data`: tables key by key, arrays
replace) and validate the result again; a bad command-line value is reported against its option
(`command line: --frames: ...`), and later errors about keys an option set name it too.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import Any

from meshdeform.errors import RecipeError
from pipeline.recipe.document import Recipe
from pipeline.recipe.load import validate
from pipeline.recipe.messages import KeyPath, LocatedError
from pipeline.recipe.schema import merge_recipe_data


def for_asset(recipe: Recipe, relative_path: str) -> Recipe:
    """The recipe for one asset: every matching [[assets]] rule merged in order (assets dropped)."""
    data = recipe.raw
    data.pop("assets", None)
    matched = False
    for rule in recipe.asset_rules:
        if rule.matches(relative_path):
            data = merge_recipe_data(data, dict(rule.override))
            matched = True
    if not matched and not recipe.assets:
        return recipe
    merged = validate(data, recipe.label, recipe.source, recipe._lines, path_prefix=())
    merged._cli = dict(recipe._cli)
    return merged


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
    labels: dict[KeyPath, str] = {}
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
        new = validate(data, recipe.label, recipe.source, {}, error_lines=False)
    except LocatedError as exc:
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
