"""The README and docs/recipes.md name exactly what the registries hold: formats, solvers, defaults.

Each check reads the lists out of the prose and tables a user reads and compares them with
`meshdeform.export.EXPORTERS` and `meshdeform.solvers.SOLVERS`, so that adding, removing or
renaming a format or solver without its documentation fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshdeform.export
from meshdeform.export import EXPORTERS
from meshdeform.solvers import SOLVERS
from pipeline.recipe.load import DEFAULT_SOLVER

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
RECIPES = (ROOT / "docs" / "recipes.md").read_text(encoding="utf-8")

FIXED = {name for name, cls in EXPORTERS.items() if not cls.supports_topology_change}


def quoted(text: str) -> list[str]:
    """The `backticked` words of `text`, in order."""
    return re.findall(r"`([^`]+)`", text)


def table_row(doc: str, key: str) -> list[str]:
    """The cells of the first table row whose first cell is `key` (backticked)."""
    row = next(line for line in doc.splitlines() if line.startswith(f"| `{key}` |"))
    return [cell.strip() for cell in row.strip("|").split("|")]


def sentence(doc: str, pattern: str) -> str:
    """What `pattern`'s group matches in `doc` with its line breaks read as spaces."""
    found = re.search(pattern, " ".join(doc.split()))
    assert found, pattern
    return found.group(1)


def test_the_output_table_lists_every_registered_format() -> None:
    meaning = table_row(RECIPES, "formats")[3]
    assert set(quoted(meaning.split(";")[0])) == set(EXPORTERS)


def test_the_readme_recipe_summary_lists_every_registered_format() -> None:
    listed = sentence(README, r"\[output\] # formats = \[([^\]]*)\]")
    assert {name.strip().strip('"') for name in listed.split(",")} == set(EXPORTERS)


def test_the_formats_said_to_refuse_tearing_are_those_with_a_fixed_topology() -> None:
    assert set(quoted(sentence(README, r"a recipe that tears is refused for (.+?) before anything"))) == FIXED
    assert set(quoted(sentence(RECIPES, r"Point caches (.+?) cannot hold a mesh that gains"))) == FIXED


def test_the_export_package_table_has_a_row_per_format_saying_whether_it_follows_a_tear() -> None:
    table = (meshdeform.export.__doc__ or "").split("|---|", 1)[1].split("\n\n", 1)[0]
    rows = [line.strip("|").split("|") for line in table.splitlines() if line.startswith("| ")]
    assert [cells[0].strip() for cells in rows] == list(EXPORTERS)
    assert {cells[0].strip() for cells in rows if cells[2].strip().startswith("refused")} == FIXED


def test_the_readme_solver_table_lists_every_registered_solver_and_marks_the_default() -> None:
    section = README.split("## Solvers", 1)[1].split("\n## ", 1)[0]
    names = [line.split("|")[1].strip() for line in section.splitlines() if line.startswith("| `")]
    assert {quoted(name)[0] for name in names} == set(SOLVERS)
    assert [quoted(name)[0] for name in names if "(default)" in name] == [DEFAULT_SOLVER]


def test_the_recipe_docs_and_the_readme_summary_list_every_registered_solver() -> None:
    cells = table_row(RECIPES, "solver")
    assert cells[2] == f'`"{DEFAULT_SOLVER}"`'
    assert set(quoted(cells[3].split("(")[0])) == set(SOLVERS)
    listed = sentence(README, r"\[simulation\] # solver = ([a-z |]+);")
    assert {name.strip() for name in listed.split("|")} == set(SOLVERS)
