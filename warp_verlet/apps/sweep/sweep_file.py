"""The sweep file: a base scene and the scene keys to vary; every combination is a variant.

    [sweep]
    scene = "../wind_sheet.toml"          # the base scene, relative to this file
    frames = 60                           # optional: every variant's simulation.frames (``sweep --frames N``
                                          # overrides it)

    [axes]                                # the grid: every combination of these values
    "simulation.substeps" = [8, 16, 32]
    "cloth.0.compliance.bend" = { start = 0.1, stop = 10.0, num = 3, spacing = "log" }

    [random]                              # optional: `samples` random draws, each combined with every grid point
    seed = 7
    samples = 20
    [random.axes]
    "simulation.wind.2" = { uniform = [0.0, 8.0] }

An axis is a dotted path into the base scene's TOML document: table keys by name, array elements (a ``[[cloth]]``,
an element of a vector) by index from 0. A variant is the base document with each axis's value written at its path,
then validated by :func:`warp_verlet.input.scene.parse_scene` like any scene file; so a value the scene refuses is one
:class:`SceneError` naming the sweep file, the axis and the variant, before anything runs.

A sweep's ``format`` is the suffix (without its dot) of a registered output format (writer_registry.py),
``usdc`` unless it says otherwise.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ...errors import SceneError
from ...input.scene import (Scene, _describe, _Invalid, _Table, choice, integer, load_scene, parse_scene,
                            read_toml_file, real, text)
from ...writer_registry import output_suffixes

DEFAULT_FORMAT = "usdc"
MAX_VARIANTS = 100_000
MAX_RANGE = 100_000
RANGE_KEYS = ("start", "stop", "step", "num", "spacing")
DISTRIBUTIONS = ("uniform", "loguniform", "integers", "choice")


def formats() -> tuple[str, ...]:
    """The values of ``[sweep] format``: every registered output suffix without its dot, the default first."""
    names = [suffix[1:] for suffix in output_suffixes()]
    return (DEFAULT_FORMAT, *(name for name in names if name != DEFAULT_FORMAT))


@dataclass(frozen=True)
class Axis:
    """One varied key: ``name`` as written (dotted), ``path`` its segments; ``values`` for a grid axis, or
    ``distribution`` (kind, arguments) for a random one."""
    name: str
    path: tuple[str, ...]
    values: tuple = ()
    distribution: tuple[str, Any] | None = None
    section: str = "axes"  # where it was written: "axes" or "random.axes"

    @property
    def key(self) -> str:
        """The axis as an error names it: its section and its name."""
        return f"{self.section}.{self.name}"


@dataclass(frozen=True)
class Variant:
    index: int
    name: str
    params: dict  # axis name -> value, in axis order (grid axes first)
    sample: int | None  # the random draw, when the sweep has a [random] table
    scene: Scene
    hash: str  # of the variant's whole scene document and the cache format


@dataclass(frozen=True)
class Sweep:
    file: str
    base: Path  # the base scene file
    output: Path  # directory of the caches and the summary
    format: str
    frames: int | None
    axes: tuple[Axis, ...]
    random_axes: tuple[Axis, ...]
    seed: int | None
    samples: int | None
    variants: tuple[Variant, ...]

    @property
    def parameter_names(self) -> list[str]:
        return [a.name for a in (*self.axes, *self.random_axes)]


def read_toml(path: Path, what: str = "sweep file") -> dict:
    """A TOML file's document, with the scene loader's errors and size cap (scene.read_toml_file)."""
    return read_toml_file(path, what)


def load_sweep(path: str | Path, output: str | Path | None = None, frames: int | None = None) -> Sweep:
    """Read a sweep file, expand and validate every variant. ``output`` overrides ``[sweep] output``, ``frames``
    (``sweep --frames``) ``[sweep] frames`` and the base scene's frame count, for every variant.
    Raises :class:`SceneError` naming the sweep file and the key (or axis) on any problem."""
    path = Path(path)
    return parse_sweep(read_toml(path), str(path), path, output, frames)


def parse_sweep(data: dict, file: str, path: Path, output: str | Path | None = None,
                frames_override: int | None = None) -> Sweep:
    top = _Table(file, "", data)
    settings = top.take("sweep", lambda v, k: v)  # read below, as its own table
    axes_data = top.take("axes", lambda v, k: v, None)
    random_data = top.take("random", lambda v, k: v, None)
    top.finish()

    t = _Table(file, "sweep", settings)
    scene_name = t.take("scene", _path_text)
    out = t.take("output", _path_text, path.stem)
    frames = t.take("frames", integer(1), None)
    fmt = t.take("format", choice(formats()), DEFAULT_FORMAT)
    t.finish()
    if frames_override is not None:
        if isinstance(frames_override, bool) or not isinstance(frames_override, int) or frames_override < 1:
            raise SceneError(file, None, f"--frames must be a whole number of frames >= 1, got {frames_override!r}")
        frames = frames_override
    base = Path(os.path.normpath(path.parent / scene_name))
    try:
        base_scene = load_scene(base)
    except SceneError as exc:
        where = f"the base scene {base}" if exc.file == str(base) else str(base)
        raise SceneError(file, "sweep.scene", f"{where} is invalid: {exc}") from None
    base_doc = read_toml(base, "scene file")  # load_scene read it without complaint

    axes = _read_axes(file, "axes", axes_data, grid=True) if axes_data is not None else ()
    seed = samples = None
    random_axes: tuple[Axis, ...] = ()
    if random_data is not None:
        r = _Table(file, "random", random_data)
        seed = r.take("seed", integer(0, 2**63 - 1))
        samples = r.take("samples", integer(1, MAX_VARIANTS))
        random_axes = _read_axes(file, "random.axes", r.take("axes", lambda v, k: v), grid=False)
        r.finish()
    if not axes and not random_axes:
        raise SceneError(file, None, "expected [axes] (a grid of values) or [random] (a random sampler), or both: "
                         "a sweep varies at least one scene key")
    names = {}
    for axis in (*axes, *random_axes):
        dotted = ".".join(axis.path)
        if dotted in names:
            raise SceneError(file, axis.key, f"varies the same scene key as {names[dotted]}")
        names[dotted] = axis.key
        if axis.path[:2] == ("output", "path"):
            raise SceneError(file, axis.key, "output.path is set by the sweep (one cache per variant, in the "
                             "sweep's output directory); vary something else")
        if frames is not None and axis.path == ("simulation", "frames"):
            where = "--frames" if frames_override is not None else "[sweep] frames"
            raise SceneError(file, axis.key, f"simulation.frames is already set for every variant by {where}; "
                             "remove one of the two")
    count = math.prod(len(a.values) for a in axes) * (samples or 1)
    if count > MAX_VARIANTS:
        raise SceneError(file, None, f"the sweep has {count} variants, more than {MAX_VARIANTS}; split it")

    sweep = Sweep(file=file, base=base, output=Path(output) if output is not None else Path(out), format=fmt,
                  frames=frames, axes=axes, random_axes=random_axes, seed=seed, samples=samples, variants=())
    variants = tuple(_expand(sweep, base_doc, base_scene))
    return Sweep(**{**sweep.__dict__, "variants": variants})


def _path_text(value: Any, key: str) -> str:
    value = text(value, key)
    if "\0" in value:
        raise _Invalid("expected a path without NUL characters")
    return value


def _flatten(file: str, section: str, data: Any, leaf: Callable[[Any], bool]) -> list[tuple[str, tuple[str, ...], Any]]:
    """The axes of a table: (name, path, spec), descending into nested tables (``cloth.0.mass = [...]`` written
    bare is a nested table in TOML) until ``leaf(value)``."""
    if not isinstance(data, dict):
        raise SceneError(file, section, f"expected a table of axes (dotted scene keys), got {_describe(data)}")
    out = []

    def walk(node: dict, prefix: tuple[str, ...]) -> None:
        for key, value in node.items():
            parts = tuple(key.split("."))
            path = prefix + parts
            name = ".".join(path)
            if any(p == "" for p in parts):
                raise SceneError(file, f"{section}.{name}", "expected a dotted scene key without empty parts "
                                 "(like simulation.substeps or cloth.0.mass)")
            if isinstance(value, dict) and not leaf(value):
                if not value:
                    raise SceneError(file, f"{section}.{name}", "expected values to sweep, got an empty table")
                walk(value, path)
            else:
                out.append((name, path, value))

    walk(data, ())
    if not out:
        raise SceneError(file, section, "expected at least one axis (a dotted scene key and its values)")
    return out


def _is_range(value: dict) -> bool:
    return "start" in value or "stop" in value  # no scene key has these names


def _is_distribution(value: dict) -> bool:
    return len(value) == 1 and next(iter(value)) in DISTRIBUTIONS


def _read_axes(file: str, section: str, data: Any, grid: bool) -> tuple[Axis, ...]:
    out = []
    for name, path, spec in _flatten(file, section, data, _is_range if grid else _is_distribution):
        key = f"{section}.{name}"
        try:
            if grid:
                out.append(Axis(name, path, values=_grid_values(spec), section=section))
            else:
                out.append(Axis(name, path, distribution=_distribution(spec), section=section))
        except _Invalid as bad:
            raise SceneError(file, f"{key}{bad.key or ''}", bad.problem) from None
    return tuple(out)


def _grid_values(spec: Any) -> tuple:
    if isinstance(spec, list):
        if not spec:
            raise _Invalid("expected at least one value, got an empty array")
        return tuple(spec)
    if isinstance(spec, dict):
        return _range_values(spec)
    raise _Invalid(f"expected an array of values or a range table {{ start, stop, step }} or {{ start, stop, num }}, "
                   f"got {_describe(spec)}")


def _sub(key: str):
    """Parse an entry of an axis's table, naming it (``.start``) in errors."""
    def wrap(parse):
        def inner(value, k):
            try:
                return parse(value, k)
            except _Invalid as bad:
                raise _Invalid(bad.problem, bad.key or f".{key}") from None
        return inner
    return wrap


