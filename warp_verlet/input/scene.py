"""Scene files: TOML in, a validated, immutable :class:`Scene` out.

This is the first stage of the one-way data flow
(scene file -> validated scene -> device state -> step loop -> writer). Nothing downstream ever
sees raw TOML: every key is checked here, once, and every failure is one :class:`SceneError` naming
the file, the key and what was expected.

Every key is declared once, as a :class:`~warp_verlet.scene_keys.Key` in :data:`SIMULATION_KEYS`,
:data:`OUTPUT_KEYS`, :data:`CLOTH_KEYS` (every cloth), :data:`GRID_KEYS` (a grid cloth) and
``mesh_scene.MESH_KEYS`` (a mesh cloth): its parser, default, type, unit, range and meaning. The loader takes each
key through its declaration, and ``docs/scenes.md``'s key tables are written from the same declarations
(``python docs/make_scene_tables.py``; tests/test_scene_docs.py fails when they are out of date). The keys that
constraint kinds add to a cloth are taken at one place, :func:`cloth_keys_of_kinds`, into ``ClothSpec.options``.
A scene built in Python (warp_verlet/builder.py, ``SceneBuilder``) is read by the same functions, table by table:
:func:`read_simulation`, :func:`read_output`, :func:`read_cloth` and ``colliders.read_collider``, then
:func:`check_scene`.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

from ..errors import SceneError
from ..scene_keys import (  # the table reader and value parsers, under the names this module has always used
    ARRAY, STRING, TABLE, FrozenMapping, Invalid as _Invalid, Key, Table as _Table, accepts, any_real as _any_real,
    boolean as _boolean, choice, describe as _describe, int_text as _int_text, integer,
    non_negative as _non_negative, per_element as _per_element, prim_name as _prim_name, real, record_key, text,
    toml_list as _toml_list, vector, NAMED_PINS, FLOAT32_MAX, FLOAT32_TINY, float32_fits,
)
from ..writer_registry import is_output_suffix, suffixes_text  # the output formats' suffixes (no pxr, no warp)

from ..colliders import kind_of, read_collider, specs_of
from ..colliders.plane import PLANE, PlaneCollider
from ..colliders.sphere import SPHERE, SphereCollider, read_path

if TYPE_CHECKING:  # the mesh modules (numpy) are imported only by a scene that has a mesh cloth
    from .mesh_scene import MeshSpec

RELAXATIONS = ("coloured", "jacobi")
PRECISIONS = ("auto", "float32", "float64")  # positions' float type; "auto" is resolved in precision.py
GLOBAL_PRECONDITIONERS = ("multigrid", "jacobi")  # the global correction's preconditioner
CONTACT_PROJECTIONS = ("after_sweeps", "every_sweep")  # when the collider clamp runs in a substep
ORIENTATIONS = ("vertical", "horizontal")
STICK_FAMILIES = ("structural", "shear", "bend")
UP_AXES = ("Y", "Z")
OUTPUT_KINDS = ("cache", "override")  # a standalone point cache, or a layer over the USD asset the cloths came from
TORN_FACES = ("remove", "holes")  # how a cache shows torn faces: left out of the topology, or holeIndices
# Named pin groups; each maps (rows, cols) to a list of (row, col). Row 0 is the top edge (the origin's
# edge), column 0 the left edge.


# Default aerodynamic coefficients of a cloth's faces (docs/scenes.md, "Air", says where they come from).
FABRIC_DRAG_COEFFICIENT = 1.2
FABRIC_LIFT_COEFFICIENT = 0.5
AIR_DENSITY = 1.2  # kg/m^3: dry air at sea level and 20 °C


@dataclass(frozen=True)
class AirSettings:
    """The air a scene's cloths move through ([simulation.air]): its velocity (keyframes, (time s, (x, y, z)
    m/s), linear between them and held at the ends, as a sphere's path), its density, and an optional seeded
    gust field (warp_verlet/core/aerodynamics.py)."""

    velocity: tuple[tuple[float, tuple[float, float, float]], ...] = ((0.0, (0.0, 0.0, 0.0)),)
    density: float = AIR_DENSITY
    gust_speed: float = 0.0  # m/s, RMS over space and time; 0: no gusts
    gust_length: float = 1.0  # m
    gust_period: float = 1.0  # s
    gust_seed: int = 0

    @property
    def keyframes(self):
        """The velocity's keyframes, named as a collider's are (colliders.kind.keyframe_arrays reads them)."""
        return self.velocity

    @property
    def moving(self) -> bool:
        """Whether the velocity changes with time (more than one distinct keyframe value)."""
        return len({v for _, v in self.velocity}) > 1

    @property
    def gusts(self) -> bool:
        return self.gust_speed > 0.0

    @property
    def felt(self) -> bool:
        """Whether the air pushes at all: a density of 0 is no air."""
        return self.density > 0.0


TARGET_ITERATIONS = 2  # sweeps per substep when target_stretch chooses the substeps (warp_verlet/core/budget.py)


@dataclass(frozen=True)
class SimulationSettings:
    fps: float = 60.0
    frames: int = 120
    substeps: int = 4
    iterations: int = 8
    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    damping: float = 0.0  # 1/s: the implicit velocity decays as exp(-damping t), whatever the substeps
    relaxation: str = "coloured"
    multilevel: bool = False  # a coarse-to-fine pass over each grid's hierarchy before every substep's sweeps
    multilevel_sweeps: int = 1  # sweeps per coarse level per substep
    contact_projection: str = "after_sweeps"  # or "every_sweep": the collider clamp also ends every sweep
    global_iterations: int = 0  # conjugate-gradient iterations of the global correction per Gauss-Newton step (0: off)
    global_newton: int = 1  # Gauss-Newton steps of the global correction per substep
    global_preconditioner: str = "multigrid"  # or "jacobi"; a scene with a mesh cloth always gets "jacobi"
    target_stretch: float | None = None  # RMS structural stretch (fraction) the substeps are chosen to stay under
    max_substeps: int = 1024  # the most substeps a target_stretch budget may choose
    min_substeps: int = 1  # the fewest substeps a target_stretch budget may choose (it starts at least there)
    max_dt_ratio: float = 2.0
    max_frame_time: float = 0.1
    position_bound: float = 1.0e4
    precision: str = "auto"  # positions' float type: "float32", "float64", or "auto" (warp_verlet/core/precision.py)
    air: AirSettings | None = None  # [simulation.air]: drag and lift on the cloths' faces; None: no air

    @property
    def dt(self) -> float:
        """The fixed physics time step in seconds."""
        return 1.0 / (self.fps * self.substeps)


@dataclass(frozen=True)
class OutputSettings:
    path: Path
    save_every: int = 10
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    kind: str = "cache"  # "cache" or "override" (a layer over the cloths' USD asset)
    torn_faces: str = "remove"  # "remove" (the default of a cache) or "holes" (of an override layer)


@dataclass(frozen=True)
class ClothSpec:
    """One cloth: a grid (``resolution`` and ``size``) or a mesh (``mesh``; resolution and size are None)."""

    name: str
    resolution: tuple[int, int] | None
    size: tuple[float, float] | None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: str = "vertical"
    mass: float = 1.0
    sticks: tuple[str, ...] = ("structural",)  # stick families to build, in STICK_FAMILIES order
    compliance: dict[str, float] = field(default_factory=dict)  # m/N per soft family (XPBD); absent: rigid
    pins: tuple[tuple[int, int], ...] = ()
    tear_threshold: float | None = None  # a stick tears beyond this multiple of its rest length; None: never
    tear_tension: float | None = None  # N/m: a stick tears above this tension per metre of width; None: never
    particle_masses: tuple[tuple[int, int, float], ...] = ()  # (row, col, kg): overrides of the even share
    tethers: bool | None = None  # None: on when the cloth has pins and cannot tear
    tether_scale: float = 1.0  # tether length / rest-pose distance to the pin (> 1: slack for a soft cloth)
    mesh: "MeshSpec | None" = None  # a mesh cloth (then pins and particle_masses above are empty)
    drag_coefficient: float = FABRIC_DRAG_COEFFICIENT  # of its faces in [simulation.air]
    lift_coefficient: float = FABRIC_LIFT_COEFFICIENT
    options: Mapping[str, Any] = field(default_factory=lambda: kind_options({}))
    """The values of the keys the constraint kinds declare (cloth_keys_of_kinds), by key name (each key's default
    where the scene does not give it), as each kind's ``check_cloth`` resolved them; read-only."""

    @property
    def uses_tethers(self) -> bool:
        """Tethers are on by default for a pinned grid that cannot tear. A tether holds a particle within its
        rest distance of a pin, so the sticks it guards could never reach a stretch threshold: a tearing cloth
        gets them only when asked (with a tether_scale above its tear_threshold, to tear at all). A mesh cloth
        gets them only when asked too: a tether's length is the straight rest distance, which is the distance
        along the cloth only for a flat panel whose straight lines stay on it."""
        if self.tethers is not None:
            return self.tethers
        return self.mesh is None and self.pin_count > 0 and not self.tears

    @property
    def tears(self) -> bool:
        """Whether the cloth can tear, by stretch (tear_threshold), by tension (tear_tension) or both."""
        return self.tear_threshold is not None or self.tear_tension is not None

    @property
    def tethers_per_particle(self) -> int:
        """Each tethered particle is tied to its nearest one or two pins."""
        return min(2, self.pin_count) if self.uses_tethers else 0

    @property
    def pin_count(self) -> int:
        return len(self.mesh.pins) if self.mesh is not None else len(set(self.pins))

    @property
    def particle_count(self) -> int:
        if self.mesh is not None:
            return self.mesh.mesh.particle_count
        return self.resolution[0] * self.resolution[1]


