"""What one collider kind declares about itself (:class:`ColliderKind`), the records its members return, and
the keys every kind shares. The kinds (sphere.py, plane.py) import this module; the registry
(``warp_verlet.colliders``) imports the kinds.

Nothing here imports warp at module level: the scene loader reads colliders through this package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Protocol, runtime_checkable

from ..scene_keys import Key, choice, real

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from ..launches import PhaseTask
    from ..scene_keys import Table

COLLIDER_PURPOSES = ("guide", "default")  # USD purpose: a helper hidden in renders, or rendered geometry
VEC3, FLOAT, INT, FLOAT64 = 12, 4, 4, 8  # device bytes, for the kinds' device_bytes (as stages.py counts them)


@dataclass(frozen=True)
class ColliderLaunches:
    """A kind's part of the Collide stage against one State: ``before`` runs first each substep (with dt), for
    every kind in registry order (a moving collider is placed here); then ``clamps``, the recorded launches that
    project particles out, again in registry order. ``clamp_pieces`` makes each clamp's launch over particles
    ``first .. first + count - 1`` (``(first, count) -> PhaseTask``), so that the CPU's relaxation threads can
    clamp a run of particles each: a particle's clamp reads and writes that particle alone. A kind that gives none
    has its ``clamps`` run whole, by one thread."""

    before: tuple[Callable[[float], None], ...] = ()
    clamps: tuple["PhaseTask", ...] = ()
    clamp_pieces: tuple[Callable[[int, int], "PhaseTask"], ...] = ()


def clamp_launches(make: Callable[[int, int], "PhaseTask"], particles: int,
                   before: tuple[Callable[[float], None], ...] = ()) -> ColliderLaunches:
    """A kind's ColliderLaunches for one clamp kernel over every particle, from its maker (first, count)."""
    return ColliderLaunches(before, (make(0, particles),), (make,))


@dataclass(frozen=True)
class InsideReport:
    """Which particles start inside a collider (``inside``: one bool per particle), where that is in words
    (completing "cloth 'c' starts with n of m particles ..."), and what to change."""

    inside: "np.ndarray"
    where: str
    fix: str


@dataclass
class LiveDrawing:
    """What a kind drew on the live page (live_app.py): its items (viser handles), the points the camera
    frames, and the per-frame update (None for colliders that never move)."""

    items: list
    points: list = field(default_factory=list)
    update: Callable[[], None] | None = None


class FrameReader(Protocol):
    """What cache_reader.py lends a kind reading its prim at one time code: ``time``; ``attribute(prim, name,
    get)``, the value of ``get()`` (a damaged one is one clear error naming the file, the frame and
    ``prim.name``); ``finite(prim, values)`` (float64, refusing NaN and inf); ``to_world(prim, points)``."""

    time: Any

    def attribute(self, prim: Any, name: str, get: Callable[[], Any]) -> Any: ...

    def finite(self, prim: Any, values: Any) -> "np.ndarray": ...

    def to_world(self, prim: Any, points: "np.ndarray") -> "np.ndarray": ...


