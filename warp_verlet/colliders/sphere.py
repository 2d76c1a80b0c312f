"""Sphere colliders: still, or moving along keyframes (kernels/collide_sphere.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..scene_keys import ARRAY, Invalid, Key, accepts, any_real, describe, per_element, real, vector
from .kind import (FLOAT, FLOAT64, INT, VEC3, ColliderLaunches, InsideReport, LiveDrawing, clamp_launches, coulomb,
                   keyframe_arrays, push_record)


@dataclass(frozen=True)
class SphereCollider:
    """A sphere whose centre follows ``keyframes`` ((time s, (x, y, z)), ...) linearly, held at the ends."""

    name: str
    radius: float
    keyframes: tuple[tuple[float, tuple[float, float, float]], ...]
    thickness: float = 0.0
    friction_coefficient: float = 0.0  # Coulomb's mu_k
    static_friction_coefficient: float | None = None  # mu_s; None: mu_k
    purpose: str = "guide"  # USD purpose of its prim in a cache

    @property
    def moving(self) -> bool:
        return len({c for _, c in self.keyframes}) > 1

    def centre_at(self, time: float) -> tuple[float, float, float]:
        times = [t for t, _ in self.keyframes]
        return tuple(float(v) for v in _lerp_keys(times, [c for _, c in self.keyframes], time))


def _lerp_keys(times: list[float], values: list[tuple], time: float):
    import numpy as np  # host-side only: USD authoring and tests

    values = np.asarray(values, dtype=np.float64)
    return np.array([np.interp(time, times, values[:, k]) for k in range(values.shape[1])])


@accepts(ARRAY)
def read_path(value: Any, key: str) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """Keyframes [[t, x, y, z], ...], at least one, times strictly increasing."""
    if not isinstance(value, list) or not value:
        raise Invalid(f"expected an array of [time, x, y, z] keyframes, got {describe(value)}")
    keys = []
    for i, item in enumerate(value):
        t, x, y, z = per_element(vector(4, per_element(real())))(item, f"{key}[{i}]")
        if keys and t <= keys[-1][0]:
            raise Invalid(f"keyframe times must increase, got {t} s after {keys[-1][0]} s", f"{key}[{i}][0]")
        keys.append((t, (x, y, z)))
    return tuple(keys)


RADIUS = Key("radius", real(0.0, lo_open=True), type="number", unit="m", allowed="> 0",
             doc="The visible radius; particles are kept at `radius + thickness` from the centre.")
CENTRE = Key("centre", vector(3, any_real), (0.0, 0.0, 0.0), type="[x, y, z] numbers", unit="m", allowed="finite",
             doc="Centre of a still sphere. Not together with `path`.")
PATH = Key("path", read_path, None, type="array of [t, x, y, z]", unit="s, m", default_text="–",
           allowed="at least one keyframe, times strictly increasing",
           doc="Centre of a moving sphere: linear between keyframes, held at the first before it and at the last "
               "after it. The cache gets a time-sampled `xformOp:translate`.")


class SphereKind:
    """Spheres: clamped before planes; a moving one is placed on the device clock first."""

    type = "sphere"
    spec = SphereCollider
    keys = (RADIUS, CENTRE, PATH)

    # ------------------------------------------------------------------ scene input
    def read(self, table, shared: dict[str, Any]) -> SphereCollider:
        radius = RADIUS.take(table)
        if "centre" in table.data and "path" in table.data:
            raise table.error("path", "give either centre (a still sphere) or path (a moving one), not both")
        if "path" in table.data:
            keys = PATH.take(table)
        else:
            keys = ((0.0, CENTRE.take(table)),)
        return SphereCollider(radius=radius, keyframes=keys, **shared)

    def check_numbers(self, spec: SphereCollider, file: str, key: str) -> None:
        from ..errors import SceneError
        from ..scene_keys import FLOAT32_MAX, float32_fits

        limit = f"float32 holds magnitudes up to {FLOAT32_MAX:.3g}"
        if not float32_fits(spec.radius):
            raise SceneError(file, f"{key}.radius", f"expected a number that float32 can hold ({limit}), "
                             f"got {spec.radius:g}")
        if not float32_fits(spec.radius + spec.thickness):
            where = f"{key}.radius" if spec.radius >= spec.thickness else f"{key}.thickness"
            raise SceneError(file, where, f"radius + thickness = {spec.radius + spec.thickness:g} m, which float32 "
                             f"cannot hold ({limit})")
        for k, (_, centre) in enumerate(spec.keyframes):
            for axis, v in enumerate(centre):
                if not float32_fits(v):
                    where = f"{key}.path[{k}][{axis + 1}]" if len(spec.keyframes) > 1 else f"{key}.centre[{axis}]"
                    raise SceneError(file, where, f"expected a number that float32 can hold ({limit}), got {v:g}")

    def start_inside(self, spec: SphereCollider, points) -> InsideReport:
        import numpy as np

        centre = np.asarray(spec.centre_at(0.0), np.float64)
        reach = spec.radius + spec.thickness
        inside = np.linalg.norm(points - centre, axis=1) < reach
        where = (f"inside sphere '{spec.name}' (closer than radius + thickness = {reach:.4g} m to its "
                 f"centre {tuple(round(v, 6) for v in centre)} at time 0)")
        fix = ("move the cloth's origin, or the sphere's centre (or its path's first keyframe), so that they start "
               "apart")
        return InsideReport(inside, where, fix)

    # ------------------------------------------------------------------ simulation core
    def counts(self, specs: tuple[SphereCollider, ...]) -> tuple[int, int]:
        """(spheres, keyframes over all spheres when one moves, else 0)."""
        moving = any(s.moving for s in specs)
        return len(specs), sum(len(s.keyframes) for s in specs) if moving else 0

    def device_bytes(self, counts: tuple[int, int]) -> int:
        spheres, keys = counts
        fixed = spheres * (VEC3 + 3 * FLOAT + VEC3)  # start centre, reach, friction (mu_k, mu_s); the State's centre
        # key starts (one more than the spheres), keyframe times and centres, the State's clock
        moving = ((spheres + 1) * INT + keys * (FLOAT + VEC3) + FLOAT64) if keys else 0
        return fixed + moving

    def build(self, specs: tuple[SphereCollider, ...], device) -> dict[str, Any]:
        import warp as wp

        moving = any(s.moving for s in specs)
        out = {
            "spheres": specs,
            "spheres_move": moving,
            "sphere_start": wp.array([s.keyframes[0][1] for s in specs], dtype=wp.vec3),
            "sphere_reach": wp.array([s.radius + s.thickness for s in specs], dtype=float),
            "sphere_friction": wp.array([coulomb(s) for s in specs], dtype=wp.vec2),
        }
        if moving:
            out["key_start"], out["key_times"], out["key_centres"] = keyframe_arrays(specs)
        return out

    def state_arrays(self, colliders) -> dict[str, Any]:
        import warp as wp

        spheres = getattr(colliders, "spheres", ())
        moving = getattr(colliders, "spheres_move", False)
        return {"collider_clock": wp.zeros(1, dtype=wp.float64) if moving else None,
                "sphere_centres": wp.clone(colliders.sphere_start) if spheres else None}

    def bind(self, model, state, pushes=None) -> ColliderLaunches:
        import warp as wp

        from ..kernels.collide_sphere import advance_clock, collide_spheres, place_spheres
        from ..launches import recorded

        c = model.colliders
        before = ()
        if c.spheres_move:
            clock = state.collider_clock
            place = recorded(place_spheres, len(c.spheres), [clock, c.key_start, c.key_times, c.key_centres],
                             [state.sphere_centres])

            def advance(dt: float) -> None:
                wp.launch(advance_clock, 1, inputs=[clock, wp.float64(dt)])
                place.run()

            before = (advance,)
        removed = push_record(pushes, model.device)

        def clamp(first: int, count: int):
            return recorded(collide_spheres, count,
                            [state.particle_q, state.particle_q_inertial, state.particle_dq, model.inv_mass,
                             state.sphere_centres, c.sphere_reach, c.sphere_friction, removed, first])

        return clamp_launches(clamp, model.particle_count, before)

    # ------------------------------------------------------------------ output
    def samples(self, colliders, state, always_moving: bool = False):
        """Centres of the moving spheres only (of every sphere when ``always_moving``), in scene order."""
        import numpy as np

        if always_moving:
            return state.sphere_centres.numpy().copy()
        if not colliders.spheres_move:
            return np.zeros((0, 3), np.float32)
        return state.sphere_centres.numpy()[[s.moving for s in colliders.spheres]]

    def cached(self, spec: SphereCollider, always_moving: bool = False) -> "CachedSphere":
        return CachedSphere(spec.name, spec.radius, spec.keyframes[0][1], spec.moving or always_moving, spec.purpose)

    def owns_prim(self, prim, under_colliders: bool) -> bool:
        from pxr import UsdGeom

        return prim.IsA(UsdGeom.Sphere)

    def read_prim(self, prim, reader) -> dict[str, Any]:
        """The sphere at the reader's time, as the drawing primitive ``spheres``: (centre, radius)."""
        import numpy as np
        from pxr import UsdGeom

        sphere, time = UsdGeom.Sphere(prim), reader.time
        centre = reader.attribute(sphere, "xformOp:translate",
                                  lambda: np.array(sphere.ComputeLocalToWorldTransform(time).ExtractTranslation()))
        radius = reader.attribute(sphere, "radius", lambda: sphere.GetRadiusAttr().Get(time))
        return {"spheres": (reader.finite(sphere, centre), float(reader.finite(sphere, radius)))}

    def add_to_live(self, app, specs: tuple[SphereCollider, ...]) -> LiveDrawing:
        """Icospheres at the live session's centres; a still sphere gets a gizmo that drags it. The per-frame
        update follows the centres (a path, a drag, or Reset)."""
        import numpy as np

        drawn = []
        centres = app.session.sphere_centres()
        for i, sphere in enumerate(specs):
            handle = draw_sphere(app.server, sphere.name, centres[i], sphere.radius)
            gizmo = None
            if not sphere.moving:  # a keyframed sphere follows its path; the others can be dragged
                gizmo = app.server.scene.add_transform_controls(
                    f"/drag/{sphere.name}", scale=max(sphere.radius * 1.6, 0.1), disable_rotations=True,
                    position=tuple(float(v) for v in centres[i]))

                def dragged(event, index=i) -> None:
                    app.guarded(lambda: app.session.move_sphere(index, np.asarray(event.target.position)))

                gizmo.on_update(dragged)
            drawn.append(LiveSphere(handle, gizmo, centres[i]))

        def update() -> None:
            for sphere, centre in zip(drawn, app.session.sphere_centres()):
                if not np.array_equal(centre, sphere.centre):
                    sphere.handle.position = tuple(float(v) for v in centre)
                    sphere.centre = centre
                    if sphere.gizmo is not None and not np.allclose(sphere.gizmo.position, centre):
                        sphere.gizmo.position = tuple(float(v) for v in centre)  # moved by Reset, not the drag

        return LiveDrawing(drawn, [d.centre for d in drawn], update)