@dataclass(frozen=True)
class Scene:
    source: str
    simulation: SimulationSettings
    output: OutputSettings
    cloths: tuple[ClothSpec, ...]
    colliders: tuple = ()

    @property
    def planes(self) -> tuple[PlaneCollider, ...]:
        return specs_of(self.colliders, PLANE)

    @property
    def spheres(self) -> tuple[SphereCollider, ...]:
        return specs_of(self.colliders, SPHERE)

    @property
    def particle_count(self) -> int:
        return sum(c.particle_count for c in self.cloths)

    @property
    def tears(self) -> bool:
        return any(c.tears for c in self.cloths)

    @property
    def tears_by_tension(self) -> bool:
        """Whether a cloth tears by tension: the relaxation then keeps each stick's tension (kernels/tear.py)."""
        return any(c.tear_tension is not None for c in self.cloths)

    @property
    def tethered_particles(self) -> int:
        """Free particles of the cloths that use tethers: one tether thread each."""
        return sum(c.particle_count - c.pin_count for c in self.cloths if c.uses_tethers)

    @property
    def tether_rows(self) -> int:
        """Rows of the tether table: the particles from the first tethered cloth's first to the last one's last
        (constraints/tethers.TetherTable)."""
        if not self.tethered_particles:
            return 0  # no table
        tethered = [i for i, c in enumerate(self.cloths) if c.uses_tethers]
        return sum(c.particle_count for c in self.cloths[tethered[0]:tethered[-1] + 1])

    @property
    def tethers_per_particle(self) -> int:
        return max((c.tethers_per_particle for c in self.cloths), default=0)

    @property
    def compliant(self) -> bool:
        """Does any cloth have soft (XPBD) sticks?"""
        return any(c.compliance for c in self.cloths)




# ------------------------------------------------------------------------------------------------------------
# The keys of [simulation] and [output], in the order of their tables in docs/scenes.md. The dataclasses above
# hold the same defaults for settings built in code (tests/test_scene_docs.py checks that they agree).

