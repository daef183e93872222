"""Typed errors of the engine: the library raises these and never prints or exits.

The CLI turns each into one line on stderr and an exit code at the edge.
"""

from __future__ import annotations


class MeshdeformError(Exception):
    """Base of every error meshdeform raises on purpose."""


class MeshLoadError(MeshdeformError):
    """A mesh file cannot be read: the message names the file, the place in it and what is wrong."""


class RecipeError(MeshdeformError):
    """A recipe is invalid: the message names the file, the key path and, where known, the line."""


class SelectionError(RecipeError):
    """A selection is malformed or selects no vertex."""


class SimulationDiverged(MeshdeformError):
    """Positions became non-finite or ran away; carries the frame it happened on."""

    def __init__(self, message: str, frame: int, solver: str) -> None:
        super().__init__(message)
        self.frame = frame
        self.solver = solver


class ExportError(MeshdeformError):
    """An output cannot be written (unsupported combination, I/O failure)."""
