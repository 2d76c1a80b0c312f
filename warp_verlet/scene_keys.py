"""Reading TOML tables key by key, for scene files and for the files that build on them (mesh keys, sweeps).

Every failure is one :class:`SceneError` naming the file, the dotted key and what was expected: a parser
raises :class:`Invalid` with the problem (and, inside an array, the element's own key), and
:meth:`Table.take` adds the file and the key. Nothing here knows what a scene holds.

Each parser declares the TOML kinds it accepts (:func:`accepts`), and :func:`recorded_keys` lists every key a
load asks for with those kinds, as the loader takes it: tests/test_scene_fuzz.py fuzzes each key so recorded, so
that a key added to the loader is fuzzed without a hand-kept list.

A scene key is declared once, as a :class:`Key` (its parser, default and documentation), in the module of what it
configures; the loader takes it through the declaration, docs/make_scene_tables.py writes docs/scenes.md's tables
from it, and :func:`recorded_keys` notes which declaration each key was taken through (``.declared``).
"""

from __future__ import annotations

import contextvars
import math
import re
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

from .errors import ArgumentError, SceneError

PRIM_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")  # a USD prim name

REQUIRED = object()

# The kinds of TOML value a parser accepts (what tomllib gives: bool, int, float, str, list, dict).
BOOL, INT, FLOAT, STRING, ARRAY, TABLE = "bool", "int", "float", "string", "array", "table"
NUMBER = (INT, FLOAT)


def accepts(*kinds: str | tuple[str, ...]):
    """Declare the TOML kinds a parser accepts (``@accepts(ARRAY)``, ``accepts(*NUMBER)(parse)``): a value of
    any other kind is refused by it, naming the key. Read by :func:`recorded_keys`."""
    flat = frozenset(k for kind in kinds for k in ((kind,) if isinstance(kind, str) else kind))

    def declare(parse: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
        parse.accepts = flat
        return parse

    return declare


_RECORDING: contextvars.ContextVar[dict | None] = contextvars.ContextVar("recorded_keys", default=None)


class RecordedKeys(dict):
    """Dotted key as errors name it -> the kinds its parser accepts (None where the parser declares none); and in
    ``declared``, dotted key -> the :class:`Key` it was taken through, for the keys taken by :meth:`Key.take`."""

    def __init__(self):
        super().__init__()
        self.declared: dict[str, Key] = {}


@contextmanager
def recorded_keys() -> Iterator[RecordedKeys]:
    """Inside the block, every key a table is asked for (by :meth:`Table.take`, present or not, or by a parser
    through :func:`record_key`) is recorded: dotted key as errors name it -> the kinds its parser accepts
    (None where the parser declares none), and the declaration it was taken through (:class:`RecordedKeys`)."""
    keys = RecordedKeys()
    token = _RECORDING.set(keys)
    try:
        yield keys
    finally:
        _RECORDING.reset(token)


def record_key(key: str, parse: Callable[[Any, str], Any]) -> None:
    """Record ``key`` as taken with ``parse``, inside :func:`recorded_keys` (for a parser that reads a table's
    keys itself). Costs one context-variable read otherwise."""
    keys = _RECORDING.get()
    if keys is not None:
        keys[key] = getattr(parse, "accepts", None)


class Table:
    """One TOML table being read: remembers the file and the dotted key path for error messages, and
    which keys were consumed so that unknown keys are reported."""

    def __init__(self, file: str, path: str, data: Any, directory: Path | None = None):
        self.file, self.path = file, path
        self.directory = directory  # what a file named in the table is relative to; None: the working directory
        if not isinstance(data, dict):
            raise SceneError(file, path, f"expected a table, got {describe(data)}")
        self.data = data
        self.seen: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str | None, problem: str) -> SceneError:
        return SceneError(self.file, self.key(name) if name else self.path or None, problem)

    def take(self, name: str, parse: Callable[[Any, str], Any], default: Any = REQUIRED) -> Any:
        self.seen.add(name)
        record_key(self.key(name), parse)
        if name not in self.data:
            if default is REQUIRED:
                raise self.error(name, "is required but missing")
            return default
        try:
            return parse(self.data[name], self.key(name))
        except Invalid as bad:
            raise SceneError(self.file, bad.key or self.key(name), bad.problem) from None

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            known = ", ".join(sorted(self.seen))
            raise self.error(unknown[0], f"unknown key (known keys here: {known})")


