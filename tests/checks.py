"""Checks the tests share: what a refused input must look like.

Plain functions beside conftest.py, imported by name (`from checks import refused`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from meshdeform.errors import MeshLoadError
from meshdeform.io import load


def one_line_about(path: Path, error: BaseException) -> str:
    """The text of `error`, checked to be one line that starts with the path it is about."""
    text = str(error)
    assert text.startswith(f"{path}: ") and "\n" not in text, text
    return text


def refused(path: Path, message: str | None = None, *, read: Callable[[Path], object] = load) -> str:
    """The error `read` refuses the file `path` with: a MeshLoadError matching the regular expression
    `message` (any, if None), in one line that starts with the path (`one_line_about`)."""
    with pytest.raises(MeshLoadError, match=message) as info:
        read(path)
    return one_line_about(path, info.value)


def reader_kinds() -> list[tuple[object, tuple[str, ...]]]:
    """Each kind of result files previews read back, as (its `ResultReading`, the registered formats that
    write those files), in search order, from the export registry."""
    from meshdeform.export import EXPORTERS
    from meshdeform.preview.results import search_order

    def writers(looks_for: str) -> tuple[str, ...]:
        return tuple(n for n, cls in EXPORTERS.items() if (r := cls.reading()) is not None and r.looks_for == looks_for)

    return [(reading, writers(reading.looks_for)) for reading in search_order()]
