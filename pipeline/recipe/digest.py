"""`recipe_hash`: the identity of a recipe for deciding whether a previous result is up to date."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from meshdeform.io.caches import cache_files
from pipeline.recipe.document import Recipe, resolve_path
from pipeline.recipe.schema import UsdOutputSpec
from pipeline.recipe.solver_options import all_options, flat_options


def recipe_hash(recipe: Recipe) -> str:
    """sha256 of the normalised recipe (defaults filled in, key order irrelevant) plus the contents
    of files it references (mesh colliders), so a changed collider file changes the hash.

    In the normal form the options of the solver in force are keys of `simulation`, one for every
    option of any registered solver (None when not given), and the other solvers' tables are left
    out, in [[assets]] rules too: the shape recipes had before `[simulation.<solver>]`, so a recipe
    whose options moved into tables keeps its hash (and a batch its finished assets). Exporter tables
    added since (`[output.usd]`) are left out when absent or at their defaults (the same files), so
    results made before them keep their hash.
    """
    content = recipe.model_dump(mode="json", by_alias=True, exclude={"source"})
    if recipe.output.usd is None or recipe.output.usd == UsdOutputSpec():
        content["output"].pop("usd", None)
    given = recipe.simulation.given_options()
    content["simulation"].update({option: given.get(option) for option in all_options()})
    for rule in content["assets"]:
        if rule["simulation"] is not None:
            solver = rule["simulation"].get("solver", recipe.simulation.solver)
            rule["simulation"] = flat_options(rule["simulation"], solver)
    digest = hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    add_collider_files(digest, recipe)
    return digest.hexdigest()


def add_collider_files(digest: hashlib._Hash, recipe: Recipe) -> None:
    """Feed `digest` the contents of the files the recipe's colliders are built from: each mesh
    collider's mesh and, for a deforming body, every file of its point cache (`cache_files`, by name
    and contents), so a result made with other files is not taken for up to date. A file that cannot
    be read counts by its path."""
    base = recipe.source.parent if recipe.source is not None else Path.cwd()
    for collider in recipe.colliders:
        if collider.mesh is None:
            continue
        path = resolve_path(recipe, collider.mesh.path)
        try:
            digest.update(hashlib.sha256(path.read_bytes()).digest())
        except OSError:
            digest.update(b"missing:" + collider.mesh.path.encode("utf-8"))
        if collider.mesh.cache is None:
            continue
        files = cache_files(collider.mesh.cache, base)
        if not files:
            digest.update(b"missing cache:" + collider.mesh.cache.encode("utf-8"))
        for file in files:
            try:
                digest.update(file.name.encode("utf-8") + hashlib.sha256(file.read_bytes()).digest())
            except OSError:
                digest.update(b"missing:" + file.name.encode("utf-8"))
