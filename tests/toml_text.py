"""A small TOML writer for the loader tests (tomli_w is not a dependency): values, inline documents and
block documents with [table] and [[array]] headers. ``Raw`` emits a literal as is (datetimes, over-long
numbers, deep nesting), for input that no well-formed writer would produce."""

from __future__ import annotations

import math
import re


class Raw(str):
    """A TOML literal emitted as is."""


_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else toml_string(k)  # not match: "$" accepts a final newline


def toml_value(v) -> str:
    if isinstance(v, Raw):
        return str(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        # decimal str() of a huge int hits Python's 4300-digit limit; hex does not, and TOML has no negative hex
        return hex(v) if v > 0 and v.bit_length() > 256 else str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def toml_document(doc: dict) -> str:
    """A document as one ``key = value`` line per top-level key; tables and [[arrays]] become inline."""
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in doc.items())


def _is_table_array(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def dump(doc: dict, path: tuple[str, ...] = ()) -> str:
    """A document in block form: plain keys first, then each sub-table under a ``[a.b]`` header and each
    non-empty array of tables as ``[[a.b]]`` blocks (their own sub-tables nested under them)."""
    lines = []
    for k, v in doc.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{toml_key(k)} = {toml_value(v)}")
    blocks = []
    for k, v in doc.items():
        header = ".".join(toml_key(p) for p in (*path, k))
        if isinstance(v, dict):
            blocks.append(f"[{header}]\n" + dump(v, (*path, k)))
        elif _is_table_array(v):
            for item in v:
                blocks.append(f"[[{header}]]\n" + dump(item, (*path, k)))
    return "\n".join(lines) + ("\n" if lines else "") + "".join("\n" + b for b in blocks)
