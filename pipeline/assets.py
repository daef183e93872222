"""The assets of a batch: which meshes, where their outputs go, and which recipe each one gets.

    discover (every OBJ/PLY under the assets folder, sorted, relative POSIX keys; symlinks out of the
    folder not followed) -> select (--include/--exclude globs) -> output_folders (a folder per asset
    under OUT, deterministic) -> resolve_recipe (base <- [[assets]] rules <- sidecar NAME.toml).

`AssetRecipe` is what a worker is sent to rebuild an asset's merged recipe from the files.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from meshdeform.errors import RecipeError
from meshdeform.io import MESH_SUFFIXES  # the suffixes a batch picks up (case-insensitive)

#: why `discover` did not follow a symlink (the manifest's "reason" of its "skipped" entry)
OUTSIDE_LINK = "symlink to a path outside the assets folder"


# -- globs -------------------------------------------------------------------------------------


def glob_match(pattern: str, relative: str) -> bool:
    """Does the asset path `relative` (POSIX, relative to the assets folder) match `pattern`?

    The same rule as the recipe's [[assets]] globs (`pipeline.recipe.AssetRule.matches`): fnmatch
    on the whole relative path, and a pattern without "/" also matches the file name alone.
    """
    from pipeline.recipe import AssetRule

    return AssetRule(pattern.strip().removeprefix("./"), {}).matches(relative)


# -- discovery ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Asset:
    """One mesh of the batch.

    key: its path relative to the assets folder, POSIX (the manifest's `input`).
    path: absolute path of the mesh file.
    output: its output folder relative to OUT (POSIX): the key without suffix, or with it when
        two assets would share a folder (`note` then says so).
    """

    key: str
    path: Path
    output: str
    note: str | None = None


def _sort_key(relative: str) -> tuple[str, ...]:
    return tuple(relative.split("/"))


@dataclass(frozen=True)
class Discovery:
    """What `discover` found under an assets folder.

    keys: relative POSIX paths of the meshes, sorted folder by folder.
    skipped: symlinks not followed, relative path (a folder's with a trailing "/") -> why.
    """

    keys: list[str]
    skipped: dict[str, str]


def _inside(path: Path, real_root: Path) -> bool:
    """Does `path`, symlinks resolved (loops included: realpath stops on them), lie in `real_root`?"""
    return Path(os.path.realpath(path)).is_relative_to(real_root)


def discover(root: Path) -> Discovery:
    """Every .obj/.ply under `root`, hidden names left out.

    Symlinks are not followed out of the folder: a linked mesh or folder whose target lies outside
    `root` is `skipped` with the reason. A linked mesh inside `root` is an asset under the link's name;
    a linked folder is never entered (a target inside `root` is searched under its own path anyway, so
    no loop and no asset twice).
    """
    root = Path(root)
    real_root = Path(os.path.realpath(root))
    found: list[str] = []
    skipped: dict[str, str] = {}
    for folder, dirs, files in os.walk(root):  # followlinks=False: linked folders are listed, never entered
        here = Path(folder)
        kept = []
        for name in dirs:
            if name.startswith("."):
                continue
            if not (here / name).is_symlink():
                kept.append(name)
            elif not _inside(here / name, real_root):
                skipped[(here / name).relative_to(root).as_posix() + "/"] = OUTSIDE_LINK
        dirs[:] = kept
        for name in files:
            if name.startswith(".") or not name.lower().endswith(MESH_SUFFIXES):
                continue
            key = (here / name).relative_to(root).as_posix()
            if (here / name).is_symlink() and not _inside(here / name, real_root):
                skipped[key] = OUTSIDE_LINK
            else:
                found.append(key)
    return Discovery(sorted(found, key=_sort_key), dict(sorted(skipped.items(), key=lambda kv: _sort_key(kv[0]))))


def select(keys: Sequence[str], include: Sequence[str] = (), exclude: Sequence[str] = ()) -> list[str]:
    """Keys matching any --include (all when none is given) and no --exclude."""
    return [
        key
        for key in keys
        if (not include or any(glob_match(p, key) for p in include)) and not any(glob_match(p, key) for p in exclude)
    ]


def output_folders(keys: Sequence[str]) -> dict[str, tuple[str, str | None]]:
    """Output folder (relative, POSIX) and note for each key: the key without its suffix, unless that
    folder would be shared (`a.obj` and `a.ply`, or names equal but for case): then every asset of the
    clash keeps its suffix (`a.obj/`, `a.ply/`); or unless it would contain another asset's folder
    (`a.obj` beside a folder `a/` of assets: replacing `a/` would delete theirs): then it keeps its
    suffix. Deterministic: it depends on the set of keys only."""
    full = {key: False for key in keys}  # True: this key keeps its suffix
    holders: dict[str, str] = {}  # the folder that would hold another asset's folder -> that asset
    while True:
        names = {key: key if keep else str(PurePosixPath(key).with_suffix("")) for key, keep in full.items()}
        groups: dict[str, list[str]] = {}
        for key, name in names.items():
            groups.setdefault(name.casefold(), []).append(key)
        clashes = [group for group in groups.values() if len(group) > 1 and not all(full[k] for k in group)]
        parents: dict[str, str] = {}  # every folder above an output folder -> the first asset below it
        for key in sorted(names, key=_sort_key):
            for parent in PurePosixPath(names[key]).parents:
                parents.setdefault(str(parent).casefold(), key)
        nesting = [key for key, name in names.items() if not full[key] and name.casefold() in parents]
        if not clashes and not nesting:
            break
        for group in clashes:
            for key in group:
                full[key] = True
        for key in nesting:
            full[key] = True
            holders.setdefault(key, parents[names[key].casefold()])
    result: dict[str, tuple[str, str | None]] = {}
    for key in keys:
        note = None
        if full[key]:
            plain = str(PurePosixPath(key).with_suffix(""))
            others = sorted(
                k for k in keys if k != key and str(PurePosixPath(k).with_suffix("")).casefold() == plain.casefold()
            )
            if others or key not in holders:
                note = f"output folder keeps the suffix: {', '.join([key, *others])} would share {plain}/"
            else:
                note = f"output folder keeps the suffix: {plain}/ would hold the output folder of {holders[key]}"
        result[key] = (names[key], note)
    return result


# -- recipes -------------------------------------------------------------------------------------


def load_base_recipe(path: Path) -> Any:
    """Load and validate the batch's recipe (with its [[assets]] rules); RecipeError is a usage error."""
    from pipeline.recipe import load_recipe

    return load_recipe(path)


def sidecar_path(mesh: Path) -> Path:
    """`NAME.toml` next to `NAME.obj` / `NAME.ply`: that asset's own recipe overrides."""
    return mesh.with_suffix(".toml")


def resolve_recipe(base: Any, asset: Asset) -> tuple[Any, list[str]]:
    """The merged recipe of one asset and the layers applied over the base, in order.

    base <- every matching [[assets]] rule in recipe order (`Recipe.for_asset`) <- the sidecar
    `NAME.toml`. Tables merge deeply, arrays replace. Raises RecipeError naming the file when a
    layer is invalid (the asset then fails alone).
    """
    layers = [
        f"[[assets]] #{n} {rule.glob!r}" for n, rule in enumerate(base.asset_rules, start=1) if rule.matches(asset.key)
    ]
    recipe = base.for_asset(asset.key)
    sidecar = sidecar_path(asset.path)
    if not sidecar.is_file() or (base.source is not None and sidecar.resolve() == Path(base.source).resolve()):
        return recipe, layers
    assets_root = Path(os.path.realpath(asset.path.parents[len(PurePosixPath(asset.key).parts) - 1]))
    if not Path(os.path.realpath(sidecar)).is_relative_to(assets_root):
        raise RecipeError(f"{sidecar}: sidecar recipe is a symlink to a path outside the assets folder; not read")
    recipe = apply_sidecar(recipe, sidecar)
    return recipe, [*layers, f"sidecar {sidecar.name}"]


@functools.lru_cache(maxsize=8)
def _load_cached(path: str, mtime_ns: int, size: int) -> Any:
    return load_base_recipe(Path(path))


@dataclass(frozen=True)
class AssetRecipe:
    """How a worker rebuilds one asset's merged recipe: the batch recipe's path, the asset's key and
    mesh path: rebuilding from the files keeps every error's file, key path and line (and a small
    task to send). The base is parsed once per worker."""

    base: str
    key: str
    mesh: str

    def load(self) -> Any:
        stat = os.stat(self.base)
        base = _load_cached(self.base, stat.st_mtime_ns, stat.st_size)
        return resolve_recipe(base, Asset(key=self.key, path=Path(self.mesh), output=""))[0]


def apply_sidecar(recipe: Any, sidecar: Path) -> Any:
    """`recipe` with a sidecar file merged over it. The sidecar is first validated alone, so its
    mistakes are reported with its own name, key path and line; relative paths in it (mesh
    colliders) are, as in [[assets]] rules, relative to the batch recipe."""
    from pipeline import recipe as recipe_module

    try:
        text = sidecar.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecipeError(f"{sidecar}: cannot read sidecar recipe: {exc}") from None
    partial = recipe_module.parse_recipe(text, str(sidecar))
    if partial.assets:
        raise RecipeError(f"{sidecar}: [[assets]] rules belong in the batch recipe, not in a sidecar")
    data = recipe_module.merge_recipe_data(recipe.raw, partial.raw)
    label = f"{recipe.label} + {sidecar}"
    # no line numbers: the keys come from two files; the message names both and the key path
    return recipe_module.recipe_from_data(data, label, recipe.source)
