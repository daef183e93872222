"""`OUT/manifest.json`: one entry per asset of a batch, rewritten atomically as assets finish.

The manifest is the batch's account for people and scripts (what ran, what failed and why,
where the outputs are). Resuming does not depend on it: the per-asset `report.json`, renamed into
place together with the outputs, is what a rerun trusts. So a crash between an asset finishing
and the next manifest write loses nothing.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from meshdeform.atomic import write_text_atomic

#: version of the manifest layout below; bumped when a key changes meaning
MANIFEST_VERSION = 1
MANIFEST_NAME = "manifest.json"
#: per-asset statuses; "pending" = not finished in this run (still running, or interrupted)
STATUSES = ("ok", "failed", "skipped", "pending")
#: keys of the manifest that hold wall-clock timings (dropped when comparing two runs)
MANIFEST_TIMING_KEYS = ("seconds", "total_seconds")


def new_entry(
    key: str,
    output: str | None,
    *,
    version: str,
    overrides: Iterable[str] = (),
    note: str | None = None,
    status: str = "pending",
    reason: str | None = None,
) -> dict[str, Any]:
    """An entry for asset `key` (its path relative to the assets folder), pending unless told.

    `output` is None for what has no output folder (a symlink the batch did not follow); `reason`
    says why an entry is "skipped" ("up to date", "symlink to a path outside the assets folder").
    """
    return {
        "input": key,
        "output": output,
        "status": status,
        "reason": reason,
        "error": None,
        "error_type": None,
        "outputs": [],
        "frames": None,
        "seconds": None,
        "input_sha256": None,
        "recipe_sha256": None,
        "version": version,
        "overrides": list(overrides),
        "note": note,
    }


class Manifest:
    """The entries of one batch, in discovery order, written to `OUT/manifest.json` atomically.

    `write()` is throttled to one write per `interval` seconds; what it held back is written by
    the next `flush_if_due()` (called on progress events) or forced write. Entries of assets
    that were not selected this time (`--include`/`--exclude`) but are still in the folder are
    carried over from the previous manifest with `"selected": false`.
    """

    def __init__(self, path: Path, header: dict[str, Any], interval: float = 0.2) -> None:
        self.path = Path(path)
        self.header = dict(header)
        self.entries: dict[str, dict[str, Any]] = {}
        self.carried: dict[str, dict[str, Any]] = {}
        self.complete = False
        self.total_seconds = 0.0
        self._interval = interval
        self._last_write = 0.0
        self._dirty = False

    def add(self, entry: dict[str, Any]) -> dict[str, Any]:
        self.entries[entry["input"]] = entry
        self._dirty = True
        return entry

    def update(self, key: str, **values: Any) -> dict[str, Any]:
        entry = self.entries[key]
        entry.update(values)
        self._dirty = True
        return entry

    def carry(self, entry: dict[str, Any]) -> None:
        """Keep a previous run's entry for an asset this run did not select."""
        self.carried[entry["input"]] = {**entry, "selected": False}
        self._dirty = True

    def summary(self) -> dict[str, Any]:
        counts = dict.fromkeys(STATUSES, 0)
        for entry in self.entries.values():
            counts[entry["status"]] += 1
        return {"assets": len(self.entries), **counts, "total_seconds": round(self.total_seconds, 3)}

    def to_dict(self) -> dict[str, Any]:
        merged = {**self.carried, **self.entries}
        order = sorted(merged, key=lambda k: tuple(k.split("/")))
        return {
            **self.header,
            "manifest_version": MANIFEST_VERSION,
            "complete": self.complete,
            "summary": self.summary(),
            "assets": [merged[k] for k in order],
        }

    def write(self, force: bool = False) -> None:
        """Write now if forced or the last write is older than the interval; else just remember."""
        self._dirty = True
        now = time.monotonic()
        if not force and now - self._last_write < self._interval:
            return
        write_text_atomic(self.path, json.dumps(self.to_dict(), indent=2, ensure_ascii=False) + "\n")
        self._last_write = now
        self._dirty = False

    def flush_if_due(self) -> None:
        """Write if something changed and the interval has passed (called on every progress event)."""
        if self._dirty and time.monotonic() - self._last_write >= self._interval:
            self.write(force=True)


def read_manifest(path: Path) -> dict[str, Any] | None:
    """A previous manifest, or None when absent or unreadable (a rerun then trusts report.json alone)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("assets"), list) else None


def drop_keys(value: Any, keys: Iterable[str]) -> Any:
    """A copy of a JSON value without the given keys at any depth (to compare runs minus timings)."""
    names = set(keys)
    if isinstance(value, dict):
        return {k: drop_keys(v, names) for k, v in value.items() if k not in names}
    if isinstance(value, list):
        return [drop_keys(v, names) for v in value]
    return value
