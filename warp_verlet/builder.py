"""Scenes built in Python: :class:`SceneBuilder` makes the same validated :class:`~warp_verlet.input.scene.Scene` a scene
file does, and the Model from it, with no TOML.

Each call takes the keys of one table of a scene file as keyword arguments: the same names, units and defaults
(docs/scenes.md), read by the same readers as the loader's (scene.read_simulation, read_output, read_cloth and
colliders.read_collider), so that a scene built here is the scene a file with the same tables loads (its ``source``
aside), and a bad value is the same :class:`~warp_verlet.errors.SceneError`, naming the call instead of the file::

    add_grid(cloth 0): mass: expected a number in (0.0, inf), got 0.0

Python values are first written as the TOML values they stand for (a tuple or a numpy array is an array, a
numpy number a number, a path a string, a mapping a table), and ``None`` for a key whose default is "absent"
(``tear_threshold``, ``tethers``, ``name``) leaves the key out. The keys that the constraint kinds declare
(``max_bend_angle``, ``rigid_patches``) and every collider kind's keys are taken from their declarations, so a new
kind's keys work here as they do in a file.

Each call is checked when it is made (a mesh is read, welded and checked in :meth:`SceneBuilder.add_mesh`);
:meth:`SceneBuilder.scene` adds the checks across tables (names, the solver against the cloths, float32 range).
Nothing here imports warp or numpy at module level: :meth:`SceneBuilder.finalize` imports the simulation core.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from .colliders import SHARED_KEYS, kind_named, kinds, read_collider
from .errors import ArgumentError, SceneError
from .input.scene import (CLOTH_KEYS, GRID_KEYS, OUTPUT_KEYS, SIMULATION_KEYS, ClothSpec, OutputSettings, Scene,
                          SimulationSettings, check_scene, cloth_keys_of_kinds, read_cloth, read_output,
                          read_simulation)
from .scene_keys import Key, Table

if TYPE_CHECKING:  # pragma: no cover
    from .core.model import Model


def toml_value(value: Any) -> Any:
    """``value`` as the TOML value it stands for, for the scene readers: tuples, lists and numpy arrays become lists,
    numpy scalars Python numbers, paths strings, mappings dicts (recursively). Anything else is passed on as it
    is, for the reader to refuse with its own message."""
    if value is None or type(value) in (bool, int, float, str):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Mapping):
        return {k: toml_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [toml_value(v) for v in value]
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):  # an array or a numpy scalar
        return toml_value(value.tolist())
    return value


def _table(keys: Iterable[Key], given: Mapping[str, Any]) -> dict[str, Any]:
    """The table that keyword arguments ``given`` stand for: each value as TOML (:func:`toml_value`), and a None
    left out where the key's default is None (absent); a None anywhere else reaches the reader, which refuses it."""
    absent_by_default = {key.name for key in keys if key.default is None}
    return {name: toml_value(value) for name, value in given.items()
            if not (value is None and name in absent_by_default)}


