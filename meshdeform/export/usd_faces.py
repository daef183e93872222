"""The input's face sets and names as a USD stage carries them: OBJ `g`, `o` and `usemtl` as GeomSubsets
and placeholder materials, prim names valid and unique with the original kept as `displayName`.

- `face_sets(mesh)`: the faces of each OBJ group (`g`), object (`o`) and material (`usemtl`), replayed from
  `Mesh.statements` (each recorded with the number of faces before it, so a statement's name holds the
  faces up to the next statement of its kind); a mesh with `groups` but no statements (built in code)
  has them as groups. Face indices are those of the mesh's face list, which the USD writer keeps as it is
  (polygons are not triangulated), so they index the USD face list too.
- `family_type`: the GeomSubset family type a family's sets allow ("partition": every face in exactly
  one; "nonOverlapping": no face in two; else "unrestricted").
- `prim_identifier` / `unique_identifiers`: names USD accepts as prim names (`Tf.MakeValidIdentifier`, a
  leading digit kept behind "_"), distinct among siblings ("name", "name_1", ...).
- `author_face_sets`: the subsets and materials on a `UsdGeom.Mesh` (families "group" and "object",
  `/Root/Materials/<name>` with a UsdPreviewSurface each, bound directly when the mesh uses one material
  for every face, else per material through subsets of family "materialBind").
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from meshdeform.mesh import Mesh

#: GeomSubset family names of the OBJ statements
GROUP_FAMILY = "group"
OBJECT_FAMILY = "object"
#: where the placeholder materials go, under the default prim
MATERIALS_SCOPE = "Materials"
#: the placeholder's UsdPreviewSurface diffuseColor (linear 18% grey: Blender's and USD's neutral default)
PLACEHOLDER_COLOR = (0.18, 0.18, 0.18)


@dataclass(frozen=True)
class FaceSets:
    """name -> face indices (sorted int64) of the OBJ groups, objects and materials, in order of first
    appearance; names whose statements hold no face are left out."""

    groups: dict[str, np.ndarray] = field(default_factory=dict)
    objects: dict[str, np.ndarray] = field(default_factory=dict)
    materials: dict[str, np.ndarray] = field(default_factory=dict)


def _statement_names(keyword: str, text: str) -> tuple[str, ...] | None:
    """The names a `g` (several, space-separated), `o` or `usemtl` line (one: the rest of the line) sets,
    () for none (a bare `g`: the default group); None when `text` is not a `keyword` statement."""
    parts = text.split()
    if not parts or parts[0] != keyword:
        return None
    if keyword == "g":
        return tuple(dict.fromkeys(parts[1:]))
    rest = " ".join(parts[1:])
    return (rest,) if rest else ()


def _replay(statements: Sequence[tuple[int, str]], keyword: str, face_count: int) -> dict[str, np.ndarray]:
    """name -> faces of the `keyword` statements: each statement's names hold the faces from its face
    count to the next statement of the same keyword (the last: to the end)."""
    marks = [(count, names) for count, text in statements if (names := _statement_names(keyword, text)) is not None]
    ranges: dict[str, list[np.ndarray]] = {}
    for k, (start, names) in enumerate(marks):
        end = marks[k + 1][0] if k + 1 < len(marks) else face_count
        for name in names:
            ranges.setdefault(name, [])
            if end > start:
                ranges[name].append(np.arange(start, end, dtype=np.int64))
    return {name: np.unique(np.concatenate(parts)) for name, parts in ranges.items() if parts}


def face_sets(mesh: Mesh) -> FaceSets:
    """The groups, objects and materials of `mesh` (`FaceSets`), from its OBJ statements, or its `groups`
    as groups when it has no `g`/`o` statements."""
    statements = list(mesh.statements)
    groups = _replay(statements, "g", mesh.face_count)
    objects = _replay(statements, "o", mesh.face_count)
    if not groups and not objects and mesh.groups:
        groups = {
            name: np.unique(np.asarray(faces, dtype=np.int64)) for name, faces in mesh.groups.items() if np.size(faces)
        }
    return FaceSets(groups=groups, objects=objects, materials=_replay(statements, "usemtl", mesh.face_count))


def family_type(sets: Iterable[np.ndarray], face_count: int) -> str:
    """ "partition" when the sets hold every one of `face_count` faces exactly once, "nonOverlapping" when
    no face is in two, else "unrestricted" (the UsdGeom.Subset family types)."""
    listed = [np.asarray(s, dtype=np.int64) for s in sets]
    counts = np.bincount(np.concatenate(listed), minlength=face_count) if listed else np.zeros(face_count, np.int64)
    if counts.size and counts.max() > 1:
        return "unrestricted"
    return "partition" if counts.size and bool((counts == 1).all()) else "nonOverlapping"


def mesh_name(mesh: Mesh, sets: FaceSets | None = None) -> str:
    """The name of the mesh as Blender's OBJ importer names its object: the OBJ object's (`o`) when there
    is exactly one and it holds every face, else the file's stem ("mesh" without a file)."""
    sets = face_sets(mesh) if sets is None else sets
    if len(sets.objects) == 1:
        ((name, faces),) = sets.objects.items()
        if faces.shape[0] == mesh.face_count:
            return name
    return mesh.source.stem if mesh.source is not None else "mesh"


