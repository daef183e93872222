"""`meshdeform inspect MESH`: counts of vertices, polygons, welded vertices, springs and defects."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from pipeline.commands.errors import cli_errors


def describe(path: Path) -> dict[str, Any]:
    """Everything `inspect` reports about a mesh file, as a JSON-ready dict."""
    import numpy as np

    from meshdeform.io import load
    from meshdeform.topology import build_springs, topology_stats

    mesh = load(path)
    welding, springs = build_springs(mesh)
    stats = topology_stats(mesh, welding, springs)
    sizes, counts = np.unique(mesh.face_sizes, return_counts=True) if mesh.face_count else ([], [])
    return {
        "file": str(path),
        "vertices": mesh.vertex_count,
        "faces": mesh.face_count,
        "polygon_sizes": {str(int(s)): int(c) for s, c in zip(sizes, counts, strict=True)},
        "lines": mesh.line_count,
        "welded_vertices": stats.welded_vertices,
        "unreferenced_vertices": stats.welded_vertices - stats.referenced_vertices,
        "springs": springs.counts(),
        "pieces": stats.pieces,
        "boundary_edges": stats.boundary_edges,
        "non_manifold_edges": stats.non_manifold_edges,
        "uvs": 0 if mesh.uvs is None else int(mesh.uvs.shape[0]),
        "normals": 0 if mesh.normals is None else int(mesh.normals.shape[0]),
        "groups": sorted(mesh.groups),
        "vertex_properties": sorted(mesh.vertex_properties),
        "bounds": [mesh.positions.min(axis=0).tolist(), mesh.positions.max(axis=0).tolist()]
        if mesh.vertex_count
        else None,
        "warnings": list(mesh.warnings),
    }


def _text(info: dict[str, Any]) -> str:
    sizes = ", ".join(f"{n} with {k} corners" for k, n in info["polygon_sizes"].items()) or "none"
    springs = info["springs"]
    lines = [
        f"{info['file']}",
        f"  vertices          {info['vertices']} ({info['welded_vertices']} welded, "
        f"{info['unreferenced_vertices']} unreferenced)",
        f"  faces             {info['faces']} ({sizes})",
        f"  lines             {info['lines']}",
        f"  springs           {sum(springs.values())}: structural {springs['structural']}, "
        f"shear {springs['shear']}, bending {springs['bending']}",
        f"  pieces            {info['pieces']}",
        f"  boundary edges    {info['boundary_edges']}",
        f"  non-manifold edges {info['non_manifold_edges']}",
        f"  uvs / normals     {info['uvs']} / {info['normals']}",
    ]
    if info["groups"]:
        lines.append(f"  groups            {', '.join(info['groups'])}")
    if info["vertex_properties"]:
        lines.append(f"  vertex properties {', '.join(info['vertex_properties'])}")
    lines += [f"  warning: {w}" for w in info["warnings"]]
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    @app.command()
    def inspect(
        mesh: Path = typer.Argument(..., help="An OBJ or PLY file."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of text."),
    ) -> None:
        """Print vertex, face, welded-vertex and spring counts, pieces, boundary and non-manifold edges."""
        with cli_errors():
            info = describe(mesh)
        typer.echo(json.dumps(info, indent=2) if as_json else _text(info))