def _whole(x: float) -> bool:
    return math.isfinite(x) and x == int(x)


def _tidy(x: float) -> float:
    """A computed range value at 12 significant digits, so that 0.1 + 2 x 0.1 is 0.3 and not 0.30000000000000004."""
    return float(f"{x:.12g}")


def _range_values(spec: dict) -> tuple:
    for k in spec:
        if k not in RANGE_KEYS:
            raise _Invalid(f"unknown key in a range (known: {', '.join(RANGE_KEYS)})", f".{k}")
    for k in ("start", "stop"):
        if k not in spec:
            raise _Invalid("is required in a range but missing", f".{k}")
    start = _sub("start")(real())(spec["start"], "")
    stop = _sub("stop")(real())(spec["stop"], "")
    has_step, has_num = "step" in spec, "num" in spec
    if has_step == has_num:
        raise _Invalid("expected exactly one of step (values start, start + step, ... up to stop) and num "
                       "(num values from start to stop)")
    spacing = _sub("spacing")(choice(("linear", "log")))(spec.get("spacing", "linear"), "")
    ints = all(isinstance(spec[k], int) and not isinstance(spec[k], bool) for k in ("start", "stop"))
    if has_step:
        if spacing == "log":
            raise _Invalid("log spacing takes num, not step", ".spacing")
        step = _sub("step")(real())(spec["step"], "")
        ints = ints and isinstance(spec["step"], int) and not isinstance(spec["step"], bool)
        if step == 0 or (stop - start) * step < 0:
            raise _Invalid(f"step {step:g} never goes from start {start:g} to stop {stop:g}", ".step")
        span = (stop - start) / step
        if not span + 1 <= MAX_RANGE:  # a span too wide for a float (inf) is refused too, before it is counted
            made = f"{math.floor(span) + 1}" if math.isfinite(span) else "more than a float can count"
            raise _Invalid(f"expected at most {MAX_RANGE} values in a range, got {made} (start {start:g} to "
                           f"stop {stop:g} in steps of {step:g})")
        count = math.floor(span + 1e-9) + 1
        values = [start + i * step for i in range(count)]
    else:
        num = _sub("num")(integer(1, MAX_RANGE))(spec["num"], "")
        if spacing == "log":
            if start <= 0 or stop <= 0:
                raise _Invalid(f"log spacing needs start and stop > 0, got {start:g} and {stop:g}")
            values = [start * (stop / start) ** (i / (num - 1)) if num > 1 else start for i in range(num)]
            if num > 1:
                values[-1] = stop
        else:
            values = [start + (stop - start) * i / (num - 1) if num > 1 else start for i in range(num)]
    values = [_tidy(v) for v in values]
    if not all(math.isfinite(v) for v in values):
        raise _Invalid("the range gives a value that is not a finite number")
    if ints and all(_whole(v) for v in values):
        return tuple(int(v) for v in values)
    return tuple(values)


