"""Key paths and the one-line messages of recipe errors.

A key path names a value in the TOML document: `('pins', 0, 'select', 'box')`, written
`pins[0].select.box`. Every recipe error is one line, `<file>: <key.path> (line N): <what>`
(`message`); `describe` turns one pydantic validation error into the `<what>`, in TOML's words
(a table, an array, an integer) rather than Python's.
"""

from __future__ import annotations

import difflib
import json
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from pydantic import BaseModel

from meshdeform.errors import RecipeError

#: a key path: table keys (str) and array indices (int), from the document's root
KeyPath = tuple[str | int, ...]


def number(value: float) -> str:
    """A number for a message: integers in full, floats shortest (1e+12)."""
    if isinstance(value, int) or (value.is_integer() and abs(value) < 1e7):
        return str(int(value))
    return f"{value:g}"


def toml_type(value: Any) -> str:
    """The TOML name of a parsed value's type, for messages."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, list | tuple):
        return "array"
    return "date-time"


def show(value: Any) -> str:
    """A parsed value as TOML would spell it (short)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array" if len(value) > 6 else "[" + ", ".join(show(v) for v in value) + "]"
    return repr(value)


def close_match(word: str, choices: Sequence[str]) -> str:
    """` (did you mean 'x'?)` for the closest of `choices`, or the empty string."""
    close = difflib.get_close_matches(word, choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def format_path(path: Sequence[str | int]) -> str:
    """('pins', 0, 'select', 'box') -> 'pins[0].select.box'."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            name = part if part.replace("_", "").replace("-", "").isalnum() else json.dumps(part)
            out += f".{name}" if out else name
    return out


def parse_path(text: str) -> KeyPath:
    """'pins[0].select.box' -> ('pins', 0, 'select', 'box') (bare keys only)."""
    out: list[str | int] = []
    for piece in text.split("."):
        name, *indices = piece.split("[")
        if name:
            out.append(name)
        out.extend(int(i.rstrip("]")) for i in indices)
    return tuple(out)


def message(label: str, path: Sequence[str | int], line: int | None, what: str) -> str:
    """`<label>: <key.path> (line N): <what>`; the parts not known are left out."""
    where = format_path(path)
    parts = [label]
    if where:
        parts.append(where + (f" (line {line})" if line else ""))
    elif line:
        parts.append(f"line {line}")
    return ": ".join(parts) + f": {what}"


def line_at(lines: Mapping[KeyPath, int], path: KeyPath) -> int | None:
    """The line of `path`, or of its nearest enclosing key, in a located document."""
    for n in range(len(path), 0, -1):
        line = lines.get(tuple(path[:n]))
        if line is not None:
            return line
    return None


class LocatedError(RecipeError):
    """A RecipeError that also keeps the key path and the bare complaint (for command-line overrides);
    `related` are other key paths the complaint is about (a limit on a product of two keys)."""

    def __init__(
        self,
        label: str,
        path: Sequence[str | int],
        line: int | None,
        detail: str,
        related: Sequence[KeyPath] = (),
    ) -> None:
        super().__init__(message(label, path, line, detail))
        self.path = tuple(path)
        self.detail = detail
        self.related = tuple(related)


# ---------------------------------------------------------------------------------------------
# pydantic errors in TOML's words
# ---------------------------------------------------------------------------------------------

_OPS = {
    "greater_than": ("greater than", "gt"),
    "greater_than_equal": ("at least", "ge"),
    "less_than": ("less than", "lt"),
    "less_than_equal": ("at most", "le"),
}

_TYPES = {
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "an integer",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "bool_type": "true or false",
    "bool_parsing": "true or false",
    "string_type": "a string",
    "model_type": "a table",
    "model_attributes_type": "a table",
    "dict_type": "a table",
    "tuple_type": "an array",
    "list_type": "an array",
}


def describe(error: Mapping[str, Any], model: type[BaseModel] | None) -> str:
    """The complaint of one pydantic error (`ValidationError.errors()` item) about data validated by
    `model` (which lists the allowed keys of an unknown key's table; None: not listed)."""
    kind = error["type"]
    loc = error["loc"]
    value = error.get("input")
    ctx = error.get("ctx") or {}
    if kind == "extra_forbidden":
        key = loc[-1]
        parent = _model_at(model, loc[:-1]) if model is not None else None
        text = f"unknown key {key!r}"
        if parent is not None:
            allowed = _allowed(parent)
            text += close_match(str(key), allowed) + f"; allowed keys: {', '.join(allowed)}"
        return text
    if kind == "missing":
        return f"missing required key {loc[-1]!r}" if loc else "missing required key"
    if kind in _TYPES:
        return f"expected {_TYPES[kind]}, got {toml_type(value)} {show(value)}"
    if kind in _OPS:
        words, key = _OPS[kind]
        return f"must be {words} {ctx.get(key)}, got {show(value)}"
    if kind == "finite_number":
        return f"must be a finite number, got {show(value)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected')}, got {show(value)}"
    if kind == "too_short":
        return f"needs at least {ctx.get('min_length')} item(s)"
    if kind == "value_error":
        msg = str(error["msg"])
        return msg.removeprefix("Value error, ")
    return str(error["msg"]).lower()


def _model_at(cls: type[BaseModel], loc: Sequence[str | int]) -> type[BaseModel] | None:
    """The model class that validates the table at `loc` (for listing its allowed keys)."""
    current: type[BaseModel] | None = cls
    for part in loc:
        if current is None:
            return None
        if isinstance(part, int):
            continue
        field = next((f for n, f in current.model_fields.items() if (f.alias or n) == part), None)
        if field is None:
            return None
        current = _find_model(field.annotation)
    return current


def _find_model(tp: Any) -> type[BaseModel] | None:
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return tp
    for arg in typing.get_args(tp):
        found = _find_model(arg)
        if found is not None:
            return found
    return None


def _allowed(cls: type[BaseModel]) -> list[str]:
    return [f.alias or n for n, f in cls.model_fields.items() if n != "source"]