@dataclass
class LiveSphere:
    """A sphere on the live page: its icosphere, its drag gizmo (None for a keyframed one), and the centre
    drawn last."""

    handle: Any
    gizmo: Any
    centre: Any


@dataclass(frozen=True)
class CachedSphere:
    """A sphere collider in the cache: its render-visible radius (thickness excluded) and where it starts."""

    name: str
    radius: float
    centre: tuple[float, float, float]
    moving: bool = False
    purpose: str = "guide"

    def define(self, stage, path):
        """A Sphere prim with a translate: sampled per frame when it moves (the op returned), else set once."""
        from pxr import UsdGeom, Vt

        sphere = UsdGeom.Sphere.Define(stage, path)
        sphere.CreateRadiusAttr(float(self.radius))
        r = float(self.radius)
        sphere.CreateExtentAttr(Vt.Vec3fArray([(-r, -r, -r), (r, r, r)]))
        sphere.CreatePurposeAttr(self.purpose)
        op = sphere.AddTranslateOp()
        if self.moving:
            return op  # sampled per frame in write_frame
        op.Set(tuple(float(c) for c in self.centre))
        return None


SPHERE = SphereKind()


LIVE_COLOUR = (178, 184, 194)  # sRGB, on the live and view pages


def draw_sphere(server, name: str, centre, radius: float):
    """A sphere collider on a viser page (live and view): an icosphere at ``centre``."""
    return server.scene.add_icosphere(f"/colliders/{name}", radius=float(radius), color=LIVE_COLOUR,
                                      subdivisions=3, position=tuple(float(v) for v in centre))
