"""`recipe_hash`: the identity of a recipe for deciding whether a previous result is up to date."""

from __future__ import annotations

import hashlib
import json

from pipeline.recipe.document import Recipe, resolve_path


def recipe_hash(recipe: Recipe) -> str:
    """sha256 of the normalised recipe (defaults filled in, key order irrelevant) plus the contents
    of files it references (mesh colliders), so a changed collider file changes the hash."""
    content = recipe.model_dump(mode="json", by_alias=True, exclude={"source"})
    digest = hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    for collider in recipe.colliders:
        if collider.mesh is not None:
            path = resolve_path(recipe, collider.mesh.path)
            try:
                digest.update(hashlib.sha256(path.read_bytes()).digest())
            except OSError:
                digest.update(b"missing:" + collider.mesh.path.encode("utf-8"))
    return digest.hexdigest()