SIMULATION_KEYS: tuple[Key, ...] = (
    Key("fps", real(0.0, lo_open=True), 60.0, "number", "Hz", allowed="> 0",
        doc="Frames per second of the output. It is also the rate of the USD time codes."),
    Key("frames", integer(1), 120, "integer", "frames", allowed="≥ 1",
        doc="Number of frames simulated after the initial pose."),
    Key("substeps", integer(1, 10_000), 4, "integer", allowed="1 … 10 000",
        doc="Fixed physics steps per frame. The step is `dt = 1 / (fps × substeps)` s."),
    Key("iterations", integer(0, 100_000), 8, "integer", allowed="0 … 100 000",
        doc="Number of constraint relaxation sweeps per substep (K below). With 0, the sticks are not solved."),
    Key("gravity", vector(3, _any_real), (0.0, -9.81, 0.0), "[x, y, z] numbers", "m/s²", allowed="finite",
        doc="Uniform acceleration applied to every free particle."),
    Key("wind", vector(3, _any_real), (0.0, 0.0, 0.0), "[x, y, z] numbers", "m/s²", allowed="finite",
        doc="Uniform acceleration added to `gravity`: not air, so no drag and no flutter (see below). For air "
            "that pushes on each face, see `[simulation.air]`."),
    Key("damping", real(0.0), 0.0, "number", "1/s", allowed="≥ 0",
        doc="Rate at which the implicit velocity decays: it falls as `exp(-damping × t)`, whatever `substeps` is. "
            "0 means no damping (see below)."),
    Key("relaxation", choice(RELAXATIONS), "coloured", "string", allowed='`"coloured"`, `"jacobi"`',
        doc="How the sticks are relaxed (see below): graph-coloured Gauss-Seidel, or Jacobi averaging. (`solver`, "
            "its old name, is an error that names it.)"),
    Key("target_stretch", real(0.0, 1.0, lo_open=True, hi_open=True), None, "number", "fraction",
        default_text="none", allowed="0 < x < 1",
        doc="Choose the substeps frame by frame to keep the RMS structural stretch under this (0.01 = 1 %); see "
            "\"A budget from `target_stretch`\" below. Not with `substeps`."),
    Key("max_substeps", integer(1, 100_000), 1024, "integer", "substeps", allowed="1 … 100 000",
        doc="The most substeps per frame a `target_stretch` budget may choose."),
    Key("min_substeps", integer(1, 100_000), 1, "integer", "substeps", allowed="1 … 100 000; at most `max_substeps`",
        doc="The fewest substeps per frame a `target_stretch` budget may choose: it starts there (or at 4, if "
            "more) and never halves below. The budget reads the stretch after each frame, so a sudden load, "
            "such as a cloth landing on a collider, stretches the frames it takes to add the substeps; this "
            "holds them from the start. Only with `target_stretch`."),
    Key("multilevel", _boolean, False, "boolean",
        doc="A coarse-to-fine pass over each grid's hierarchy before every substep's sweeps (see \"Multilevel pass\" "
            "below). Not with a cloth that can tear (`tear_threshold` or `tear_tension`), soft structural sticks or "
            "`global_iterations`."),
    Key("multilevel_sweeps", integer(1, 1000), 1, "integer", "sweeps", allowed="1 … 1000",
        doc="Sweeps of each coarse level per substep."),
    Key("contact_projection", choice(CONTACT_PROJECTIONS), "after_sweeps", "string",
        allowed='`"after_sweeps"`, `"every_sweep"`',
        doc="When the colliders push the cloth out (see \"Contact inside the sweeps\" below): once, after the "
            "substep's sweeps, or also at the end of every sweep, so that the next sweep relaxes the sticks next to "
            "each contact from where the contact left them."),
    Key("global_iterations", integer(0, 10_000), 0, "integer", "iterations", allowed="0 … 10 000",
        doc="Conjugate-gradient iterations of the global correction per Gauss-Newton step (see \"Global "
            "correction\" below); 0 leaves it out. It moves the whole cloth towards its stick lengths, with contact "
            "inside, before each substep's sweeps."),
    Key("global_newton", integer(1, 100), 1, "integer", "steps", allowed="1 … 100",
        doc="Gauss-Newton steps of the global correction per substep (each re-reads the sticks' directions)."),
    Key("global_preconditioner", choice(GLOBAL_PRECONDITIONERS), "multigrid", "string",
        allowed='`"multigrid"`, `"jacobi"`',
        doc="What speeds up the global correction's conjugate gradients: a multigrid cycle over the grid's levels, "
            "or each particle's own 3 × 3 block. A scene with a mesh cloth always uses `\"jacobi\"`."),
    Key("max_dt_ratio", real(1.0), 2.0, "number", allowed="≥ 1",
        doc="Upper limit on `dt / dt_prev` in the time-step-corrected Verlet update."),
    Key("max_frame_time", real(0.0, lo_open=True), 0.1, "number", "s", allowed="> 0",
        doc="Upper limit on the time banked by `Simulator.advance` (see below)."),
    Key("position_bound", real(0.0, lo_open=True), 1.0e4, "number", "m", default_text="`1.0e4`", allowed="> 0",
        doc="Divergence guard: a coordinate with \\|x\\| above this value stops the run."),
    Key("precision", choice(PRECISIONS), "auto", "string", allowed='`"auto"`, `"float32"`, `"float64"`',
        doc="Float type of the particle positions (see *The smallest step* below). `\"auto\"`: float32, unless the "
            "scene's `dt` is below the float32 limit, then float64."),
    Key("air", accepts(TABLE)(lambda value, key: read_air(value, key)), None, "table", default_text="absent: no air",
        allowed="the keys of `[simulation.air]`",
        doc="Air with a velocity and a density: drag and lift on every face of the cloths (see [air](#air))."),
)


@accepts(ARRAY)
def _air_velocity(value: Any, key: str) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """A constant [x, y, z], or keyframes [[t, x, y, z], ...] as a sphere's path (colliders/sphere.read_path)."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return read_path(value, key)
    if isinstance(value, list) and any(isinstance(v, list) for v in value):
        raise _Invalid("expected [x, y, z] numbers (a constant velocity) or an array of [t, x, y, z] keyframes, "
                       "got a mix of numbers and arrays")
    return ((0.0, vector(3, _any_real)(value, key)),)


AIR_KEYS: tuple[Key, ...] = (
    Key("velocity", _air_velocity, ((0.0, (0.0, 0.0, 0.0)),), "[x, y, z] numbers, or array of [t, x, y, z]",
        "m/s (s, m/s)", default_text="`[0.0, 0.0, 0.0]`: still air",
        allowed="finite; keyframes: at least one, times strictly increasing",
        doc="The air's velocity: constant, or keyframed (linear between keyframes, held at the first before it and "
            "at the last after it, as a sphere's `path`)."),
    Key("density", real(0.0), AIR_DENSITY, "number", "kg/m³", allowed="≥ 0",
        doc="Mass of air per volume (1.2 at sea level and 20 °C). 0 means no aerodynamic force at all."),
    Key("gust_speed", real(0.0), 0.0, "number", "m/s", allowed="≥ 0",
        doc="RMS speed of the gusts added to `velocity` (0: none); see [gusts](#gusts)."),
    Key("gust_length", real(0.0, lo_open=True), 1.0, "number", "m", allowed="> 0",
        doc="Mean wavelength of the gusts in space."),
    Key("gust_period", real(0.0, lo_open=True), 1.0, "number", "s", allowed="> 0",
        doc="Mean period of the gusts in time."),
    Key("gust_seed", integer(0, 2**32 - 1), 0, "integer", allowed="0 … 4 294 967 295",
        doc="Seed of the gusts' random sinusoids: the same seed gives the same gusts."),
)


def read_air(data: Any, key: str) -> AirSettings:
    """The [simulation.air] table ``data``, whose dotted key is ``key``: the parser of the ``air`` key, so a
    problem is raised as :class:`Invalid` naming the inner key, and the table reader adds the file."""
    try:
        t = _Table("", key, data)
        settings = AirSettings(**{k.name: k.take(t) for k in AIR_KEYS})
        t.finish()
    except SceneError as error:
        raise _Invalid(error.problem, error.key) from None
    return settings


def read_simulation(file: str, data: Any, path: str = "simulation") -> SimulationSettings:
    """The [simulation] table ``data``, checked: the loader's and SceneBuilder.set_simulation's one reader. ``path``
    is the table's key in errors ("" where ``file`` already names it)."""
    t = _Table(file, path, data)
    if "drag" in t.data:
        raise t.error("drag", _drag_moved(t.data))
    if "solver" in t.data:
        raise t.error("solver", 'is renamed relaxation (the scheme that relaxes the sticks): write relaxation = '
                      '"coloured" (graph-coloured Gauss-Seidel) or "jacobi"')
    settings = SimulationSettings(**{key.name: key.take(t) for key in SIMULATION_KEYS})
    t.finish()
    if "min_substeps" in t.data:
        if settings.target_stretch is None:
            raise t.error("min_substeps", "bounds the substeps a target_stretch budget chooses, and this scene has "
                          "no target_stretch: set substeps instead, or add target_stretch")
        if settings.min_substeps > settings.max_substeps:
            raise t.error("min_substeps", f"at most max_substeps ({settings.max_substeps}), got "
                          f"{settings.min_substeps}")
        settings = replace(settings, substeps=max(settings.substeps, settings.min_substeps))
    if settings.target_stretch is not None:
        if "substeps" in t.data:
            raise t.error("target_stretch", "substeps chosen by the scene: with target_stretch the simulator "
                          "chooses them (set max_substeps to cap it), so remove one of the two")
        if settings.max_dt_ratio < 2.0:
            raise t.error("target_stretch", f"max_dt_ratio >= 2, since the budget doubles the substeps (halves "
                          f"dt) in one step; got max_dt_ratio = {settings.max_dt_ratio:g}")
        if "iterations" not in t.data:
            settings = replace(settings, iterations=TARGET_ITERATIONS)
    return settings