@runtime_checkable
class ColliderKind(Protocol):
    """One kind of collider. Every member is looked up on the kind by the consumers; none of them knows which
    kinds exist.

    Scene input (no warp):

    - ``type``: the ``type`` string of its ``[[collider]]`` tables (``"sphere"``).
    - ``spec``: the frozen dataclass of one collider of this kind; it has at least ``name``, ``thickness``,
      ``friction_coefficient``, ``static_friction_coefficient`` (None: the same as ``friction_coefficient``) and
      ``purpose`` (the shared keys, :data:`SHARED_KEYS`); :func:`coulomb` reads the two coefficients.
    - ``keys``: its own scene keys (:class:`~warp_verlet.scene_keys.Key`), after the shared ones: the loader
      takes them and the docs tables are written from them.
    - ``read(table, shared)``: the spec from its table; ``shared`` holds the shared keys' values by name. It
      takes its own keys from ``table`` (and refuses bad combinations with ``table.error``); the caller checks
      for unknown keys afterwards.
    - ``check_numbers(spec, file, key)``: refuse (SceneError naming ``key`` and below) numbers that are valid
      TOML floats but not float32 on the device.
    - ``start_inside(spec, points)``: an :class:`InsideReport` of the rest positions ``points`` (N, 3) that the
      clamp would move on the first substep (scene_warnings.py; numpy only).

    Simulation core (counts known before anything is built, then device work):

    - ``counts(specs)``: the kind's sizes for the memory estimate, a tuple of ints, from its specs alone (all
      of them, in scene order); part of ``stages.Requirements.colliders``.
    - ``device_bytes(counts)``: the bytes of every device array the kind allocates (Model and State), from
      its counts: ``memory.estimate`` sums them and tests/test_memory.py checks them against the allocations.
    - ``build(specs, device)``: its fixed device data, as attributes of the Model's :class:`ColliderModel`
      (names start with the kind's own prefix: they share one namespace).
    - ``state_arrays(colliders)``: what moves, created where the State is built: name -> array, or None where
      this scene needs none; every name the kind ever creates, always (the State keeps them as attributes).
    - ``bind(model, state, pushes=None)``: its :class:`ColliderLaunches` against one State; where ``pushes`` (a
      vec3 per particle) is given, its clamps add to it each push out they give a particle (normal x depth), from
      which launches.clamp_noting_normals takes the contact normals where friction tilts the particles' moves.
    - ``capturable(specs, device)``, optional: False when its launches do not replay from a frame capture (a
      deforming mesh's BVH refit is host work Warp's CPU capture does not record); the simulator then steps
      such a scene launch by launch. A kind without it is capturable.

    Output (cache, preview, viewer, live page; pxr and viser imported inside, where they are used):

    - ``cached(spec, always_moving)``: what the cache writer needs of one collider: a frozen record with
      ``name``, ``purpose``, ``moving`` and ``define(stage, path)``, which defines its prim under
      /World/Colliders and returns the attribute op to time-sample per frame, or None for a still prim
      (usd_writer.py; ``always_moving``: a live session, where colliders are dragged).
    - ``samples(colliders, state, always_moving)``: the per-frame samples of this kind's moving colliders
      (of all of them when ``always_moving``, as ``cached``), (M, 3), in scene order: what ``define``'s ops are
      set to each frame (runner.py and a live session's recording, through ``ColliderModel.moving_centres``).
    - ``owns_prim(prim, under_colliders)``: whether a cache prim is one of this kind (cache_reader.py asks each
      kind in registry order and the first that owns the prim reads it; ``under_colliders``: the prim lies
      under /World/Colliders). The plane owns every mesh there, so a kind that writes a mesh comes before it
      (its clamp then runs before the plane's too, as the ground's should run last).
    - ``read_prim(prim, reader)``: its geometry at ``reader.time`` (a :class:`FrameReader`) as drawing
      primitives, name -> item: ``"spheres"`` (centre, radius), ``"planes"`` ((4, 3) corners, which the
      drawing clips to the content) or ``"meshes"`` ((V, 3) points, (T, 3) triangles); the preview (preview_render.py) and the viewer (cache_player.py) draw
      those primitives.
    - ``add_to_live(app, specs)``: draw this kind's colliders on the live page (live_app.py): a
      :class:`LiveDrawing`.
    """

    type: str
    spec: type
    keys: tuple[Key, ...]

    def read(self, table: "Table", shared: dict[str, Any]) -> Any: ...

    def check_numbers(self, spec: Any, file: str, key: str) -> None: ...

    def start_inside(self, spec: Any, points: "np.ndarray") -> InsideReport: ...

    def counts(self, specs: tuple) -> tuple[int, ...]: ...

    def device_bytes(self, counts: tuple[int, ...]) -> int: ...

    def build(self, specs: tuple, device) -> dict[str, Any]: ...

    def state_arrays(self, colliders: Any) -> dict[str, Any]: ...

    def bind(self, model: Any, state: Any, pushes: Any = None) -> ColliderLaunches: ...

    def cached(self, spec: Any, always_moving: bool = False) -> Any: ...

    def samples(self, colliders: Any, state: Any, always_moving: bool = False) -> "np.ndarray": ...

    def owns_prim(self, prim: Any, under_colliders: bool) -> bool: ...

    def read_prim(self, prim: Any, reader: FrameReader) -> dict[str, Any]: ...

    def add_to_live(self, app: Any, specs: tuple) -> LiveDrawing: ...