@dataclass(frozen=True)
class Key:
    """One scene key, declared once where its kind lives: the loader takes it (:meth:`take`), docs/scenes.md's
    tables are written from it (docs/make_scene_tables.py), and the fuzz tests find it (:func:`recorded_keys`).

    A key whose parser needs what the scene says elsewhere (a grid's pins need its rows and columns) declares
    ``bind`` instead of ``parse``: a function of that context returning the parser, called by :meth:`bound`
    (``PINS.bound(rows, cols).take(t)``). Every other key is taken as it is (``FPS.take(t)``)."""

    name: str
    parse: Callable[[Any, str], Any] | None = None  # None only with bind
    default: Any = REQUIRED  # the value when the key is absent; REQUIRED: it must be given
    type: str = ""  # as the docs name it: "number", "[x, y, z] numbers", "array of [row, col] pairs"
    unit: str = "–"  # SI: "m", "kg", "s", "m/s²", "degrees", or "–" for none
    default_text: str | None = None  # the docs' default where the value alone does not say it ("absent: ...")
    allowed: str = ""  # the docs' range or choices: "> 0", "0 … 180"
    doc: str = ""  # what it does, in a sentence or a few
    bind: Callable[..., Callable[[Any, str], Any]] | None = None  # context -> the parser, for a key that needs it

    def __post_init__(self):
        if (self.parse is None) == (self.bind is None):
            raise ArgumentError(f"scene key {self.name!r}: declare exactly one of parse and bind")

    def bound(self, *context: Any) -> "Key":
        """This key with the parser its ``bind`` makes of ``context``."""
        if self.bind is None:
            raise ArgumentError(f"scene key {self.name!r} takes no context: take it as it is")
        return replace(self, parse=self.bind(*context), bind=None)

    def take(self, table: "Table") -> Any:
        """The key's value from ``table``, parsed, or its default."""
        if self.parse is None:
            raise ArgumentError(f"scene key {self.name!r} needs its context first: take it as key.bound(...).take(t)")
        keys = _RECORDING.get()
        if keys is not None:
            keys.declared[table.key(self.name)] = self
        return table.take(self.name, self.parse, self.default)


class FrozenMapping(Mapping):
    """A read-only mapping that pickles (a sweep's process pool sends scenes to its workers) and compares by
    content: the values of a cloth's declared extra keys (ClothSpec.options)."""

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | None = None):
        object.__setattr__(self, "_items", dict(items or {}))

    def __getitem__(self, key: str) -> Any:
        return self._items[key]

    def __iter__(self):
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("a FrozenMapping is read-only")

    def __reduce__(self):
        return (FrozenMapping, (self._items,))

    def __repr__(self) -> str:
        return f"FrozenMapping({self._items!r})"


class Invalid(Exception):
    def __init__(self, problem: str, key: str | None = None):
        self.problem, self.key = problem, key


def int_text(n: int) -> str:
    """An integer for a message. Huge ones (TOML hex/octal/binary literals have no length limit) are
    summarised: printing them in full is unreadable and, past sys.get_int_max_str_digits(), raises."""
    if n.bit_length() > 128:
        return f"{'-' if n < 0 else ''}an integer of {n.bit_length()} bits"
    return str(n)


def describe(value: Any) -> str:
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, int):
        return f"int {int_text(value)}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"an array of {len(value)}"
    return f"{type(value).__name__} {value!r}"


