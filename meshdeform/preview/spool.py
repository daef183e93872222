"""Arrays a run's previews keep until they are rendered: in memory up to a budget, the rest in a scratch file.

A run's previews are rendered once its last frame is known (the camera and colour range are the whole
sequence's: `meshdeform.preview.live`), so the frames to render are kept until then: every frame when
there is a video. `ArraySpool` holds them in memory while they fit in `budget` bytes and appends the rest
to one hidden scratch file in the folder given (a run's staging folder, on the disk its outputs go to),
read back one array at a time; `close` deletes the file. The bytes read back are the bytes put.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Hashable, Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

#: bytes of kept arrays a run's previews hold in memory before they go to the scratch file (512 MiB)
MEMORY_BUDGET = 512 * 2**20


class ArraySpool:
    """Arrays by key: `put`, `spool[key]` (a fresh array), `close`. folder: where the scratch file goes
    (`.preview-spool-*.tmp`, made on the first array past the budget); budget: bytes held in memory."""

    def __init__(self, folder: str | Path, budget: int = MEMORY_BUDGET) -> None:
        self.folder = Path(folder)
        self.budget = int(budget)
        #: bytes held in memory / written to the scratch file
        self.memory_bytes = 0
        self.file_bytes = 0
        self._memory: dict[Hashable, np.ndarray] = {}
        self._spilled: dict[Hashable, tuple[int, np.dtype, tuple[int, ...]]] = {}
        self._file: BinaryIO | None = None
        self.path: Path | None = None

    def put(self, key: Hashable, array: np.ndarray) -> None:
        """Keep a copy of `array` under `key` (a key put again replaces the array it held)."""
        self.discard(key)
        array = np.ascontiguousarray(array)
        if self.memory_bytes + array.nbytes <= self.budget:
            self._memory[key] = array.copy()
            self.memory_bytes += array.nbytes
            return
        if self._file is None:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.path = self.folder / f".preview-spool-{uuid.uuid4().hex}.tmp"
            self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by `close`)
        self._file.seek(0, os.SEEK_END)
        offset = self._file.tell()
        self._file.write(array.tobytes())
        self._spilled[key] = (offset, array.dtype, array.shape)
        self.file_bytes += array.nbytes

    def discard(self, key: Hashable) -> None:
        """Forget `key` (its bytes in the scratch file stay until `close`)."""
        if key in self._memory:
            self.memory_bytes -= self._memory.pop(key).nbytes
        self._spilled.pop(key, None)

    def __contains__(self, key: object) -> bool:
        return key in self._memory or key in self._spilled

    def __getitem__(self, key: Hashable) -> np.ndarray:
        if key in self._memory:
            return self._memory[key].copy()
        offset, dtype, shape = self._spilled[key]
        assert self._file is not None
        out = np.empty(shape, dtype=dtype)
        self._file.seek(offset)
        if self._file.readinto(memoryview(out).cast("B")) != out.nbytes:
            raise OSError(f"{self.path}: the preview scratch file is shorter than what was written to it")
        return out

    def __len__(self) -> int:
        return len(self._memory) + len(self._spilled)

    def __iter__(self) -> Iterator[Hashable]:
        yield from self._memory
        yield from self._spilled

    def close(self) -> None:
        """Drop every array and delete the scratch file."""
        self._memory.clear()
        self._spilled.clear()
        self.memory_bytes = 0
        if self._file is not None:
            with contextlib.suppress(OSError):
                self._file.close()
            self._file = None
        if self.path is not None:
            with contextlib.suppress(OSError):
                self.path.unlink()
            self.path = None

    def __enter__(self) -> ArraySpool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
