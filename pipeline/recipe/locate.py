"""The line of every key in a recipe's TOML text.

tomllib parses without positions, so `Locator` scans the text (already known to be valid TOML)
once and records the line of every table header, key and array element by its key path; a
recipe error then names the line of the key it is about (or of its nearest enclosing key).
"""

from __future__ import annotations

import contextlib
import json
from bisect import bisect_right
from collections.abc import Sequence

from pipeline.recipe.messages import KeyPath

_BARE = set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")


def key_lines(text: str) -> dict[KeyPath, int]:
    """Key path -> line (from 1) of every table header, key and array element of valid TOML text."""
    return Locator(text).lines


class Locator:
    """Finds the line of every table header, key and array element of a TOML text (already valid)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.pos = 0
        self.lines: dict[KeyPath, int] = {}
        self.aot: dict[KeyPath, int] = {}
        self.starts = [0] + [i + 1 for i, c in enumerate(text) if c == "\n"]
        with contextlib.suppress(IndexError, ValueError):  # best effort: keep what was found
            self._document()

    def line(self, offset: int) -> int:
        return bisect_right(self.starts, offset)

    def _record(self, path: KeyPath, offset: int) -> None:
        self.lines.setdefault(path, self.line(offset))

    def _skip(self, newlines: bool = True) -> None:
        t = self.text
        while self.pos < len(t):
            c = t[self.pos]
            if c in " \t\r" or (newlines and c == "\n"):
                self.pos += 1
            elif c == "#":
                while self.pos < len(t) and t[self.pos] != "\n":
                    self.pos += 1
            else:
                break

    def _string(self) -> str:
        t = self.text
        for quote in ('"""', "'''"):
            if t.startswith(quote, self.pos):
                end = t.index(quote, self.pos + 3)
                while t.startswith(quote[0], end + 3):
                    end += 1
                value = t[self.pos + 3 : end]
                self.pos = end + 3
                return value
        q = t[self.pos]
        i = self.pos + 1
        out = []
        while t[i] != q:
            if q == '"' and t[i] == "\\":
                out.append(t[i : i + 2])
                i += 2
                continue
            out.append(t[i])
            i += 1
        self.pos = i + 1
        raw = "".join(out)
        return json.loads(f'"{raw}"') if q == '"' else raw

    def _key(self) -> list[str]:
        keys = []
        t = self.text
        while True:
            self._skip(newlines=False)
            if t[self.pos] in "\"'":
                keys.append(self._string())
            else:
                start = self.pos
                while t[self.pos] in _BARE:
                    self.pos += 1
                keys.append(t[start : self.pos])
            self._skip(newlines=False)
            if t[self.pos] == ".":
                self.pos += 1
                continue
            return keys

    def _resolve(self, keys: Sequence[str]) -> KeyPath:
        path: KeyPath = ()
        for k in keys:
            path = (*path, k)
            if path in self.aot:
                path = (*path, self.aot[path] - 1)
        return path

    def _document(self) -> None:
        t = self.text
        current: KeyPath = ()
        while True:
            self._skip()
            if self.pos >= len(t):
                return
            start = self.pos
            if t.startswith("[[", self.pos):
                self.pos += 2
                keys = self._key()
                self.pos += 2
                parent = self._resolve(keys[:-1])
                array = (*parent, keys[-1])
                self.aot[array] = self.aot.get(array, 0) + 1
                current = (*array, self.aot[array] - 1)
                for n in range(1, len(current) + 1):
                    self._record(current[:n], start)
            elif t[self.pos] == "[":
                self.pos += 1
                keys = self._key()
                self.pos += 1
                current = self._resolve(keys)
                for n in range(1, len(current) + 1):
                    self._record(current[:n], start)
            else:
                self._keyval(current)

    def _keyval(self, prefix: KeyPath) -> None:
        start = self.pos
        keys = self._key()
        self.pos += 1  # '='
        path = (*prefix, *keys)
        for n in range(len(prefix) + 1, len(path) + 1):
            self._record(path[:n], start)
        self._value(path)

    def _value(self, path: KeyPath) -> None:
        t = self.text
        self._skip(newlines=False)
        c = t[self.pos]
        if c == "{":
            self.pos += 1
            while True:
                self._skip()
                if t[self.pos] == "}":
                    self.pos += 1
                    return
                if t[self.pos] == ",":
                    self.pos += 1
                    continue
                self._keyval(path)
        elif c == "[":
            self.pos += 1
            i = 0
            while True:
                self._skip()
                if t[self.pos] == "]":
                    self.pos += 1
                    return
                if t[self.pos] == ",":
                    self.pos += 1
                    continue
                self._record((*path, i), self.pos)
                self._value((*path, i))
                i += 1
        elif c in "\"'":
            self._string()
        else:
            while self.pos < len(t) and t[self.pos] not in ",]}\n#":
                self.pos += 1