@accepts(STRING)
def _usd_path(value: Any, key: str) -> Path:
    if "\0" in text(value, key):
        raise _Invalid("expected a path without NUL characters")
    p = Path(value)
    if not is_output_suffix(p.suffix):  # a registered writer's (writer_registry.py)
        raise _Invalid(f"expected a path ending in {suffixes_text()}, got {value!r}")
    return p


OUTPUT_KEYS: tuple[Key, ...] = (
    # None: named after the scene file (read_output)
    Key("path", _usd_path, None, "string", default_text='`"<scene stem>.usdc"`',
        allowed="ends in a registered output suffix (`.usd`, `.usda` or `.usdc`)", doc="Where the USD point cache is written."),
    Key("save_every", integer(1), 10, "integer", "frames", allowed="≥ 1",
        doc="How often the writer saves the layer to disk."),
    Key("up_axis", choice(UP_AXES), "Y", "string", allowed='`"Y"`, `"Z"`', doc="The stage's `upAxis` metadata."),
    Key("meters_per_unit", real(0.0, lo_open=True), 1.0, "number", "m", allowed="> 0",
        doc="The stage's `metersPerUnit` metadata."),
    Key("kind", choice(OUTPUT_KINDS), "cache", "string", allowed='`"cache"`, `"override"`',
        doc="A standalone point cache, or an override layer over the USD asset the cloths came from (see below)."),
    # None: chosen by kind (read_output)
    Key("torn_faces", choice(TORN_FACES), None, "string",
        default_text='`"remove"` for a cache, `"holes"` for an override', allowed='`"remove"`, `"holes"`',
        doc="How a tearing cloth shows its torn faces (see below)."),
)


def read_output(file: str, data: Any, scene_path: Path, path: str = "output") -> OutputSettings:
    """The [output] table ``data``, checked (the default path is named after ``scene_path``): the loader's and
    SceneBuilder.set_output's one reader."""
    t = _Table(file, path, data)
    values = {key.name: key.take(t) for key in OUTPUT_KEYS}
    if values["path"] is None:
        values["path"] = Path(scene_path.stem + ".usdc")
    if values["torn_faces"] is None:
        # A cache leaves torn faces out of the topology, which every DCC shows (Blender ignores holeIndices); an
        # override layer keeps the asset's faces, whose indices its GeomSubsets and material bindings use.
        values["torn_faces"] = "holes" if values["kind"] == "override" else "remove"
    settings = OutputSettings(**values)
    t.finish()
    if settings.kind == "override":
        for key in ("up_axis", "meters_per_unit"):
            if key in t.data:
                raise t.error(key, "an override layer takes upAxis and metersPerUnit from the asset it overrides; "
                              f"remove {key} (or write kind = \"cache\")")
    return settings


def _drag_moved(data: dict) -> str:
    """The error for the old per-substep ``drag``, with the damping rate that means the same at this budget."""
    drag, fps, substeps = data.get("drag"), data.get("fps", 60.0), data.get("substeps", 4)
    hint = "damping = -ln(drag) x fps x substeps"
    numbers = (drag, fps, substeps)
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers) and 0 < drag <= 1 and fps > 0:
        rate = -math.log(drag) * fps * substeps
        hint = f"damping = {rate:.4g} (= -ln({drag}) x {fps:g} fps x {substeps} substeps)" if rate > 0 else \
            "damping = 0 (the default: it keeps all the velocity, as drag = 1 did)"
    return ("drag (the velocity kept per substep, so the cloth changed with substeps) is replaced by damping, a "
            f"rate per second (velocity decays as exp(-damping t)); for the same motion at this budget write {hint}")


@accepts(ARRAY)
def _read_sticks(value: Any, key: str) -> tuple[str, ...]:
    if isinstance(value, dict):
        soft = {f: k for f, k in value.items() if isinstance(k, (int, float)) and not isinstance(k, bool) and k != 1}
        families = [f for f in STICK_FAMILIES if f in value]
        hint = f"sticks = {_toml_list(families or ['structural'])}"
        if soft:
            hint += (" and, for a soft family, its XPBD compliance in m/N (0 = rigid), e.g. compliance = { "
                     + ", ".join(f"{f} = 1e-3" for f in soft) + " }")
        raise _Invalid("the table form { family = stiffness } is gone: a stiffness per relaxation made the cloth "
                       f"change with substeps and iterations; write {hint}")
    if not isinstance(value, list) or not value:
        raise _Invalid(f"expected a non-empty array of stick families from {_toml_list(STICK_FAMILIES)}, "
                       f"got {_describe(value)}")
    for i, family in enumerate(value):
        if family not in STICK_FAMILIES:
            raise _Invalid(f"unknown stick family {family!r} (expected one of {', '.join(STICK_FAMILIES)})",
                           f"{key}[{i}]")
    if len(set(value)) != len(value):
        raise _Invalid(f"a stick family is listed twice: {_toml_list(value)}")
    return tuple(f for f in STICK_FAMILIES if f in value)


_COMPLIANCE = _per_element(real(0.0))  # m/N per stick family, 0 = rigid


