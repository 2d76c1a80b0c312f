"""Scene colliders on the device, and the launches that clamp particles out of them.

Only the collider kinds a scene has get arrays and launches: no planes, no ``collide_planes``; no moving
sphere, no clock and no ``place_spheres``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from warp_verlet.kernels.collide import advance_clock, collide_planes, collide_spheres, place_spheres

from .scene import Scene


class Colliders:
    def __init__(self, scene: Scene, device):
        self.planes, self.spheres = scene.planes, scene.spheres
        self.moving = any(s.moving for s in self.spheres)
        with wp.ScopedDevice(device):
            if self.planes:
                self.plane_points = wp.array([p.point for p in self.planes], dtype=wp.vec3)
                self.plane_normals = wp.array([p.normal for p in self.planes], dtype=wp.vec3)
                self.plane_thickness = wp.array([p.thickness for p in self.planes], dtype=float)
                self.plane_friction = wp.array([p.friction for p in self.planes], dtype=float)
            if self.spheres:
                self.sphere_centres = wp.array([s.keyframes[0][1] for s in self.spheres], dtype=wp.vec3)
                self.sphere_reach = wp.array([s.radius + s.thickness for s in self.spheres], dtype=float)
                self.sphere_friction = wp.array([s.friction for s in self.spheres], dtype=float)
            if self.moving:
                counts = [len(s.keyframes) for s in self.spheres]
                self.key_start = wp.array(np.r_[0, np.cumsum(counts)].astype(np.int32), dtype=int)
                self.key_times = wp.array([t for s in self.spheres for t, _ in s.keyframes], dtype=float)
                self.key_centres = wp.array([c for s in self.spheres for _, c in s.keyframes], dtype=wp.vec3)
                self.clock = wp.zeros(1, dtype=wp.float64)

    def launch_plan(self) -> list[str]:
        plan = ["advance_clock", "place_spheres"] if self.moving else []
        plan += ["collide_spheres"] if self.spheres else []
        plan += ["collide_planes"] if self.planes else []
        return plan

    def record(self, x, x_inertial, delta, inv_mass) -> list:
        """The clamping launches after the clock, recorded once (they only reference arrays)."""
        launches = []
        if self.moving:
            launches.append(wp.launch(place_spheres, len(self.spheres), inputs=[
                self.clock, self.key_start, self.key_times, self.key_centres], outputs=[self.sphere_centres],
                record_cmd=True))
        # Spheres first, planes last: a sphere resting on the ground cannot push cloth through the ground.
        if self.spheres:
            launches.append(wp.launch(collide_spheres, x.shape[0], inputs=[
                x, x_inertial, delta, inv_mass, self.sphere_centres, self.sphere_reach, self.sphere_friction],
                record_cmd=True))
        if self.planes:
            launches.append(wp.launch(collide_planes, x.shape[0], inputs=[
                x, x_inertial, delta, inv_mass, self.plane_points, self.plane_normals, self.plane_thickness,
                self.plane_friction], record_cmd=True))
        return launches

    def tick(self, dt: float) -> None:
        if self.moving:
            wp.launch(advance_clock, 1, inputs=[self.clock, wp.float64(dt)])

    def centres(self) -> np.ndarray:
        """Sphere centres now, (spheres, 3), on the host."""
        return self.sphere_centres.numpy() if self.spheres else np.zeros((0, 3), np.float32)

    def moving_centres(self) -> np.ndarray:
        """Centres of the moving spheres only, in scene order: what the cache samples per frame. Costs no
        device copy when nothing moves."""
        if not self.moving:
            return np.zeros((0, 3), np.float32)
        return self.centres()[[s.moving for s in self.spheres]]