class SceneBuilder:
    """Builds one scene in Python, call by call, as a scene file's tables would.

    ``name`` stands where a scene file's path would: it is ``Scene.source`` (in the run summary, the cache's
    metadata and the errors :meth:`scene` raises) and names the default output, ``<name>.usdc`` (its stem, as a
    scene file's). Mesh files given by a relative path are read relative to the working directory.

    The methods take a table's keys as keyword arguments (docs/scenes.md lists them): :meth:`set_simulation`
    ``[simulation]``, :meth:`set_output` ``[output]``, :meth:`add_grid` and :meth:`add_mesh` a ``[[cloth]]``,
    :meth:`add_collider` (:meth:`add_sphere`, :meth:`add_plane`) a ``[[collider]]``. Each returns what it
    validated (a frozen dataclass); :meth:`scene` gives the :class:`Scene` (for ``Simulator`` and
    ``runner.run_scene``), :meth:`finalize` the immutable Model on a device.
    """

    def __init__(self, name: str = "scene"):
        if not isinstance(name, str) or not name:
            raise ArgumentError(f"SceneBuilder: name must be a non-empty string, got {name!r}")
        self.name = name
        self._simulation: dict[str, Any] = {}  # the keys given so far, as TOML values
        self._output: dict[str, Any] = {}
        self.simulation: SimulationSettings = read_simulation(self.name, {})
        self.output: OutputSettings = read_output(self.name, {}, Path(self.name))
        self._cloths: list[ClothSpec] = []
        self._colliders: list = []

    @property
    def cloths(self) -> tuple[ClothSpec, ...]:
        """The cloths added so far, in order (``cloth[i]`` in the errors of :meth:`scene`)."""
        return tuple(self._cloths)

    @property
    def colliders(self) -> tuple:
        """The colliders added so far, in order (``collider[i]``), each its kind's spec."""
        return tuple(self._colliders)

    # ------------------------------------------------------------------ [simulation] and [output]
    def set_simulation(self, **keys: Any) -> SimulationSettings:
        """Set ``[simulation]`` keys (fps, frames, substeps, iterations, gravity, ...), over those of earlier
        calls; the table is checked as a whole, as a file's is (``target_stretch`` with ``substeps`` is refused
        whichever call gave each)."""
        table = {**self._simulation, **_table(SIMULATION_KEYS, keys)}
        self.simulation = read_simulation("set_simulation()", table, path="")
        self._simulation = table
        return self.simulation

    def set_output(self, **keys: Any) -> OutputSettings:
        """Set ``[output]`` keys (path, save_every, up_axis, ...), over those of earlier calls."""
        table = {**self._output, **_table(OUTPUT_KEYS, keys)}
        self.output = read_output("set_output()", table, Path(self.name), path="")
        self._output = table
        return self.output

    # ------------------------------------------------------------------ [[cloth]]
    def add_grid(self, **keys: Any) -> ClothSpec:
        """Add a grid cloth: ``resolution`` and ``size`` (required), and any other key of a grid cloth (pins,
        tethers, compliance, tear_threshold, ...) or of a constraint kind (max_bend_angle, rigid_patches)."""
        where = f"add_grid(cloth {len(self._cloths)})"
        if "mesh" in keys:
            raise SceneError(where, "mesh", "a mesh cloth is added with add_mesh(mesh=...) or add_mesh(points=..., "
                             "faces=...)")
        table = _table((*CLOTH_KEYS, *GRID_KEYS, *cloth_keys_of_kinds()), keys)
        return self._add_cloth(read_cloth(where, len(self._cloths), table, Path(), path=""))

    def add_mesh(self, mesh: str | os.PathLike | None = None, *, points: Any = None, faces: Any = None,
                 **keys: Any) -> ClothSpec:
        """Add a mesh cloth, from a file (``mesh``: a path, and ``prim`` for USD) or from ``points`` ((V, 3)
        metres) and ``faces`` (an (F, k) array of vertex indices, a list of faces of any size, or a
        :class:`~warp_verlet.geometry.faces.Faces`), counter-clockwise seen from the front. Either way the mesh is moved by
        ``scale``, ``rotate`` and ``translate``, welded and checked as a file's is; the other keys are a mesh
        cloth's (pins, particle_masses, mass_distribution, weld_distance, ...) and every cloth's."""
        from .input.mesh_scene import MESH_KEYS

        where = f"add_mesh(cloth {len(self._cloths)})"
        in_memory = points is not None or faces is not None
        if in_memory == (mesh is not None):
            raise SceneError(where, "mesh", "expected either a mesh file (mesh = path) or the mesh itself (points "
                             "and faces), not both" if in_memory else "expected a mesh file (mesh = path) or "
                             "points and faces")
        table = _table((*CLOTH_KEYS, *MESH_KEYS, *cloth_keys_of_kinds()), keys)
        if not in_memory:
            return self._add_cloth(read_cloth(where, len(self._cloths), {"mesh": toml_value(mesh), **table}, Path(),
                                              path=""))
        arrays = _mesh_arrays(where, points, faces)
        return self._add_cloth(read_cloth(where, len(self._cloths), table, Path(), path="", mesh_arrays=arrays))

    def _add_cloth(self, spec: ClothSpec) -> ClothSpec:
        self._cloths.append(spec)
        return spec

    # ------------------------------------------------------------------ [[collider]]
    def add_collider(self, type: str, **keys: Any) -> Any:
        """Add a collider of a registered kind (``type``: "sphere", "plane", ...) with its keys: the shared ones
        (name, thickness, friction_coefficient, static_friction_coefficient, purpose) and the kind's own (a
        sphere's radius, centre or path; a plane's point and normal)."""
        return self._add_collider("add_collider", type, keys)

    def add_sphere(self, **keys: Any) -> Any:
        """Add a sphere collider: ``radius`` (required), and ``centre`` (still) or ``path`` (moving keyframes
        [[t, x, y, z], ...]), and the shared collider keys."""
        return self._add_collider("add_sphere", "sphere", keys)

    def add_plane(self, **keys: Any) -> Any:
        """Add a plane collider: its ``point`` and ``normal``, and the shared collider keys."""
        return self._add_collider("add_plane", "plane", keys)

    def _add_collider(self, call: str, type_name: Any, keys: Mapping[str, Any]) -> Any:
        index = len(self._colliders)
        where = f"{call}(collider {index})"
        if "type" in keys:
            raise SceneError(where, "type", f"is the collider's kind, given once: {call} takes it as "
                             + ("its first argument" if call == "add_collider" else "its name"))
        declared = list(SHARED_KEYS)
        if isinstance(type_name, str) and type_name in {k.type for k in kinds()}:
            declared += kind_named(type_name).keys
        table = {"type": toml_value(type_name), **_table(declared, keys)}
        spec = read_collider(Table(where, "", table), index)
        self._colliders.append(spec)
        return spec

    # ------------------------------------------------------------------ the results
    def scene(self) -> Scene:
        """The validated Scene: what ``load_scene`` gives for the same tables (its ``source`` is this builder's
        name). The checks across tables run here; a problem is a SceneError naming the builder and the key
        (``cloth[1].name``: the cloths and the colliders are numbered in the order they were added)."""
        if not self._cloths:
            raise SceneError(self.name, "cloth", "expected one or more cloths: add one with add_grid or add_mesh")
        scene = Scene(source=self.name, simulation=self.simulation, output=self.output, cloths=self.cloths,
                      colliders=self.colliders)
        check_scene(scene)
        return scene

    def finalize(self, device: str | None = None, colouring: str = "auto", sticks: str = "auto",
                 particle_order: str = "auto") -> "Model":
        """The immutable Model of :meth:`scene` on ``device`` (as ``Simulator``: "cpu", "cuda", "cuda:1"; default
        CUDA when a GPU is present), its memory need checked first as ``Simulator`` checks it. ``colouring``,
        ``sticks`` and ``particle_order`` are ``Simulator``'s arguments of the same names. A State of it is
        ``state.State(model)``."""
        from .core.simulator import build_model, resolve_device

        return build_model(self.scene(), resolve_device(device), colouring, sticks, particle_order)[0]


