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

from typing import Any

from ..errors import ArgumentError
from ..scene_keys import STRING, Key, accepts, choice, prim_name
from .kind import (COLLIDER_PURPOSES, FLOAT, FLOAT64, FRICTION_COEFFICIENT, INT, PURPOSE,  # noqa: F401
                   STATIC_FRICTION_COEFFICIENT, THICKNESS, VEC3, coulomb,
                   ColliderKind, ColliderLaunches, FrameReader, InsideReport, LiveDrawing)  # the kinds' names, here too
from .mesh import MESH
from .plane import PLANE
from .sphere import SPHERE

@accepts(STRING)
def _collider_type(value: Any, key: str) -> str:
    """One of the registered kinds' ``type`` strings, read from the registry when the key is read (so that a
    kind registered later is accepted)."""
    return choice(tuple(sorted(k.type for k in kinds())))(value, key)


def kinds() -> tuple[ColliderKind, ...]:
    """The registered kinds, in clamp order (read at each call, so that a kind registered later counts)."""
    return COLLIDER_KINDS


def kind_named(type_name: str) -> ColliderKind:
    """The registered kind whose ``type`` string is ``type_name``."""
    for kind in kinds():
        if kind.type == type_name:
            return kind
    raise ArgumentError(f"no collider kind {type_name!r} is registered")


def kind_of(spec: Any) -> ColliderKind:
    """The registered kind of one collider spec."""
    for kind in kinds():
        if isinstance(spec, kind.spec):
            return kind
    raise ArgumentError(f"{type(spec).__name__} is not the spec of a registered collider kind")


def specs_of(colliders: tuple, kind: ColliderKind) -> tuple:
    """The colliders of ``kind`` among ``colliders``, in scene order."""
    return tuple(c for c in colliders if isinstance(c, kind.spec))


def by_kind(colliders: tuple) -> list[tuple[ColliderKind, tuple]]:
    """(kind, its specs) for every registered kind that ``colliders`` has, in clamp order."""
    return [(kind, specs) for kind in kinds() if (specs := specs_of(colliders, kind))]


def read_collider(table, index: int) -> Any:
    """One ``[[collider]]`` table: the shared keys, then the kind's own, then no unknown key."""
    kind = kind_named(TYPE.take(table))
    if "friction" in table.data:
        raise table.error("friction", FRICTION_REPLACED)
    shared = {key.name: key.take(table) for key in SHARED_KEYS[1:]}
    kinetic, static = shared["friction_coefficient"], shared["static_friction_coefficient"]
    if static is not None and static < kinetic:
        raise table.error("static_friction_coefficient", f"must be at least friction_coefficient ({kinetic:g}): a "
                          f"particle that slides is held at most as hard as one at rest; got {static:g}")
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
    clock and no ``place_spheres``. What moves lives in the :class:`~warp_verlet.core.state.State` (each kind's
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

    def moving_centres(self, state, always_moving: bool = False):
        """Per-frame samples of every moving collider (every collider that can move, when ``always_moving``: a
        live session's, where spheres are dragged), in clamp order then scene order: what the cache
        time-samples. Costs no device copy when nothing moves."""
        import numpy as np

        parts = [kind.samples(self, state, always_moving) for kind, _ in self.kinds]
        parts = [p for p in parts if len(p)]
        return np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)


COLLIDER_KINDS: tuple[ColliderKind, ...] = (SPHERE, MESH, PLANE)
"""The registered kinds, in clamp order: spheres and meshes before planes, so that a sphere or a mesh resting on
the ground cannot push cloth through the ground (the plane's clamp comes last and wins)."""

# The type's choices and the name's default are the registry's, in the docs' (alphabetical) order.
TYPE = Key("type", _collider_type, type="string", allowed=", ".join(sorted(f'`"{k.type}"`' for k in COLLIDER_KINDS)),
           doc="The kind of collider.")
NAME = Key("name", prim_name, default=None, type="string",
           default_text=" / ".join(sorted(f'`"{k.type}<i>"`' for k in COLLIDER_KINDS)),
           allowed="letters, digits, `_`; not starting with a digit; unique among colliders",
           doc="Its prim name in the cache: `/World/Colliders/<name>`.")
SHARED_KEYS = (TYPE, NAME, THICKNESS, FRICTION_COEFFICIENT, STATIC_FRICTION_COEFFICIENT, PURPOSE)

FRICTION_REPLACED = (
    "was the fraction of the tangential velocity removed per substep, so the same scene slid differently at other "
    "substeps; it is replaced by Coulomb friction, which does not depend on them: write friction_coefficient = "
    "mu_k (sliding cloth on the surface decelerates at mu_k g; about 0.3 to 0.6 for cloth on wood or fabric) and, "
    "if it holds harder at rest, static_friction_coefficient = mu_s (cloth rests on a slope while tan(slope) < mu_s)")
