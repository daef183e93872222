"""The sha256 of a file, as the reports, the manifest and the batch's resume check record it.

Standard library only: pool and Dask workers import it without loading the engine (their thread
counts are set before the engine is imported, `pipeline.executors`).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

#: bytes read at a time (1 MiB): a large mesh is hashed without being held in memory
CHUNK_BYTES = 1 << 20


def file_sha256(path: Path | str) -> str:
    """Hex sha256 of a file's bytes, read in chunks; raises OSError when it cannot be read."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(CHUNK_BYTES), b""):
            digest.update(chunk)
    return digest.hexdigest()