def number(value: Any, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise Invalid(f"expected {'an integer' if integer else 'a number'}, got {describe(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise Invalid(f"expected a finite number, got {value}")
    if not integer and isinstance(value, int):
        try:
            float(value)
        except OverflowError:  # an integer literal beyond the float range (about 1.8e308)
            raise Invalid(f"expected a finite number, got {int_text(value)}") from None
    return value


def real(lo: float | None = None, hi: float | None = None, lo_open: bool = False, hi_open: bool = False):
    """A finite float within [lo, hi] (ends open where asked)."""

    @accepts(NUMBER)
    def parse(value: Any, key: str) -> float:
        x = float(number(value))
        bad_lo = lo is not None and (x <= lo if lo_open else x < lo)
        bad_hi = hi is not None and (x >= hi if hi_open else x > hi)
        if bad_lo or bad_hi:
            left = "(" if lo_open or lo is None else "["  # an infinite end is never included
            right = ")" if hi_open or hi is None else "]"
            span = f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"
            raise Invalid(f"expected a number in {span}, got {x}")
        return x

    return parse


def integer(lo: int, hi: int | None = None):
    @accepts(INT)
    def parse(value: Any, key: str) -> int:
        n = int(number(value, integer=True))
        if n < lo or (hi is not None and n > hi):
            raise Invalid(f"expected an integer {'>= ' + str(lo) if hi is None else f'in [{lo}, {hi}]'}, got {int_text(n)}")
        return n

    return parse


def vector(length: int, element: Callable[[Any, str], Any]):
    @accepts(ARRAY)
    def parse(value: Any, key: str) -> tuple:
        if not isinstance(value, list) or len(value) != length:
            raise Invalid(f"expected an array of {length} numbers, got {describe(value)}")
        return tuple(element(v, f"{key}[{i}]") for i, v in enumerate(value))

    return parse


def choice(options: tuple[str, ...]):
    @accepts(STRING)
    def parse(value: Any, key: str) -> str:
        if not isinstance(value, str) or value not in options:
            raise Invalid(f"expected one of {', '.join(repr(o) for o in options)}, got {describe(value)}")
        return value

    parse.options = options  # the choices, for the fuzz tests' strings
    return parse


@accepts(BOOL)
def boolean(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise Invalid(f"expected true or false, got {describe(value)}")
    return value


@accepts(STRING)
def text(value: Any, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise Invalid(f"expected a non-empty string, got {describe(value)}")
    return value


def per_element(parse_one):
    """Wrap a scalar parser so that an error inside a vector names the element, e.g. ``size[1]``."""

    def parse(value: Any, key: str):
        try:
            return parse_one(value, key)
        except Invalid as bad:
            raise Invalid(bad.problem, bad.key or key) from None

    if hasattr(parse_one, "accepts"):
        parse.accepts = parse_one.accepts
    return parse


any_real = per_element(real())
non_negative = per_element(real(0.0))


def toml_list(items) -> str:
    return "[" + ", ".join(f'"{i}"' for i in items) + "]"


@accepts(STRING)
def prim_name(value: Any, key: str) -> str:
    """A USD prim name: the cloth or collider appears under that name in the cache."""
    name = text(value, key)
    if not PRIM_NAME.fullmatch(name):  # not .match: "$" would accept a trailing newline
        raise Invalid(f"expected a name of letters, digits and '_' not starting with a digit, got {name!r}")
    return name


# Grid pins by name: (rows, cols) -> the [row, col] of each pinned particle. Read by every selection of a grid's
# particles (pins, rigid patches).
NAMED_PINS: dict[str, Callable[[int, int], list[tuple[int, int]]]] = {
    "top-left": lambda r, c: [(0, 0)],
    "top-right": lambda r, c: [(0, c - 1)],
    "bottom-left": lambda r, c: [(r - 1, 0)],
    "bottom-right": lambda r, c: [(r - 1, c - 1)],
    "top-edge": lambda r, c: [(0, j) for j in range(c)],
    "bottom-edge": lambda r, c: [(r - 1, j) for j in range(c)],
    "left-edge": lambda r, c: [(i, 0) for i in range(r)],
    "right-edge": lambda r, c: [(i, c - 1) for i in range(r)],
}

FLOAT32_MAX = 3.4028234663852886e38
FLOAT32_TINY = 1.1754943508222875e-38  # the smallest normal float32: below it precision is lost, then 0


def float32_fits(x: float) -> bool:
    """Whether the device can hold ``x`` as a float32: finite and within its range."""
    return math.isfinite(x) and abs(x) <= FLOAT32_MAX


_positive = per_element(real(0.0, lo_open=True))


@accepts(NUMBER, ARRAY)
def scale_factors(value: Any, key: str) -> tuple[float, float, float]:
    """A scale: one positive number for all three axes, or [x, y, z] of them (a mesh cloth's, a mesh collider's)."""
    if isinstance(value, list):
        return vector(3, _positive)(value, key)
    s = _positive(value, key)
    return (s, s, s)