@accepts(TABLE)
def _read_compliance(value: Any, key: str) -> dict[str, float]:
    for family in STICK_FAMILIES:
        record_key(f"{key}.{family}", _COMPLIANCE)
    if not isinstance(value, dict):
        raise _Invalid(f"expected a table like {{ bend = 1e-3 }} (m/N per stick family), got {_describe(value)}")
    out: dict[str, float] = {}
    for family, alpha in value.items():
        if family not in STICK_FAMILIES:
            raise _Invalid(f"unknown stick family (expected {', '.join(STICK_FAMILIES)})", f"{key}.{family}")
        alpha = _COMPLIANCE(alpha, f"{key}.{family}")
        if alpha > 0.0:  # 0 means rigid, the default
            out[family] = alpha
    return out


def _read_pins(value: Any, key: str, rows: int, cols: int) -> tuple[tuple[int, int], ...]:
    if not isinstance(value, list):
        raise _Invalid(f"expected an array of pin names, indices or [row, col] pairs, got {_describe(value)}")
    pins: list[tuple[int, int]] = []
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if isinstance(item, str):
            if item not in NAMED_PINS:
                raise _Invalid(f"unknown pin name {item!r} (expected one of {', '.join(NAMED_PINS)})", item_key)
            pins.extend(NAMED_PINS[item](rows, cols))
        elif isinstance(item, int) and not isinstance(item, bool):
            if not 0 <= item < rows * cols:
                raise _Invalid(f"particle index {_int_text(item)} is outside the grid (0 .. {rows * cols - 1})", item_key)
            pins.append(divmod(item, cols))
        elif isinstance(item, list) and len(item) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in item):
            r, c = item
            if not (0 <= r < rows and 0 <= c < cols):
                raise _Invalid(f"[row, col] = [{_int_text(r)}, {_int_text(c)}] is outside the {rows} x {cols} grid", item_key)
            pins.append((r, c))
        else:
            raise _Invalid(f"expected a pin name, a particle index or a [row, col] pair, got {_describe(item)}", item_key)
    return tuple(sorted(set(pins)))


def _read_particle_masses(value: Any, key: str, rows: int, cols: int) -> tuple[tuple[int, int, float], ...]:
    if not isinstance(value, list):
        raise _Invalid(f"expected an array of [row, col, kg] triples, got {_describe(value)}")
    out: dict[tuple[int, int], float] = {}
    for i, item in enumerate(value):
        item_key = f"{key}[{i}]"
        if not (isinstance(item, list) and len(item) == 3):
            raise _Invalid(f"expected a [row, col, kg] triple, got {_describe(item)}", item_key)
        r = _per_element(integer(0, rows - 1))(item[0], f"{item_key}[0]")
        c = _per_element(integer(0, cols - 1))(item[1], f"{item_key}[1]")
        kg = _per_element(real(0.0, lo_open=True))(item[2], f"{item_key}[2]")
        if (r, c) in out:
            raise _Invalid(f"particle [{r}, {c}] is given a mass twice", item_key)
        out[(r, c)] = kg
    return tuple((r, c, kg) for (r, c), kg in out.items())


# ------------------------------------------------------------------------------------------------------------
# The keys of a [[cloth]]: those every cloth has, those of a grid, and (mesh_scene.MESH_KEYS) those of a mesh.

CLOTH_KEYS: tuple[Key, ...] = (  # every cloth, grid or mesh
    # None: cloth<i>, by the cloth's place in the file (read_cloth)
    Key("name", _prim_name, None, "string", default_text='`"cloth<i>"` (`cloth0`, `cloth1`, …)',
        allowed="letters, digits and `_`, not starting with a digit; unique among the cloths and the colliders; "
                "not `Colliders`",
        doc="The USD prim name of this cloth's mesh."),
    Key("mass", real(0.0, lo_open=True), 1.0, "number", "kg",
        allowed="> 0; each particle's inverse mass a normal float32 (see the value rules)",
        doc="Total mass. A grid spreads it evenly: each particle carries `mass / (rows × cols)`; a mesh spreads it "
            "as `mass_distribution` says."),
    Key("sticks", _read_sticks, ("structural",), "array of family names",
        allowed='`"structural"`, `"shear"`, `"bend"`; at least one, each at most once',
        doc="Which stick families to build (see [stick families](#stick-families))."),
    Key("compliance", _read_compliance, {}, "table of family = number", "m/N", default_text="`{}`: every stick rigid",
        allowed="families listed in `sticks`; ≥ 0, finite; coloured solver only",
        doc="XPBD compliance of a soft family: how far its sticks stretch per newton of tension. 0 means rigid."),
    Key("tear_threshold", real(1.0, lo_open=True), None, "number", "– (a ratio of rest length)",
        default_text="absent: the cloth never tears", allowed="> 1, finite",
        doc="A stick stretched beyond `tear_threshold × L` is removed (see [tearing](#tearing))."),
    Key("tear_tension", real(0.0, lo_open=True), None, "number", "N/m (tension per metre of cloth width)",
        default_text="absent: the cloth never tears by tension", allowed="> 0, finite; coloured solver only",
        doc="A stick whose tension, averaged over 10 ms, exceeds `tear_tension × L` newtons is removed (see "
            "[tearing](#tearing)). With `tear_threshold` too, either tears."),
    # None: ClothSpec.uses_tethers decides
    Key("tethers", _boolean, None, "boolean",
        default_text="on for a grid with pins that cannot tear (no `tear_threshold` or `tear_tension`), else off "
                     "(on a mesh: off unless asked, see [mesh cloth](#mesh-cloth))",
        allowed="`true` needs pins",
        doc="Long-range attachments (see [tethers](#tethers)): each free particle stays within its rest-pose "
            "distance of its nearest one or two pins."),
    Key("tether_scale", real(1.0), 1.0, "number", "– (a ratio of the rest-pose distance)", allowed="≥ 1, finite",
        doc="Slack: a tether allows `tether_scale ×` the rest distance, for a cloth meant to stretch."),
    Key("drag_coefficient", real(0.0), FABRIC_DRAG_COEFFICIENT, "number", allowed="≥ 0",
        doc="C_d of this cloth's faces in `[simulation.air]`: the pressure force along a face's normal (see "
            "[air](#air)); 1.2 is a flat plate across the flow."),
    Key("lift_coefficient", real(0.0), FABRIC_LIFT_COEFFICIENT, "number", allowed="≥ 0",
        doc="C_l of this cloth's faces in `[simulation.air]`: the force across the relative wind of a face held "
            "at an angle to it (see [air](#air))."),
)