def _mesh_arrays(where: str, points: Any, faces: Any) -> tuple:
    """``points`` as a finite (V, 3) float64 array and ``faces`` as Faces, or a SceneError naming the argument."""
    import numpy as np

    from .geometry.faces import Faces

    if points is None or faces is None:
        missing = "points" if points is None else "faces"
        raise SceneError(where, missing, "is required with " + ("faces" if missing == "points" else "points")
                         + ": a mesh given in memory needs both")
    try:
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SceneError(where, "points", f"expected an (N, 3) array of numbers ({exc})") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise SceneError(where, "points", f"expected an (N, 3) array of numbers, got shape {p.shape}")
    finite = np.isfinite(p).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        shown = ", ".join(f"{v:g}" for v in p[bad])
        raise SceneError(where, f"points[{bad}]", f"expected a finite point, got ({shown})")
    if isinstance(faces, Faces):
        return p, faces
    try:
        if isinstance(faces, np.ndarray) or (len(faces) and len({len(f) for f in faces}) == 1):
            return p, Faces.uniform(np.asarray(faces))  # Faces refuses fractions and out-of-range indices
        counts = [len(f) for f in faces]
        return p, Faces(np.asarray(counts, np.int64), np.asarray([i for f in faces for i in f]))
    except (TypeError, ValueError) as exc:  # ArgumentError is a ValueError
        raise SceneError(where, "faces", f"expected an (F, k) array of vertex indices, a list of faces (each a list "
                         f"of vertex indices) or a Faces ({exc})") from None
