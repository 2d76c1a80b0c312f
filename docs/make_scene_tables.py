"""Write docs/scenes.md's key tables from the keys' declarations (warp_verlet.scene_keys.Key).

    python docs/make_scene_tables.py           # rewrite the key tables of docs/scenes.md
    python docs/make_scene_tables.py --check   # change nothing; exit 1 naming the tables that are out of date

A table lies between a marker line naming it and an end marker::

    <!-- keys: simulation -->
    | key | type | unit | default | allowed | meaning |
    ...
    <!-- /keys -->

Everything between the two markers is rewritten; every other line of the file is left as it is. The tables are
those of :func:`key_tables`: the scene's own (``simulation``, ``output``, ``cloth``, ``grid``, ``mesh``), and those
of the collider and constraint kinds, found in their registries when those packages provide them
(``warp_verlet.colliders.COLLIDER_KINDS`` gives ``collider.<kind>`` for each kind, named by its ``name`` or
``type``, with its ``keys``, and ``SHARED_KEYS`` the table ``collider``; ``warp_verlet.constraints.CONSTRAINT_KINDS``
gives ``constraint.<kind>`` with each kind's ``cloth_keys``, and ``CONSTRAINT_KEYS`` the table ``constraint``). So a new kind's table
is one marker in docs/scenes.md. A marker naming a table that does not exist is an error, as is a marker left
open. tests/test_scene_docs.py runs the check.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Iterable

REPO = Path(__file__).resolve().parent.parent
SCENES_MD = REPO / "docs" / "scenes.md"
if str(REPO) not in sys.path:  # run as a script from anywhere: the checkout's package
    sys.path.insert(0, str(REPO))

from warp_verlet.scene_keys import REQUIRED, Key  # noqa: E402

BEGIN = re.compile(r"^<!-- keys: (\S.*?) -->$")
END = "<!-- /keys -->"
HEADER = "| key | type | unit | default | allowed | meaning |\n|---|---|---|---|---|---|"
# (module, registry of kinds, table of the keys all its kinds share, prefix of the tables' names)
REGISTRIES = (("warp_verlet.colliders", "COLLIDER_KINDS", "SHARED_KEYS", "collider"),
              ("warp_verlet.constraints", "CONSTRAINT_KINDS", "CONSTRAINT_KEYS", "constraint"))
KIND_KEYS = ("keys", "cloth_keys")  # the attribute of a kind that holds its keys (a constraint's are [[cloth]] keys)


class TableError(Exception):
    """A problem with docs/scenes.md's markers or with a declaration that cannot be written as a table row."""


def key_tables() -> dict[str, tuple[Key, ...]]:
    """Every table of keys a marker may name -> its keys, in the order of the table."""
    from warp_verlet.input import mesh_scene
    from warp_verlet.input import scene

    tables: dict[str, tuple[Key, ...]] = {
        "simulation": scene.SIMULATION_KEYS, "output": scene.OUTPUT_KEYS, "cloth": scene.CLOTH_KEYS,
        "grid": scene.GRID_KEYS, "mesh": mesh_scene.MESH_KEYS, "simulation.air": scene.AIR_KEYS,
    }
    for module_name, kinds_name, shared_name, prefix in REGISTRIES:
        module = _optional_module(module_name)
        if module is None:
            continue
        shared = getattr(module, shared_name, None)
        if shared is not None:
            _add(tables, prefix, shared, f"{module_name}.{shared_name}")
        kinds = getattr(module, kinds_name, None)
        if kinds is None:
            continue
        for label, kind in (kinds.items() if isinstance(kinds, Mapping) else ((None, k) for k in kinds)):
            name = getattr(kind, "name", None) or getattr(kind, "type", None) or label
            if not isinstance(name, str) or not name:
                raise TableError(f"{module_name}.{kinds_name}: {kind!r} has no name (a .name or .type string)")
            keys = next((getattr(kind, a) for a in KIND_KEYS if getattr(kind, a, None) is not None), None)
            if keys is None:
                raise TableError(f"{module_name}.{kinds_name}: kind {name!r} has no keys tuple "
                                 f"({' or '.join(KIND_KEYS)})")
            _add(tables, f"{prefix}.{name}", keys, f"{module_name}.{kinds_name}[{name!r}]")
    return tables


