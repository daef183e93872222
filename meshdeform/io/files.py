"""What kind of file a path names, checked before it is opened.

Opening a named pipe for reading blocks until something writes into it, and a device or a socket
is no mesh or recipe either: readers ask `special_file_kind` first and refuse such paths with one
line instead of hanging.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path


def special_file_kind(path: str | os.PathLike[str]) -> str | None:
    """'a named pipe', 'a socket' or 'a device' when `path` (symlinks followed) is one, else None
    (a regular file, a folder, or nothing: the caller's open() reports those as usual)."""
    try:
        mode = os.stat(Path(path)).st_mode
    except OSError:
        return None
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return None