def _distribution(spec: Any) -> tuple[str, Any]:
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
        raise _Invalid("expected a distribution: { uniform = [lo, hi] }, { loguniform = [lo, hi] }, "
                       "{ integers = [lo, hi] } or { choice = [a, b, ...] }, got " + _describe(spec))
    kind, args = next(iter(spec.items()))
    key = f".{kind}"
    if kind == "choice":
        if not isinstance(args, list) or not args:
            raise _Invalid(f"expected a non-empty array of values, got {_describe(args)}", key)
        return kind, tuple(args)
    if not isinstance(args, list) or len(args) != 2:
        raise _Invalid(f"expected [lo, hi], got {_describe(args)}", key)
    if kind == "integers":
        try:
            lo, hi = (integer(-(2**62), 2**62)(a, "") for a in args)
        except _Invalid as bad:
            raise _Invalid(bad.problem, key) from None
        if lo > hi:
            raise _Invalid(f"expected lo <= hi, got [{lo}, {hi}]", key)
        return kind, (lo, hi)
    if all(isinstance(a, list) for a in args):  # a vector: [lo_0, lo_1, ...], [hi_0, hi_1, ...], drawn per element
        if len(args[0]) != len(args[1]) or not args[0]:
            raise _Invalid(f"expected [lo, hi] vectors of one length, got {len(args[0])} and {len(args[1])} elements",
                           key)
        pairs = [_bounds(kind, [a, b], f"{key}[{i}]") for i, (a, b) in enumerate(zip(*args))]
        return kind, tuple(pairs)
    return kind, _bounds(kind, args, key)