GRID_KEYS: tuple[Key, ...] = (  # a grid cloth: its particles from resolution and size
    Key("resolution", vector(2, _per_element(integer(1, 1 << 15))), type="[rows, cols] integers", unit="particles",
        allowed="each 1 … 32 768; at least 2 particles in all", doc="Grid size in particles."),
    Key("size", vector(2, _non_negative), type="[along rows, along cols] numbers", unit="m",
        allowed="≥ 0; > 0 on an axis with more than one particle",
        doc="Extent of the grid: first the distance from the first row to the last, then from the first column to "
            "the last."),
    Key("origin", vector(3, _any_real), (0.0, 0.0, 0.0), "[x, y, z] numbers", "m", allowed="finite",
        doc="Position of particle 0 (row 0, column 0)."),
    Key("orientation", choice(ORIENTATIONS), "vertical", "string", allowed='`"vertical"`, `"horizontal"`',
        doc="Which way the rows run (see the grid conventions)."),
    Key("pins", default=(), type="array", allowed="names, indices or [row, col] pairs inside the grid",
        doc="Particles held fixed in place for the whole run (see [pins](#pins)).",
        bind=lambda rows, cols: accepts(ARRAY)(lambda v, k: _read_pins(v, k, rows, cols))),
    Key("particle_masses", default=(), type="array of [row, col, kg]", unit="–, –, kg",
        allowed="row, col inside the grid, each particle at most once; kg > 0",
        doc="Per-particle overrides of the even share: a heavy weight at the hem, a light chain with a heavy end. A "
            "pinned particle stays pinned whatever its mass.",
        bind=lambda rows, cols: accepts(ARRAY)(lambda v, k: _read_particle_masses(v, k, rows, cols))),
)

_CLOTH = {key.name: key for key in CLOTH_KEYS}
_GRID = {key.name: key for key in GRID_KEYS}


def cloth_keys_of_kinds() -> tuple[Key, ...]:
    """The [[cloth]] keys that constraint kinds declare (the modules of warp_verlet/constraints/), taken from every
    cloth, grid or mesh, after its own keys; their values land in ``ClothSpec.options`` by key name. This is the
    one place the loader asks for them: empty while no kind declares a key. A kind's keys are documented by its
    own table in docs/scenes.md, written from the same declarations (docs/make_scene_tables.py). Imported here,
    not at the top: the kinds need numpy, which ``import warp_verlet`` does without."""
    from ..constraints import cloth_keys

    return cloth_keys()


def kind_options(values: dict[str, Any]) -> FrozenMapping:
    """A cloth's options: ``values`` over the defaults of every key the constraint kinds declare."""
    return FrozenMapping({**{key.name: key.default for key in cloth_keys_of_kinds()}, **values})


def _read_options(t: _Table) -> FrozenMapping:
    return kind_options({key.name: key.take(t) for key in cloth_keys_of_kinds()})


def read_cloth(file: str, index: int, data: Any, scene_dir: Path, path: str | None = None,
               mesh_arrays: tuple | None = None) -> ClothSpec:
    """One [[cloth]] table ``data``, the ``index``-th cloth, checked (a mesh file relative to ``scene_dir``): the
    loader's and SceneBuilder.add_grid / add_mesh's one reader. ``path`` is the table's key in errors (default
    ``cloth[index]``); ``mesh_arrays``: a mesh given in memory as (points, Faces), whose table then names no file."""
    t = _Table(file, f"cloth[{index}]" if path is None else path, data)
    if mesh_arrays is not None or (isinstance(data, dict) and "mesh" in data):
        return _read_mesh_cloth(t, index, scene_dir, mesh_arrays)

    name = _CLOTH["name"].take(t)
    rows, cols = _GRID["resolution"].take(t)
    if rows * cols < 2:
        raise t.error("resolution", "expected at least 2 particles, got a 1 x 1 grid")
    size = _GRID["size"].take(t)
    for axis, (n, s) in enumerate(zip((rows, cols), size)):
        if n > 1 and s <= 0.0:
            raise t.error(f"size[{axis}]", f"expected a length > 0 m along an axis with {n} particles, got {s}")
    spec = ClothSpec(
        name=f"cloth{index}" if name is None else name,
        resolution=(rows, cols),
        size=size,
        origin=_GRID["origin"].take(t),
        orientation=_GRID["orientation"].take(t),
        mass=_CLOTH["mass"].take(t),
        sticks=_CLOTH["sticks"].take(t),
        compliance=_CLOTH["compliance"].take(t),
        pins=_GRID["pins"].bound(rows, cols).take(t),
        tear_threshold=_CLOTH["tear_threshold"].take(t),
        tear_tension=_CLOTH["tear_tension"].take(t),
        particle_masses=_GRID["particle_masses"].bound(rows, cols).take(t),
        tethers=_CLOTH["tethers"].take(t),
        tether_scale=_CLOTH["tether_scale"].take(t),
        drag_coefficient=_CLOTH["drag_coefficient"].take(t),
        lift_coefficient=_CLOTH["lift_coefficient"].take(t),
        options=_read_options(t),
    )
    t.finish()
    return check_cloth(t, spec)


def _read_mesh_cloth(t: _Table, index: int, scene_dir: Path, mesh_arrays: tuple | None = None) -> ClothSpec:
    """A cloth from a mesh file (or from ``mesh_arrays``, points and faces in memory): the mesh keys are read by
    warp_verlet/input/mesh_scene.py (imported only here: numpy, and trimesh or pxr), the keys every cloth has here; the
    file is read once every key has been checked."""
    from . import mesh_scene

    mesh_keys = {key.name for key in mesh_scene.MESH_KEYS}
    for key in GRID_KEYS:
        if key.name not in mesh_keys and key.name in t.data:
            raise t.error(key.name, f"a mesh cloth takes its particles from the mesh: remove {key.name} (or mesh, for "
                          "a grid)")
    request = mesh_scene.read_mesh_keys(t, scene_dir, in_memory=mesh_arrays is not None)
    values = {key.name: key.take(t) for key in CLOTH_KEYS}
    if values["name"] is None:
        values["name"] = f"cloth{index}"
    spec = ClothSpec(resolution=None, size=None, **values, options=_read_options(t))
    t.finish()
    spec = replace(spec, mesh=mesh_scene.load_mesh(t, request, spec.options, mesh_arrays))
    if spec.tears and spec.mesh.mesh.non_manifold_edges:
        key = "tear_threshold" if spec.tear_threshold is not None else "tear_tension"
        raise t.error(key, f"tearing needs a manifold mesh (each edge beside at most two faces, to "
                      f"know which faces a torn edge opens), and {spec.mesh.mesh.non_manifold_edges} edges have more")
    return check_cloth(t, spec)


