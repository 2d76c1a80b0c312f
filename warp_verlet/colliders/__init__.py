"""Collider kinds: each kind (a sphere, a plane) is one module that describes itself, and the registry.

A scene's ``[[collider]]`` tables are read, built on the device, clamped against, estimated, warned about and
written to the cache by asking each collider's kind, never by branching on sphere or plane. A new kind is
one module here (its :class:`ColliderKind`), one kernel file in ``kernels/``, and one entry in
:data:`COLLIDER_KINDS`.

Nothing here imports warp at module level: the scene loader reads colliders through this package, and
``warp-verlet validate`` stays light. A kind imports warp (and its kernels) inside the members that build or
bind device work.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Protocol, runtime_checkable

from ..scene_keys import STRING, Key, accepts, choice, prim_name, real

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from ..model import Model
    from ..scene_keys import Table
    from ..stages import PhaseTask
    from ..state import State

COLLIDER_PURPOSES = ("guide", "default")  # USD purpose: a helper hidden in renders, or rendered geometry
VEC3, FLOAT, INT, FLOAT64 = 12, 4, 4, 8  # device bytes, for the kinds' device_bytes (as stages.py counts them)


@dataclass(frozen=True)
class ColliderLaunches:
    """A kind's part of the Collide stage against one State: ``before`` runs first each substep (with dt), for
    every kind in registry order (a moving collider is placed here); then ``clamps``, the recorded launches that
    project particles out, again in registry order."""

    before: tuple[Callable[[float], None], ...] = ()
    clamps: tuple["PhaseTask", ...] = ()


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
      ``friction`` and ``purpose`` (the shared keys, :data:`SHARED_KEYS`).
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
    - ``bind(model, state)``: its :class:`ColliderLaunches` against one State.

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
      primitives, name -> item: ``"spheres"`` (centre, radius) or ``"planes"`` ((4, 3) corners, which the
      drawing clips to the content); the preview (preview_render.py) and the viewer (cache_player.py) draw
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

    def state_arrays(self, colliders: "ColliderModel") -> dict[str, Any]: ...

    def bind(self, model: "Model", state: "State") -> ColliderLaunches: ...

    def cached(self, spec: Any, always_moving: bool = False) -> Any: ...

    def samples(self, colliders: "ColliderModel", state: "State", always_moving: bool = False) -> "np.ndarray": ...

    def owns_prim(self, prim: Any, under_colliders: bool) -> bool: ...

    def read_prim(self, prim: Any, reader: FrameReader) -> dict[str, Any]: ...

    def add_to_live(self, app: Any, specs: tuple) -> LiveDrawing: ...


@accepts(STRING)
def _collider_type(value: Any, key: str) -> str:
    """One of the registered kinds' ``type`` strings, read from the registry when the key is read (so that a
    kind registered later is accepted)."""
    return choice(tuple(sorted(k.type for k in kinds())))(value, key)


# The keys every kind shares, declared once (SHARED_KEYS, below the registry); the kinds' own keys follow them
# in each table.
THICKNESS = Key("thickness", real(0.0), 0.0, type="number", unit="m", allowed="≥ 0",
                doc="The cloth is kept this far outside the surface, so that it never touches the render-visible "
                    "collider. At `0` the cloth rests on the visible surface and z-fights with it in renders: "
                    "`validate` and `run` warn and suggest half the finest cloth's particle spacing (a grid's "
                    "`size / (n - 1)`, a mesh's median edge).")
FRICTION = Key("friction", real(0.0, 1.0), 0.0, type="number", allowed="0 … 1",
               doc="Fraction of the tangential implicit velocity (x − x_prev) removed each substep a particle is "
                   "in contact. 0 = frictionless, 1 = sticks.")
PURPOSE = Key("purpose", choice(COLLIDER_PURPOSES), "guide", type="string", allowed='`"guide"`, `"default"`',
              doc="The USD `purpose` of its prim in a cache. `\"guide\"`: a helper, left out of renders (Blender, "
                  "Karma) and hidden in usdview until guides are shown (Display > Display Purposes > Guide); the "
                  "default, since a collider stands in for the user's own geometry. `\"default\"`: rendered with "
                  "the cloth.")


def kinds() -> tuple[ColliderKind, ...]:
    """The registered kinds, in clamp order (read at each call, so that a kind registered later counts)."""
    return COLLIDER_KINDS


def kind_named(type_name: str) -> ColliderKind:
    """The registered kind whose ``type`` string is ``type_name``."""
    for kind in kinds():
        if kind.type == type_name:
            return kind
    raise KeyError(f"no collider kind {type_name!r} is registered")


def kind_of(spec: Any) -> ColliderKind:
    """The registered kind of one collider spec."""
    for kind in kinds():
        if isinstance(spec, kind.spec):
            return kind
    raise TypeError(f"{type(spec).__name__} is not the spec of a registered collider kind")


def specs_of(colliders: tuple, kind: ColliderKind) -> tuple:
    """The colliders of ``kind`` among ``colliders``, in scene order."""
    return tuple(c for c in colliders if isinstance(c, kind.spec))


def by_kind(colliders: tuple) -> list[tuple[ColliderKind, tuple]]:
    """(kind, its specs) for every registered kind that ``colliders`` has, in clamp order."""
    return [(kind, specs) for kind in kinds() if (specs := specs_of(colliders, kind))]


def read_collider(table: "Table", index: int) -> Any:
    """One ``[[collider]]`` table: the shared keys, then the kind's own, then no unknown key."""
    kind = kind_named(TYPE.take(table))
    shared = {key.name: key.take(table) for key in SHARED_KEYS[1:]}
    if shared["name"] is None:
        shared["name"] = f"{kind.type}{index}"
    spec = kind.read(table, shared)
    table.finish()
    return spec


