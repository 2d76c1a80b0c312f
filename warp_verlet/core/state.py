"""Everything that changes while a scene runs, apart from the immutable :class:`~warp_verlet.core.model.Model`.

A solver steps a ``State`` by dt; nothing else about a run is hidden anywhere. So a state can be cloned (a
checkpoint), assigned back (a rollback, or a reset to a clone of the start) and given an initial velocity.

Arrays exist only when the scene needs them (a state of a scene that cannot tear has no live-stick
weights, one with no moving sphere has no clock), as in Newton's ``State``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..errors import ArgumentError
from ..colliders import kinds as collider_kinds
from .model import Model


class State:
    """The time-varying data of one scene on one device.

    Attributes (N particles, in the Model's device order; E tear entries: one per stick for the coloured
    solver, two for Jacobi):

    - ``particle_q``: (N,) ``wp.vec3`` (float32), or ``wp.vec3d`` where the model's precision is float64
      (``model.position_dtype``), m. Positions.
    - ``particle_q_inertial``: (N,) of the same type, m. The position the last Verlet step predicted (summed form,
      kernels/integrate.py): x - x_prev = ``particle_dq`` + (x - x_inertial).
    - ``particle_dq``: (N,) of the same type, m. The last step's increment (zero before the first step).
    - ``stick_weight``: (E,) float32, dimensionless, or None. Per tear entry, 1 while the stick holds and 0
      once torn; only when a cloth can tear. The relaxation multiplies a stick's correction by it.
    - ``torn_entries``: (1,) int32, or None. Tear entries zeroed so far; only when a cloth can tear.
    - ``tether_length``: (T, K) float32, m, or None. Live tether lengths (+inf once a tear cuts a particle off
      from its pin); only when a tethered cloth can tear, otherwise the Model's lengths serve.
    - ``stick_force``: (M,) float32, N, or None. Per stick, the running average of the force it transmits
      (kernels/tear.py ``tear_sticks_by_tension``); only when a cloth tears by tension.
    - what each collider kind moves (its ``state_arrays``, warp_verlet/colliders), for spheres:
      ``collider_clock``: (1,) float64, s, or None. Simulated time on the device, which places the moving
      spheres inside a captured frame; only when a sphere moves. ``sphere_centres``: (S,) ``wp.vec3``, m, or
      None. Where each sphere is now; only when there are spheres.
    - ``air_clock``: (1,) float64, s, or None. Simulated time on the device, at which the air's keyframes and
      gusts are read; only when the air changes with time.

    Host scalars: ``time`` (s simulated), ``steps`` (substeps taken) and ``dt_prev`` (s, the last step's dt,
    None before the first step: the next step then runs the exact start). On the host too, ``start_velocity``:
    (N, 3) m/s of the positions' numpy type, or None (at rest): the velocity :meth:`set_velocity` gave, which
    the exact start turns into the first increment; None again once it has.

    The host methods (:meth:`positions`, :meth:`previous_positions`, :meth:`set_positions`,
    :meth:`set_velocity`) take and give particles in the scene's order, whatever order the device holds them in
    (``Model.scene_particle``): positions cross between the device and the user here, and are converted here.
    """

    _ARRAYS = ("particle_q", "particle_q_inertial", "particle_dq", "stick_weight", "torn_entries",
               "tether_length", "stick_force", "air_clock")  # then each collider kind's (state_arrays), in registry order

    def __init__(self, model: Model):
        self.model = model
        with wp.ScopedDevice(model.device):
            self.particle_q = wp.array(model.rest_positions, dtype=model.position_dtype)  # float32 widens exactly
            self.particle_q_inertial = wp.clone(self.particle_q)  # x_prev = x before the first step
            self.particle_dq = wp.zeros_like(self.particle_q)  # no initial velocity
            self.stick_weight = wp.clone(model.tear_weight_start) if model.tears else None
            self.torn_entries = wp.zeros(1, dtype=int) if model.tears else None
            cuttable = model.tears and model.tether_table is not None
            self.tether_length = wp.clone(model.tether_length) if cuttable else None
            self.stick_force = wp.zeros(model.stick_count, dtype=float) if model.tension_tears else None
            # Simulated time on the device for air that changes with time (keyframes, gusts), as a moving
            # sphere's clock: a captured frame replays it.
            self.air_clock = wp.zeros(1, dtype=wp.float64) if model.air is not None and model.air.clock else None
            self.collider_array_names: tuple[str, ...] = ()  # what the collider kinds move, present or None
            for kind in collider_kinds():  # every kind's names, None where this scene has none of it
                for name, array in kind.state_arrays(model.colliders).items():
                    setattr(self, name, array)
                    self.collider_array_names += (name,)
        self.time = 0.0
        self.steps = 0
        self.dt_prev: float | None = None
        self.start_velocity: np.ndarray | None = None

    def arrays(self) -> dict[str, wp.array]:
        """The device arrays this state holds, by name (absent ones left out)."""
        return {name: getattr(self, name) for name in self._names() if getattr(self, name) is not None}

    def _names(self) -> tuple[str, ...]:
        return self._ARRAYS + self.collider_array_names

    def clone(self) -> "State":
        """An independent copy: stepping one does not touch the other."""
        other = State.__new__(State)
        other.model = self.model
        with wp.ScopedDevice(self.model.device):
            other.collider_array_names = self.collider_array_names
            for name in self._names():
                value = getattr(self, name)
                setattr(other, name, None if value is None else wp.clone(value))
        other.time, other.steps, other.dt_prev = self.time, self.steps, self.dt_prev
        other.start_velocity = None if self.start_velocity is None else self.start_velocity.copy()
        return other

    def assign(self, other: "State") -> None:
        """Copy ``other`` into this state in place (its arrays keep their addresses, so launches recorded
        against this state, and a captured frame, stay valid)."""
        if other.model is not self.model:
            raise ArgumentError("a state can only be assigned from a state of the same model")
        for name in self._names():
            mine = getattr(self, name)
            if mine is not None:
                wp.copy(mine, getattr(other, name))
        self.time, self.steps, self.dt_prev = other.time, other.steps, other.dt_prev
        self.start_velocity = None if other.start_velocity is None else other.start_velocity.copy()

    def set_velocity(self, velocity) -> None:
        """Start again from the current positions, moving at ``velocity`` (m/s): one (3,) vector for every particle, or
        (N, 3). Pinned particles stay at rest. The next step runs the exact start (x = x0 + v0 dt + a dt^2 / 2
        for a constant acceleration a)."""
        n, dtype = self.model.particle_count, self.model.host_position_dtype
        try:
            v = np.broadcast_to(np.asarray(velocity, dtype=dtype), (n, 3))
        except (ValueError, TypeError):
            shape = np.shape(velocity) if not isinstance(velocity, str) else "a string"
            raise ArgumentError(f"velocity must be numbers of shape (3,) or ({n}, 3) for this model's {n} "
                                f"particles, got {shape}") from None
        if not np.isfinite(v).all():
            raise ArgumentError("velocity must be finite")
        v = self.model.to_device_order(v)
        self.start_velocity = np.where(self.model.host_inv_mass[:, None] > 0, v, 0.0).astype(dtype)
        self.particle_dq.zero_()
        self.particle_q_inertial.assign(self.particle_q)
        self.dt_prev = None

    def positions(self) -> np.ndarray:
        """Particle positions in the scene's order, (N, 3) m, float32 or float64 as ``model.precision``: a host
        snapshot that later steps do not change."""
        points = self.particle_q.numpy()
        if self.model.device_particle is not None:
            return points[self.model.device_particle]  # a gather: a copy
        return points.copy() if self.model.device.is_cpu else points  # on the CPU numpy() is a live view

    def set_positions(self, points) -> None:
        """Overwrite the positions, (N, 3) m in the scene's order, keeping the implicit velocity x - x_prev of every
        particle."""
        n = self.model.particle_count
        try:
            points = np.asarray(points, dtype=self.model.host_position_dtype)
        except (ValueError, TypeError):
            raise ArgumentError(f"points must be numbers of shape ({n}, 3)") from None
        if points.size != 3 * n:
            raise ArgumentError(f"points must have shape ({n}, 3) for this model's {n} particles, got {points.shape}")
        points = self.model.to_device_order(points.reshape(n, 3))
        if self.dt_prev is None:
            self.particle_q.assign(points)
            return
        # x - x_prev = dq + (x - x_inertial): move x_inertial with x so that the difference stays.
        shift = points - self.particle_q.numpy()
        self.particle_q.assign(points)
        self.particle_q_inertial.assign(self.particle_q_inertial.numpy() + shift)

    def previous_positions(self) -> np.ndarray:
        """Positions at the end of the previous substep (x_prev of the textbook form), in the scene's order."""
        return self.model.to_scene_order(self.particle_q_inertial.numpy() - self.particle_dq.numpy())