def check_cloth(t: _Table, spec: ClothSpec) -> ClothSpec:
    """What a grid and a mesh cloth must both satisfy once read; each constraint kind then checks its options
    against the cloth and resolves them. Returns the cloth with its options resolved."""
    if spec.tethers and not spec.pin_count:
        raise t.error("tethers", "expected pins: a tether ties a particle to a pin, and this cloth has none")
    missing = sorted(set(spec.compliance) - set(spec.sticks))
    if missing:
        raise t.error(f"compliance.{missing[0]}", f"gives a compliance to the {missing[0]} family, which sticks = "
                      f"{_toml_list(spec.sticks)} does not build")
    from ..constraints import kinds

    for kind in kinds():
        resolved = kind.check_cloth(spec, t)
        if resolved:
            spec = replace(spec, options=kind_options({**spec.options, **resolved}))
    return spec


def parse_scene(data: dict, file: str = "<scene>", scene_path: Path | None = None) -> Scene:
    """Validate an already-parsed TOML document. ``file`` is used in error messages."""
    scene_path = scene_path or Path(file)
    top = _Table(file, "", data)
    simulation = (top.take("simulation", accepts(TABLE)(lambda v, k: read_simulation(file, v)), None)
                  or read_simulation(file, {}))
    output = (top.take("output", accepts(TABLE)(lambda v, k: read_output(file, v, scene_path)), None)
              or read_output(file, {}, scene_path))

    @accepts(ARRAY)
    def cloths(value: Any, key: str) -> tuple[ClothSpec, ...]:
        if not isinstance(value, list) or not value:
            raise _Invalid("expected one or more [[cloth]] tables")
        return tuple(read_cloth(file, i, c, scene_path.parent) for i, c in enumerate(value))

    @accepts(ARRAY)
    def colliders(value: Any, key: str) -> tuple:
        if not isinstance(value, list):
            raise _Invalid(f"expected [[collider]] tables, got {_describe(value)}")
        return tuple(read_collider(_Table(file, f"collider[{i}]", c, scene_path.parent), i) for i, c in enumerate(value))

    cloth_specs = top.take("cloth", cloths)
    collider_specs = top.take("collider", colliders, ())
    top.finish()
    scene = Scene(source=file, simulation=simulation, output=output, cloths=cloth_specs, colliders=collider_specs)
    check_scene(scene)
    return scene


def check_scene(scene: Scene) -> None:
    """The checks across sections (solver against cloths, names, float32 range), one SceneError for the first
    problem: run by parse_scene, and again on a scene edited in code (a live session's new tear threshold)."""
    file, simulation, output = scene.source, scene.simulation, scene.output
    cloth_specs, collider_specs = scene.cloths, scene.colliders
    if simulation.relaxation == "jacobi":
        for i, spec in enumerate(cloth_specs):
            if spec.compliance:
                raise SceneError(file, f"cloth[{i}].compliance", 'soft sticks need the coloured solver (XPBD '
                                 'accumulates each stick\'s tension in order); remove compliance or set '
                                 'simulation.relaxation = "coloured"')
            if spec.tear_tension is not None:
                raise SceneError(file, f"cloth[{i}].tear_tension", "tearing by tension needs the coloured solver "
                                 "(each stick's tension is what its own projections add up to, and a Jacobi "
                                 "particle averages its sticks' moves); remove tear_tension or set "
                                 'simulation.relaxation = "coloured"')
    if simulation.multilevel and simulation.global_iterations:
        raise SceneError(file, "simulation.multilevel", "the multilevel pass and the global correction "
                         "(global_iterations) each carry a correction across the whole grid, and together they fed "
                         "each other until an unpinned cloth at rest diverged: set multilevel = false or "
                         "global_iterations = 0")
    if simulation.multilevel:
        for i, spec in enumerate(cloth_specs):
            if spec.mesh is not None:
                raise SceneError(file, "simulation.multilevel", f"cloth[{i}] ({spec.name!r}) is a mesh, and the "
                                 "multilevel hierarchy is built for grids: set multilevel = false")
            if spec.tears:
                raise SceneError(file, "simulation.multilevel", f"cloth[{i}] ({spec.name!r}) can tear, and the "
                                 "coarse levels would hold a torn piece on: set multilevel = false or remove "
                                 "its tear_threshold and tear_tension")
            if spec.compliance.get("structural", 0.0) > 0.0:
                raise SceneError(file, "simulation.multilevel", f"cloth[{i}] ({spec.name!r}) has soft structural "
                                 "sticks, and the coarse levels limit stretch to the rest pose: set "
                                 "multilevel = false or make its structural sticks rigid")
    if output.kind == "override":
        _check_override(file, cloth_specs)
    for section, items in (("cloth", cloth_specs), ("collider", collider_specs)):
        names = [c.name for c in items]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise SceneError(file, f"{section}[{i}].name", f"expected a unique name, but {n!r} is used twice")
    _check_prim_names(file, cloth_specs, collider_specs)
    _check_float32(file, simulation, cloth_specs, collider_specs)


def _check_override(file: str, cloths: tuple[ClothSpec, ...]) -> None:
    """An override layer overrides USD prims: every cloth must come from a prim, all of one USD file."""
    assets = set()
    for i, spec in enumerate(cloths):
        source = spec.mesh.mesh.source if spec.mesh is not None else None
        if source is None or source.prim_path is None:
            raise SceneError(file, "output.kind", f"an override layer overrides the USD prims the cloths came from, "
                             f"and cloth[{i}] ({spec.name!r}) is not from a USD prim: write kind = \"cache\"")
        assets.add(source.file.resolve())
    if len(assets) > 1:
        raise SceneError(file, "output.kind", f"an override layer goes over one asset, and the cloths come from "
                         f"{len(assets)} files ({', '.join(sorted(map(str, assets)))}): write kind = \"cache\"")


# The most bytes a scene or sweep file may hold. The largest shipped scene is a few kB; a scene that lists
# particle masses or pins one by one stays far below this. Reading stops here, so a file that never ends
# (/dev/zero, a pipe) or a huge one costs this much memory at most, not all the machine has.
MAX_TOML_BYTES = 16 * 2**20
UTF8_BOM = b"\xef\xbb\xbf"