def _bounds(kind: str, args: list, key: str) -> tuple[float, float]:
    try:
        lo, hi = (real()(a, "") for a in args)
    except _Invalid as bad:
        raise _Invalid(bad.problem, key) from None
    if not lo <= hi or not math.isfinite(hi - lo):
        raise _Invalid(f"expected lo <= hi, got [{lo:g}, {hi:g}]", key)
    if kind == "loguniform" and lo <= 0:
        raise _Invalid(f"expected 0 < lo <= hi, got [{lo:g}, {hi:g}]", key)
    return lo, hi


def _draw(rng, distribution: tuple[str, Any]):
    kind, args = distribution
    if kind in ("uniform", "loguniform") and isinstance(args[0], tuple):
        return [_draw(rng, (kind, pair)) for pair in args]
    if kind == "uniform":
        return float(rng.uniform(*args))
    if kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
    if kind == "integers":
        return int(rng.integers(args[0], args[1], endpoint=True))
    return copy.deepcopy(args[int(rng.integers(len(args)))])


def draws(seed: int, samples: int, axes: tuple[Axis, ...]) -> list[list]:
    """``samples`` draws of every random axis, in order: draw i is the same whatever ``samples`` is (more samples
    extend the list), so that growing a sampled sweep resumes it."""
    import numpy as np

    rng = np.random.default_rng(seed)
    return [[_draw(rng, a.distribution) for a in axes] for _ in range(samples)]


# ---------------------------------------------------------------------------------------------- variants

class _PathError(Exception):
    pass


def set_at(doc: dict, path: tuple[str, ...], value: Any) -> None:
    """Write ``value`` at a dotted path: tables by key (a missing table is created), arrays by index."""
    node: Any = doc
    for i, part in enumerate(path):
        last = i == len(path) - 1
        where = ".".join(path[:i]) or "the scene"
        if isinstance(node, dict):
            if last:
                node[part] = copy.deepcopy(value)
                return
            if part not in node:
                if re.fullmatch(r"\d+", path[i + 1]):
                    name = ".".join(path[:i + 1])
                    raise _PathError(f"{name} is not in the base scene, so it has no element {path[i + 1]} to "
                                     f"set: vary {name} as a whole, or give it a value in the base scene")
                node[part] = {}
            node = node[part]
        elif isinstance(node, list):
            if not re.fullmatch(r"\d+", part) or int(part) >= len(node):
                raise _PathError(f"{where} is an array of {len(node)} in the base scene: expected an index "
                                 f"0 .. {len(node) - 1} after it, got {part!r}")
            if last:
                node[int(part)] = copy.deepcopy(value)
                return
            node = node[int(part)]
        else:
            raise _PathError(f"{where} is {_describe(node)} in the base scene, not a table or an array")


def _scene_key_path(key: str | None) -> tuple[str, ...]:
    """A scene error's key (``cloth[0].size[1]``) as path segments (cloth, 0, size, 1)."""
    if not key:
        return ()
    return tuple(p for p in re.split(r"[.\[\]]+", key) if p)