def counts(colliders: tuple) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """(type, the kind's counts) for every kind the colliders have, in clamp order: ``Requirements.colliders``."""
    return tuple((kind.type, tuple(kind.counts(specs))) for kind, specs in by_kind(colliders))


def device_bytes(collider_counts: tuple[tuple[str, tuple[int, ...]], ...]) -> int:
    """The device bytes of every kind in ``collider_counts`` (as :func:`counts` gives them)."""
    return sum(kind_named(name).device_bytes(c) for name, c in collider_counts)


class ColliderModel:
    """The scene's colliders on one device: each kind's fixed data (``build``), as attributes of this object
    (flat, so that the memory check, bench.common.device_arrays, finds every array as it did).

    Only the kinds a scene has get arrays and launches: no planes, no ``collide_planes``; no moving sphere, no
    clock and no ``place_spheres``. What moves lives in the :class:`~warp_verlet.state.State` (each kind's
    ``state_arrays``); this object holds what does not.
    """

    def __init__(self, scene, device):
        import warp as wp

        self.specs = scene.colliders
        self.kinds = by_kind(scene.colliders)  # (kind, its specs) in clamp order
        with wp.ScopedDevice(device):
            for kind, specs in self.kinds:
                for name, value in kind.build(specs, device).items():
                    if name in vars(self):
                        raise AssertionError(f"collider kind {kind.type!r} builds {name!r}, which is taken")
                    setattr(self, name, value)

    def moving_centres(self, state, always_moving: bool = False) -> "np.ndarray":
        """Per-frame samples of every moving collider (every collider that can move, when ``always_moving``: a
        live session's, where spheres are dragged), in clamp order then scene order: what the cache
        time-samples. Costs no device copy when nothing moves."""
        import numpy as np

        parts = [kind.samples(self, state, always_moving) for kind, _ in self.kinds]
        parts = [p for p in parts if len(p)]
        return np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)


from .plane import PLANE  # noqa: E402 (the kinds import the records above)
from .sphere import SPHERE  # noqa: E402

COLLIDER_KINDS: tuple[ColliderKind, ...] = (SPHERE, PLANE)
"""The registered kinds, in clamp order: spheres before planes, so that a sphere resting on the ground cannot
push cloth through the ground (the plane's clamp comes last and wins)."""

# The type's choices and the name's default are the registry's, in the docs' (alphabetical) order.
TYPE = Key("type", _collider_type, type="string", allowed=", ".join(sorted(f'`"{k.type}"`' for k in COLLIDER_KINDS)),
           doc="The kind of collider.")
NAME = Key("name", prim_name, default=None, type="string",
           default_text=" / ".join(sorted(f'`"{k.type}<i>"`' for k in COLLIDER_KINDS)),
           allowed="letters, digits, `_`; not starting with a digit; unique among colliders",
           doc="Its prim name in the cache: `/World/Colliders/<name>`.")
SHARED_KEYS = (TYPE, NAME, THICKNESS, FRICTION, PURPOSE)