def _optional_module(name: str):
    """The module, or None where it does not exist (yet). Any other import problem is raised, not hidden."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            return None
        raise


def _add(tables: dict, name: str, keys: Iterable, source: str) -> None:
    keys = tuple(keys)
    if name in tables:
        raise TableError(f"{source}: a table named {name!r} is declared twice")
    if not all(isinstance(k, Key) for k in keys):
        raise TableError(f"{source}: expected a tuple of scene_keys.Key, got {keys!r}")
    tables[name] = keys


def toml_value(value: Any) -> str:
    """A default as a scene file writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, Path):
        return toml_value(str(value))
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }" if value else "{}"
    raise TypeError(f"no TOML form for {value!r}")


def default_cell(key: Key) -> str:
    if key.default_text is not None:
        return key.default_text
    if key.default is REQUIRED:
        return "**required**"
    if key.default is None:
        raise TableError(f"key {key.name!r}: its default is None, which a scene cannot write: declare default_text "
                         "(what happens when the key is absent)")
    return f"`{toml_value(key.default)}`"


def render_table(keys: Iterable[Key]) -> str:
    """The Markdown table of ``keys``: one row per key, in their order."""
    rows = [HEADER]
    for key in keys:
        cells = [f"`{key.name}`", key.type, key.unit, default_cell(key), key.allowed, key.doc]
        for cell in cells:
            if "\n" in cell or re.search(r"(?<!\\)\|", cell):
                raise TableError(f"key {key.name!r}: a table cell may not hold a line break or an unescaped '|': "
                                 f"{cell!r}")
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def rewrite(text: str, tables: Mapping[str, tuple[Key, ...]], source: str = "docs/scenes.md") -> tuple[str, list[str]]:
    """``text`` with every marked table written from ``tables``, and the names of the tables that changed."""
    lines = text.split("\n")
    out: list[str] = []
    changed: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        begin = BEGIN.match(line)
        if line.startswith("<!-- keys") and not begin:
            raise TableError(f"{source}:{i + 1}: expected a marker <!-- keys: NAME -->, got {line!r}")
        if line == END:
            raise TableError(f"{source}:{i + 1}: {END} without a <!-- keys: NAME --> before it")
        out.append(line)
        i += 1
        if not begin:
            continue
        name = begin.group(1)
        if name not in tables:
            raise TableError(f"{source}:{i}: no table of keys is named {name!r} (known: {', '.join(sorted(tables))})")
        if not tables[name]:
            raise TableError(f"{source}:{i}: the table {name!r} declares no keys: remove its marker")
        try:
            end = lines.index(END, i)
        except ValueError:
            raise TableError(f"{source}:{i}: the table {name!r} has no {END} after it") from None
        nested = [j for j in range(i, end) if lines[j].startswith("<!-- keys")]
        if nested:
            raise TableError(f"{source}:{nested[0] + 1}: a marker inside the table {name!r}, which is not closed")
        body = ["", render_table(tables[name]), ""]
        if "\n".join(lines[i:end]) != "\n".join(body):
            changed.append(name)
        out.extend(body)
        out.append(END)
        i = end + 1
    return "\n".join(out), changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a table is out of date")
    parser.add_argument("--file", type=Path, default=SCENES_MD, help="the Markdown file (default: docs/scenes.md)")
    args = parser.parse_args(argv)
    text = args.file.read_text(encoding="utf-8")
    try:
        new, changed = rewrite(text, key_tables(), str(args.file))
    except TableError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        if changed:
            print(f"{args.file}: out of date with the key declarations: {', '.join(changed)}; run python "
                  "docs/make_scene_tables.py", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.file.write_text(new, encoding="utf-8")
        print(f"{args.file}: rewrote {', '.join(changed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