def _fmt_value(value: Any, digits: int = 4) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    if isinstance(value, list) or isinstance(value, tuple):
        return "_".join(_fmt_value(v, digits) for v in value)
    if isinstance(value, dict):
        return "_".join(f"{k}-{_fmt_value(v, digits)}" for k, v in value.items())
    return str(value)


def show(value: Any) -> str:
    """A value as TOML would write it, numbers to 8 digits: for messages and listings."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.8g}"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {show(v)}" for k, v in value.items()) + " }" if value else "{}"
    return str(value)


def short_names(axes: list[Axis]) -> list[str]:
    """The fewest trailing segments of each axis path that tell the axes apart (``bend`` for
    ``cloth.0.compliance.bend``), joined with '.'."""
    def tail(path: tuple[str, ...], depth: int) -> str:
        if path[-1].isdigit():  # wind.2, not 2
            depth = max(depth, 2)
        return ".".join(path[-depth:])

    for depth in range(1, max((len(a.path) for a in axes), default=1) + 1):
        names = [tail(a.path, depth) for a in axes]
        if len(set(names)) == len(names):
            return names
    return [a.name for a in axes]


def variant_name(index: int, width: int, shorts: list[str], values: list) -> str:
    """``0007_substeps=16_bend=1``: the index, then each parameter, in characters safe in any file name."""
    slug = "_".join(f"{s}={_fmt_value(v)}" for s, v in zip(shorts, values))
    slug = re.sub(r"[^A-Za-z0-9.=+\-_]", "-", slug)[:120].rstrip("_")
    return f"{index:0{width}d}" + (f"_{slug}" if slug else "")


def parameter_hash(doc: dict, fmt: str) -> str:
    """sha256 of the variant's whole scene document (its output path left out) and the cache format."""
    doc = copy.deepcopy(doc)
    if isinstance(doc.get("output"), dict):
        doc["output"].pop("path", None)
    text_ = json.dumps({"scene": doc, "format": fmt}, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text_.encode()).hexdigest()[:20]


def _expand(sweep: Sweep, base_doc: dict, base_scene: Scene):
    axes = list(sweep.axes)
    grid = list(itertools.product(*(a.values for a in axes))) if axes else [()]
    sampled = draws(sweep.seed, sweep.samples, sweep.random_axes) if sweep.random_axes else [None]
    all_axes = axes + list(sweep.random_axes)
    shorts = short_names(all_axes)
    total = len(grid) * len(sampled)
    width = max(3, len(str(total - 1)))
    index = 0
    for point in grid:
        for s, draw in enumerate(sampled):
            values = list(point) + (draw or [])
            doc = copy.deepcopy(base_doc)
            for axis, value in zip(all_axes, values):
                try:
                    set_at(doc, axis.path, value)
                except _PathError as exc:
                    raise SceneError(sweep.file, axis.key, str(exc)) from None
            if sweep.frames is not None:
                set_at(doc, ("simulation", "frames"), sweep.frames)
            params = dict(zip((a.name for a in all_axes), values))
            try:
                scene = parse_scene(doc, str(sweep.base), sweep.base)
            except SceneError as exc:
                raise _variant_error(sweep, all_axes, values, index, params, exc) from None
            yield Variant(index=index, name=variant_name(index, width, shorts, values), params=params,
                          sample=s if draw is not None else None, scene=scene,
                          hash=parameter_hash(doc, sweep.format))
            index += 1


def _variant_error(sweep: Sweep, axes: list[Axis], values: list, index: int, params: dict,
                   exc: SceneError) -> SceneError:
    """The scene's complaint about one variant, put on the axis whose value it names (or on the variant)."""
    bad = _scene_key_path(exc.key)
    described = ", ".join(f"{k} = {show(v)}" for k, v in params.items())
    for axis, value in zip(axes, values):
        n = min(len(bad), len(axis.path))
        if n and bad[:n] == axis.path[:n]:
            return SceneError(sweep.file, axis.key, f"the value {show(value)} gives an invalid scene "
                              f"(variant {index}: {described}): {exc.key}: {exc.problem}")
    return SceneError(sweep.file, "axes" if sweep.axes else "random.axes",
                      f"variant {index} ({described}) gives an invalid scene: {exc.key or exc.file}: {exc.problem}")