def prim_identifier(name: str) -> str:
    """A valid prim name for `name`: characters other than ASCII letters, digits and "_" become "_"
    (`Tf.MakeValidIdentifier`), a leading digit is kept behind "_" ("0" -> "_0"), "" is "_"."""
    from pxr import Tf

    return Tf.MakeValidIdentifier(f"_{name}" if name[:1].isdigit() else name)


def unique_identifiers(names: Iterable[str], taken: set[str]) -> list[str]:
    """`prim_identifier` of each name, made distinct from each other and from `taken` (which is updated)
    by "_1", "_2", ... suffixes, in order."""
    out = []
    for name in names:
        base = prim_identifier(name)
        candidate, n = base, 0
        while candidate in taken:
            n += 1
            candidate = f"{base}_{n}"
        taken.add(candidate)
        out.append(candidate)
    return out


def _int_array(faces: np.ndarray) -> Any:
    from pxr import Vt

    return Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, dtype=np.int32))


def _placeholder_material(stage: Any, path: str, name: str) -> Any:
    """A `UsdShade.Material` named after an OBJ material: one UsdPreviewSurface, grey (no MTL is read)."""
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    material.GetPrim().SetDisplayName(name)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*PLACEHOLDER_COLOR))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.5)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def author_face_sets(stage: Any, geom: Any, root: str, sets: FaceSets, face_count: int) -> None:
    """Author `sets` on the `UsdGeom.Mesh` `geom` (of `face_count` faces) in `stage`'s edit target:
    GeomSubsets of element type "face" in families "group" and "object" (each with the family type its sets
    allow) and the materials under `root`/Materials, bound to the mesh directly when one material holds
    every face, else through one "materialBind" subset per material."""
    from pxr import UsdGeom, UsdShade

    prim = geom.GetPrim()
    taken = {child.GetName() for child in prim.GetChildren()}
    for family, named in ((GROUP_FAMILY, sets.groups), (OBJECT_FAMILY, sets.objects)):
        if not named:
            continue
        kind = family_type(named.values(), face_count)
        for (name, faces), identifier in zip(named.items(), unique_identifiers(named, taken), strict=True):
            subset = UsdGeom.Subset.CreateGeomSubset(
                geom, identifier, UsdGeom.Tokens.face, _int_array(faces), family, kind
            )
            subset.GetPrim().SetDisplayName(name)
    if not sets.materials:
        return
    scope = f"{root}/{MATERIALS_SCOPE}"
    UsdGeom.Scope.Define(stage, scope)
    materials = {
        name: _placeholder_material(stage, f"{scope}/{identifier}", name)
        for name, identifier in zip(sets.materials, unique_identifiers(sets.materials, set()), strict=True)
    }
    binding = UsdShade.MaterialBindingAPI.Apply(prim)
    if len(materials) == 1 and next(iter(sets.materials.values())).shape[0] == face_count:
        binding.Bind(next(iter(materials.values())))
        return
    subset_names = unique_identifiers(sets.materials, taken)
    for (name, faces), identifier in zip(sets.materials.items(), subset_names, strict=True):
        subset = binding.CreateMaterialBindSubset(identifier, _int_array(faces), UsdGeom.Tokens.face)
        subset.GetPrim().SetDisplayName(name)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[name])
    binding.SetMaterialBindSubsetsFamilyType(family_type(sets.materials.values(), face_count))
