"""The numeric range a scene key's documentation states (its ``allowed`` text, as docs/scenes.md shows it), read
back as numbers, so that tests can hold the loader to the documented range."""

from __future__ import annotations

import re
from typing import NamedTuple

from warp_verlet.scene_keys import Key

NUMBER = r"-?\d[\d ]*(?:\.\d+)?(?:e-?\d+)?"


class Range(NamedTuple):
    lo: float | None  # None: unbounded
    lo_open: bool
    hi: float | None
    hi_open: bool
    integer: bool


def _number(text: str, integer: bool) -> float:
    value = float(text.replace(" ", ""))  # "10 000"
    return int(value) if integer else value


def is_scalar_number(key: Key) -> bool:
    """A key whose value is one number (not a vector, not a number-or-array)."""
    kinds = getattr(key.parse, "accepts", frozenset())
    return bool(kinds) and kinds <= {"int", "float"}


def documented_range(key: Key) -> Range:
    """The range that ``key.allowed`` states in its first clause: "> 0", "≥ 1", "1 … 10 000", "0 < x < 1",
    "finite". Raises ValueError for a text that states none of these."""
    integer = getattr(key.parse, "accepts", frozenset()) == {"int"}
    clause = re.split(r"[;,(]", key.allowed)[0].strip()
    if clause == "finite":
        return Range(None, False, None, False, integer)
    if m := re.fullmatch(rf"(>|≥|>=) ({NUMBER})", clause):
        return Range(_number(m[2], integer), m[1] == ">", None, False, integer)
    if m := re.fullmatch(rf"({NUMBER}) … ({NUMBER})", clause):
        return Range(_number(m[1], integer), False, _number(m[2], integer), False, integer)
    if m := re.fullmatch(rf"({NUMBER}) (<|≤) x (<|≤) ({NUMBER})", clause):
        return Range(_number(m[1], integer), m[2] == "<", _number(m[4], integer), m[3] == "<", integer)
    raise ValueError(f"{key.name}: no range in its allowed text {key.allowed!r}")