def read_toml_file(path: str | Path, what: str = "scene file") -> dict:
    """The TOML document in ``path`` (a scene or sweep file, ``what`` in messages), read up to
    :data:`MAX_TOML_BYTES`. Raises :class:`SceneError` naming the file on any problem: unreadable, too large,
    not UTF-8 (a byte order mark is named as such), not TOML."""
    path = Path(path)
    file = str(path)
    cap = MAX_TOML_BYTES
    try:
        with open(path, "rb") as f:
            raw = f.read(cap + 1)  # one byte more than allowed tells "too large" from "just fits"
            if len(raw) > cap:
                size = os.fstat(f.fileno()).st_size  # 0 for a device or a pipe: its size is unknown
                known = f"{size:,} bytes" if size > cap else f"more than {cap:,} bytes"
                most = f"{cap:,} bytes" + (f" ({cap // 2**20} MiB)" if cap % 2**20 == 0 else "")
                raise SceneError(file, None, f"the file is too large for a {what}: {known}, and a {what} may hold "
                                 f"at most {most}")
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL character
        raise SceneError(file, None, f"cannot read the file ({getattr(exc, 'strerror', None) or exc})") from None
    if raw.startswith(UTF8_BOM):
        raise SceneError(file, None, "the file starts with a UTF-8 byte order mark (BOM, bytes EF BB BF), which "
                         "TOML does not allow: save it as UTF-8 without a BOM")
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneError(file, None, f"expected UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(file, None, f"not valid TOML: {exc}") from None
    except ValueError as exc:  # tomllib lets int()'s digit limit through (an integer of > 4300 digits)
        raise SceneError(file, None, f"not valid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays / inline tables
        raise SceneError(file, None, "not valid TOML: arrays or inline tables nested too deeply") from None


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file. Raises :class:`SceneError` on any problem."""
    path = Path(path)
    return parse_scene(read_toml_file(path), str(path), path)


# ------------------------------------------------------------------------------------------------------------
# Checks across keys: prim names in the cache, and numbers as the device will hold them (float32).

RESERVED_PRIM_NAMES = ("Colliders",)  # /World/Colliders holds the colliders (usd_writer.COLLIDERS_PATH)


def _check_prim_names(file: str, cloths: tuple, colliders: tuple) -> None:
    """Every prim of the cache gets its own name: a cloth may not take a reserved name or a collider's."""
    collider_names = {c.name: j for j, c in enumerate(colliders)}
    for i, cloth in enumerate(cloths):
        if cloth.name in RESERVED_PRIM_NAMES:
            raise SceneError(file, f"cloth[{i}].name", f"{cloth.name!r} is reserved: the cache keeps the colliders "
                             f"under /World/{cloth.name}; give the cloth another name")
        if cloth.name in collider_names:
            raise SceneError(file, f"cloth[{i}].name", f"expected a name different from every collider's, but "
                             f"collider[{collider_names[cloth.name]}] is also named {cloth.name!r}")


def _check_float32(file: str, simulation: SimulationSettings, cloths: tuple, colliders: tuple) -> None:
    """Refuse numbers that are valid as TOML floats (float64) but not as the float32 the device computes with:
    past about 3.4e38 they become inf, and an inverse mass below about 1.2e-38 becomes 0 (the particle would
    never move) or, for a tiny mass, inf. Each error names the key, as the reader's own checks do."""
    limit = f"float32 holds magnitudes up to {FLOAT32_MAX:.3g}"

    def fits(key: str, values) -> None:
        for k, v in enumerate(values):
            if not float32_fits(v):
                where = key if len(values) == 1 else f"{key}[{k}]"
                raise SceneError(file, where, f"expected a number that float32 can hold ({limit}), got {v:g}")

    fits("simulation.gravity", simulation.gravity)
    fits("simulation.wind", simulation.wind)
    for k, (g, w) in enumerate(zip(simulation.gravity, simulation.wind)):
        if not float32_fits(g + w):  # one acceleration on the device
            larger = "gravity" if abs(g) >= abs(w) else "wind"
            raise SceneError(file, f"simulation.{larger}[{k}]", f"gravity + wind = {g + w:g} m/s^2, which float32 "
                             f"cannot hold ({limit})")
    air = simulation.air
    if air is not None:
        for k, (time, velocity) in enumerate(air.velocity):
            where = f"simulation.air.velocity[{k}]" if len(air.velocity) > 1 else "simulation.air.velocity"
            fits(where, (time, *velocity) if len(air.velocity) > 1 else velocity)
        for name in ("density", "gust_speed", "gust_length", "gust_period"):
            fits(f"simulation.air.{name}", [getattr(air, name)])
    dt = 1.0 / (simulation.fps * simulation.substeps)
    if not FLOAT32_TINY <= dt <= FLOAT32_MAX:
        raise SceneError(file, "simulation.fps", f"the step 1 / (fps x substeps) = {dt:g} s is beyond what float32 "
                         f"can hold (a normal float32 lies in [{FLOAT32_TINY:.3g}, {FLOAT32_MAX:.3g}])")
    for i, c in enumerate(cloths):
        key = f"cloth[{i}]"
        fits(f"{key}.origin", c.origin)
        if c.size is not None and c.resolution is not None:  # a grid (a mesh's positions are checked at run time)
            fits(f"{key}.size", c.size)
            far = max(abs(v) for v in c.origin)
            reach = far + max(c.size)  # the far corner, whichever way the cloth lies
            if not float32_fits(reach):
                where = (f"{key}.origin[{[abs(v) for v in c.origin].index(far)}]" if far >= max(c.size)
                         else f"{key}.size[{list(c.size).index(max(c.size))}]")
                raise SceneError(file, where, f"the cloth reaches {reach:g} m from the world's origin, beyond what "
                                 f"float32 can hold ({limit})")
            for axis, (n, length) in enumerate(zip(c.resolution, c.size)):
                if n > 1 and length / (n - 1) < FLOAT32_TINY:
                    raise SceneError(file, f"{key}.size[{axis}]", f"expected a spacing float32 can hold: {length:g} "
                                     f"m over {n - 1} gaps is below {FLOAT32_TINY:.3g} m")
        n = c.particle_count
        lo, hi = n / FLOAT32_MAX, n / FLOAT32_TINY  # each particle's inverse mass, n / mass, a normal float32
        if not lo <= c.mass <= hi:
            what = "rounds to 0, and the cloth would never move" if c.mass > hi else "overflows to inf"
            raise SceneError(file, f"{key}.mass", f"expected a number in [{lo:.3g}, {hi:.3g}] kg for {n} particles, "
                             f"got {c.mass:g}: each particle's inverse mass in float32 ({n} / mass) {what}")
        for j, (_, _, kg) in enumerate(c.particle_masses):
            if not 1 / FLOAT32_MAX <= kg <= 1 / FLOAT32_TINY:
                raise SceneError(file, f"{key}.particle_masses[{j}][2]", f"expected a number in "
                                 f"[{1 / FLOAT32_MAX:.3g}, {1 / FLOAT32_TINY:.3g}] kg, got {kg:g}: its inverse "
                                 "must be a normal float32")
        for family, alpha in c.compliance.items():
            fits(f"{key}.compliance.{family}", [alpha])
        fits(f"{key}.drag_coefficient", [c.drag_coefficient])
        fits(f"{key}.lift_coefficient", [c.lift_coefficient])
    for j, c in enumerate(colliders):
        key = f"collider[{j}]"
        fits(f"{key}.thickness", [c.thickness])
        kind_of(c).check_numbers(c, file, key)
