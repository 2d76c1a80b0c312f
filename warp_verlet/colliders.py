"""Scene colliders: their fixed data on the device, and the launches that clamp particles out of them.

Only the collider kinds a scene has get arrays and launches: no planes, no ``collide_planes``; no moving
sphere, no clock and no ``place_spheres``. What moves (the clock and the sphere centres) lives in the
:class:`~warp_verlet.state.State`; this module holds what does not.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .scene import Scene


class ColliderModel:
    """The scene's planes and spheres on one device: geometry, thickness, friction and sphere keyframes."""

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
                self.sphere_start = wp.array([s.keyframes[0][1] for s in self.spheres], dtype=wp.vec3)
                self.sphere_reach = wp.array([s.radius + s.thickness for s in self.spheres], dtype=float)
                self.sphere_friction = wp.array([s.friction for s in self.spheres], dtype=float)
            if self.moving:
                # A still sphere (one centre, however many keyframes) keeps one key: place_spheres leaves it be.
                keys = [s.keyframes if s.moving else s.keyframes[:1] for s in self.spheres]
                self.key_start = wp.array(np.r_[0, np.cumsum([len(k) for k in keys])].astype(np.int32), dtype=int)
                self.key_times = wp.array([t for k in keys for t, _ in k], dtype=float)
                self.key_centres = wp.array([c for k in keys for _, c in k], dtype=wp.vec3)

    def moving_centres(self, state) -> np.ndarray:
        """Centres of the moving spheres only, in scene order: what the cache samples per frame. Costs no
        device copy when nothing moves."""
        if not self.moving:
            return np.zeros((0, 3), np.float32)
        return state.sphere_centres.numpy()[[s.moving for s in self.spheres]]