# The keys every kind shares, declared once (SHARED_KEYS, below the registry); the kinds' own keys follow them
# in each table.
THICKNESS = Key("thickness", real(0.0), 0.0, type="number", unit="m", allowed="≥ 0",
                doc="The cloth is kept this far outside the surface, so that it never touches the render-visible "
                    "collider. At `0` the cloth rests on the visible surface and z-fights with it in renders: "
                    "`validate` and `run` warn and suggest half the finest cloth's particle spacing (a grid's "
                    "`size / (n - 1)`, a mesh's median edge).")
FRICTION_COEFFICIENT = Key(
    "friction_coefficient", real(0.0), 0.0, type="number", allowed="≥ 0",
    doc="Coulomb's kinetic friction coefficient μ_k: a sliding particle's move along the surface in a substep is "
        "shortened by μ_k times the distance the surface pushed it out, so on an incline it slides down at "
        "g (sin θ − μ_k cos θ) and on level ground it stops from v after v² / (2 μ_k g), whatever the substeps. "
        "`0` = frictionless; cloth on wood or fabric is about 0.3 … 0.6.")
STATIC_FRICTION_COEFFICIENT = Key(
    "static_friction_coefficient", real(0.0), None, type="number", default_text="`friction_coefficient`",
    allowed="≥ 0; at least `friction_coefficient`",
    doc="Coulomb's static friction coefficient μ_s: a particle whose move along the surface in a substep is under "
        "μ_s times the distance the surface pushed it out stays where it was, so cloth rests on an incline while "
        "tan θ < μ_s.")
PURPOSE = Key("purpose", choice(COLLIDER_PURPOSES), "guide", type="string", allowed='`"guide"`, `"default"`',
              doc="The USD `purpose` of its prim in a cache. `\"guide\"`: a helper, left out of renders (Blender, "
                  "Karma) and hidden in usdview until guides are shown (Display > Display Purposes > Guide); the "
                  "default, since a collider stands in for the user's own geometry. `\"default\"`: rendered with "
                  "the cloth.")


def push_record(pushes: Any, device: Any) -> Any:
    """The clamp kernels' ``pushes`` argument: the array a stage gave, or an empty one (not written)."""
    import warp as wp

    return pushes if pushes is not None else wp.empty(0, dtype=wp.vec3, device=device)


def has_friction(specs: Any) -> bool:
    """Whether any of the collider specs ``specs`` has friction (its static coefficient, the larger, above 0)."""
    return any(coulomb(spec)[1] > 0.0 for spec in specs)


def coulomb(spec: Any) -> tuple[float, float]:
    """A collider's Coulomb coefficients (mu_k, mu_s), as the clamp kernels take them (a ``wp.vec2`` each); an
    unset mu_s is mu_k."""
    kinetic = spec.friction_coefficient
    static = spec.static_friction_coefficient
    return kinetic, kinetic if static is None else static


def keyframe_arrays(specs) -> tuple:
    """Every collider's keyframes in one table on the current device, as the place_* kernels read them: (each
    collider's first key, (K + 1,) int; the times, s, float; the values, vec3), in ``specs`` order. A still collider
    (one value, however many keyframes) keeps one key, which its place kernel leaves be."""
    import numpy as np
    import warp as wp

    keys = [s.keyframes if s.moving else s.keyframes[:1] for s in specs]
    start = np.r_[0, np.cumsum([len(k) for k in keys])].astype(np.int32)
    return (wp.array(start, dtype=int), wp.array([t for k in keys for t, _ in k], dtype=float),
            wp.array([v for k in keys for _, v in k], dtype=wp.vec3))
