"""The step loop: decides which kernels a scene needs and launches only those.

A substep is

1. ``verlet_step`` (gravity and wind folded into one acceleration on the host, drag as a scale),
2. relaxation: ``iterations`` sweeps, each one launch of ``relax_colour`` per colour (Gauss-Seidel across
   colours), or one ``relax_jacobi`` gather plus a copy (Jacobi),
3. collider clamping, once, after the sweeps: ``collide_spheres`` and ``collide_planes`` for the kinds the
   scene has (moving spheres are first placed on the device clock),
4. ``tear_sticks``, only when a cloth of the scene can tear,

and nothing else unless the scene asks for it. A frame's fixed-dt substeps are captured once (a CUDA graph, or
Warp's CPU capture) and replayed, so the host issues one launch per frame. On the CPU, large grids instead
cut every colour over several threads (warp_verlet/cpu_team.py); the result is bit-identical either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import warp as wp

from warp_verlet.kernels.guard import find_diverged
from warp_verlet.kernels.integrate import verlet_start, verlet_step
from warp_verlet.kernels.relax import relax_colour, relax_jacobi
from warp_verlet.kernels.tear import tear_sticks

from .colliders import Colliders
from .cpu_team import COLOURED_SECONDS_PER_STICK, JACOBI_SECONDS_PER_ENTRY, PhaseTeam, auto_threads, split
from .errors import WarpVerletError
from .memory import available_host_bytes, check_fits
from .model import Model
from .scene import Scene


def resolve_device(name: str | None = None):
    """``None`` picks CUDA when present, else the CPU. Accepts "cpu", "cuda" and "cuda:N"."""
    if name is None:
        return wp.get_device("cuda" if wp.is_cuda_available() else "cpu")
    if name != "cpu" and not (name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit())):
        raise WarpVerletError(f"device must be 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise WarpVerletError(f"device {name!r} asked for, but no CUDA device is available (try --device cpu)")
    try:
        return wp.get_device(name)
    except Exception as exc:  # Warp raises a bare error for an index past the device count
        raise WarpVerletError(f"device {name!r} is not available: {exc}") from None


@dataclass(frozen=True)
class StretchStats:
    """Relative stretch |D - L| / L over structural sticks."""

    max: float
    rms: float

    @classmethod
    def of(cls, values: np.ndarray) -> "StretchStats":
        if values.size == 0:
            return cls(0.0, 0.0)
        return cls(float(values.max()), float(np.sqrt(np.mean(values * values))))


class Simulator:
    """One scene on one device.

    ``step(dt)`` runs one substep of any dt (time-step-corrected Verlet); ``step_frame()`` runs the scene's
    fixed substeps of one frame; ``advance(frame_time)`` is the real-time entry point with a clamped
    accumulator.
    """

    def __init__(self, scene: Scene, device: str | None = None, colouring: str = "auto", use_graph: bool = True,
                 threads: int | None = None):
        self.scene = scene
        self.settings = scene.simulation
        self.device = resolve_device(device)
        # Refuse a scene that cannot fit before allocating any of it.
        self.memory = check_fits(scene, str(self.device), self.device.free_memory if self.device.is_cuda else None,
                                 available_host_bytes())
        with wp.ScopedDevice(self.device):
            self.model = Model(scene, self.device, colouring)
            self.x = wp.array(self.model.rest_positions, dtype=wp.vec3)
            # Summed-form Verlet state (kernels/integrate.py): what the last step predicted, and its increment.
            self.x_inertial = wp.empty_like(self.x)
            self.delta = wp.empty_like(self.x)
            # Jacobi reads old positions while writing new ones: only it needs a second buffer.
            self._x_scratch = wp.empty_like(self.x) if self.settings.solver == "jacobi" else None
            self.colliders = Colliders(scene, self.device)
        accel = np.add(self.settings.gravity, self.settings.wind)
        self.accel = wp.vec3(*accel)
        self._accel_magnitude = float(np.linalg.norm(accel))  # for the float32 limit on dt
        self.time = 0.0
        self.steps = 0
        self._dt_prev: float | None = None
        self._accumulator = 0.0
        self._first_diverged = None  # allocated by the first divergence check
        self._frame_graph = None
        self.threads = self._thread_count(threads)
        phases = self._relax_phases()
        self._sweep = [task for phase in phases for task in phase if task is not None]
        self._team = PhaseTeam(phases, self.settings.iterations) if self.threads > 1 and phases else None
        # A frame's substeps are captured once and replayed: a CUDA graph, or on the CPU Warp's own capture
        # (replayed in C++: 2.4 -> 1.2 ms per frame at 32^2, bit-identical). Threaded relaxation needs its
        # launches issued from Python, so it is not captured.
        self._use_graph = use_graph and self._team is None
        with wp.ScopedDevice(self.device):
            self._clamp = self.colliders.record(self.x, self.x_inertial, self.delta, self.model.inv_mass)
            self._tear = self._record_tear_launch()
        self._stages = self.stages()
        self._relaxes = "relax" in dict(self._stages)
        self.min_dt = self._smallest_resolved_dt()
        if self.settings.dt < self.min_dt:
            raise WarpVerletError(self._too_small(self.settings.dt) + " (raise it with fewer simulation.substeps)")

    def _thread_count(self, threads: int | None) -> int:
        """CPU threads for the relaxation: ``None`` picks them from the cores and the work per colour
        (``cpu_team.auto_threads``); CUDA always uses 1, its parallelism is on the device."""
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
            raise WarpVerletError(f"threads must be a whole number >= 1, got {threads!r}")
        if self.device.is_cuda:
            if threads not in (None, 1):
                raise WarpVerletError(f"threads = {threads} applies to the CPU only; on {self.device} the "
                                      "relaxation runs in parallel on the device")
            return 1
        if threads is not None:
            return threads
        m = self.model
        if self.settings.solver == "coloured":
            phase = m.stick_count / max(m.colour_count, 1) * COLOURED_SECONDS_PER_STICK
        else:
            phase = m.stick_count * JACOBI_SECONDS_PER_ENTRY  # two entries per stick over two phases per sweep
        return auto_threads(phase)

    def _smallest_resolved_dt(self) -> float:
        """The smallest dt whose gravity-and-wind step |a| dt^2 is at least 4 float32 spacings of the scene's
        coordinates. Below it, x + step rounds back to x, the relaxation corrects the rounding-level stick
        errors, and that correction enters the implicit velocity and cancels the acceleration: a cloth at
        dt = 1e-5 s does not fall at all, at 1e-4 s (|a| dt^2 below one spacing) it falls 1.8% short. Without
        relaxation nothing feeds rounding back into velocity, so there is no limit."""
        a = self._accel_magnitude
        if not self._relaxes or a == 0.0:
            return 0.0
        scale = float(np.abs(self.model.rest_positions).max()) if self.model.particle_count else 1.0
        return float(np.sqrt(4.0 * np.spacing(np.float32(max(scale, 1e-3))) / a))

    def _too_small(self, dt: float) -> str:
        return (f"dt = {dt:.3g} s is too small for float32 positions: one step's acceleration moves a particle by "
                f"|a| dt^2 = {self._accel_magnitude * dt * dt:.2g} m, "
                f"under 4 float32 spacings of this scene's coordinates, so the relaxation's rounding would cancel "
                f"it; the smallest dt resolved here is {self.min_dt:.3g} s")

    def _record_tear_launch(self):
        m = self.model
        if not m.tears:
            return None
        self._torn_entries = wp.zeros(1, dtype=int)  # tear entries zeroed so far (see Model._build_tearing)
        return wp.launch(tear_sticks, m.tear_ends.shape[0], inputs=[self.x, m.tear_ends, m.tear_length],
                         outputs=[m.tear_stiffness, self._torn_entries], record_cmd=True)

    # ------------------------------------------------------------------ what a substep launches
    def stages(self) -> list[tuple[str, Callable[[float], None]]]:
        """The stages of one substep, in order, as (name, run(dt)): only those the scene uses. ``_substep``
        runs exactly these; ``bench/throughput.py`` times them one by one."""
        stages: list[tuple[str, Callable[[float], None]]] = []
        if self.model.has_free_particles:
            stages.append(("integrate", self._integrate))
        if self._sweep and self.settings.iterations:
            stages.append(("relax", self._relax))
        if self._clamp:
            stages.append(("collide", self._collide))
        if self._tear:
            stages.append(("tear", lambda dt: self._tear.launch()))
        return stages

    def launch_plan(self) -> list[str]:
        """The kernel launches of one substep, in order (after the first, which also runs verlet_start)."""
        plan = ["verlet_step"] if self.model.has_free_particles else []
        if self.settings.solver == "coloured":
            plan += ["relax_colour"] * (self.model.colour_count * self.settings.iterations)
        elif self.model.stick_count:
            plan += ["relax_jacobi", "copy"] * self.settings.iterations
        return plan + self.colliders.launch_plan() + (["tear_sticks"] if self._tear else [])

    # ------------------------------------------------------------------ stepping
    def step(self, dt: float | None = None) -> None:
        """Advance by one substep of ``dt`` seconds (the scene's fixed dt by default)."""
        dt = self.settings.dt if dt is None else float(dt)
        if not (dt > 0.0 and np.isfinite(dt)):
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt}")
        if dt < self.min_dt:
            raise WarpVerletError(self._too_small(dt))
        if self._relaxes and self._dt_prev is not None and dt * self.settings.max_dt_ratio < self._dt_prev:
            # The relaxation leaves a residual stretch after each step; a much shorter step removes it within
            # that step, and Verlet turns the move into velocity residual / dt: energy from nowhere (a drop
            # from 1/240 s to 1e-5 s gave a hanging cloth 10x the kinetic energy gravity had released).
            # Without relaxation there is no residual, and any sequence of steps is exact (test_integrate).
            raise WarpVerletError(
                f"dt fell from {self._dt_prev:.3g} s to {dt:.3g} s in one step; a step may shrink by at most a "
                f"factor max_dt_ratio = {self.settings.max_dt_ratio:g} (shrink it over several steps), or the "
                "relaxation's residual stretch would turn into spurious velocity")
        with wp.ScopedDevice(self.device):
            self._substep(dt)

    def _substep(self, dt: float) -> None:
        if self._dt_prev is None:
            # Exact start for constant acceleration: x_prev = x0 - v0 dt + a dt^2 / 2 (v0 = 0).
            wp.launch(verlet_start, self.model.particle_count,
                      inputs=[self.x, self.model.inv_mass, wp.vec3(0.0), self.accel, dt],
                      outputs=[self.x_inertial, self.delta])
            self._dt_prev = dt
        for _, run in self._stages:
            run(dt)
        self._dt_prev = dt
        self.time += dt
        self.steps += 1

    def _integrate(self, dt: float) -> None:
        ratio = min(dt / self._dt_prev, self.settings.max_dt_ratio)
        accel_offset = self.accel * (dt * (dt + self._dt_prev) * 0.5)
        wp.launch(verlet_step, self.model.particle_count,
                  inputs=[self.x, self.x_inertial, self.delta, self.model.inv_mass, self.settings.drag * ratio,
                          accel_offset])

    def _collide(self, dt: float) -> None:
        self.colliders.tick(dt)
        for launch in self._clamp:
            launch.launch()

    def _relax_phases(self) -> list[list]:
        """One sweep as phases that run one after the other, each cut into ``self.threads`` pieces that may
        run at once: one phase per colour (coloured), or the gather and the copy back (Jacobi). A piece is a
        recorded ``wp.Launch``'s ``launch`` (replaying it skips the argument packing of ``wp.launch``, which
        dominates small grids on the CPU: measured at 64^2, 2.5 -> 1.4 ms per 8 sweeps), or None when empty.
        The launches only reference arrays, so they stay valid for the simulator's lifetime."""
        m, threads = self.model, self.threads

        def pieces(kernel, first: int, count: int, args) -> list:
            return [wp.launch(kernel, n, inputs=args(f), record_cmd=True).launch if n else None
                    for f, n in split(first, count, threads)]

        with wp.ScopedDevice(self.device):
            if self.settings.solver == "coloured":
                return [pieces(relax_colour, first, count,
                               lambda f: [self.x, m.inv_mass, m.stick_ends, m.stick_rest, m.stick_stiffness, f])
                        for first, count in m.colour_ranges]
            if not m.stick_count:
                return []
            gather = pieces(relax_jacobi, 0, m.particle_count,
                            lambda f: [self.x, m.inv_mass, m.neighbour_start, m.neighbour, m.neighbour_rest,
                                       m.neighbour_stiffness, f, self._x_scratch])
            copy_back = [self._copy_back(f, n) if n else None for f, n in split(0, m.particle_count, threads)]
            return [gather, copy_back]

    def _copy_back(self, first: int, count: int) -> Callable[[], None]:
        """Jacobi's new positions of particles first .. first + count - 1 into x. The task holds the arrays,
        not the simulator: worker threads keep their tasks alive, and must not keep the simulator alive."""
        x, scratch = self.x, self._x_scratch
        return lambda: wp.copy(x, scratch, dest_offset=first, src_offset=first, count=count)

    def _relax(self, dt: float = 0.0) -> None:
        if self._team is not None:
            self._team.run()
            return
        for _ in range(self.settings.iterations):
            for task in self._sweep:
                task()

    def step_frame(self) -> None:
        """The scene's ``substeps`` fixed steps of one frame, replayed from a capture (a CUDA graph, or Warp's
        CPU capture) once the first frame (which initialises x_prev) has run, unless the CPU relaxation is
        threaded."""
        n, dt = self.settings.substeps, self.settings.dt
        with wp.ScopedDevice(self.device):
            if not self._use_graph or self._dt_prev != dt:
                for _ in range(n):
                    self._substep(dt)
                return
            if self._frame_graph is None:
                time, steps = self.time, self.steps
                with wp.ScopedCapture() as capture:
                    for _ in range(n):
                        self._substep(dt)
                self._frame_graph = capture.graph
                self.time, self.steps = time, steps  # capture recorded the work; it has not run yet
            wp.capture_launch(self._frame_graph)
            self.time += n * dt
            self.steps += n

    def advance(self, frame_time: float) -> float:
        """Real-time stepping: bank ``frame_time`` seconds, run as many fixed substeps as it pays for, and
        return the interpolation factor alpha in [0, 1) for :meth:`render_positions`.

        The bank is clamped to ``max_frame_time`` so that a stall (a debugger pause, a slow frame) cannot
        queue more substeps than the next frame can afford: the spiral of death."""
        if not (frame_time >= 0.0 and np.isfinite(frame_time)):
            raise ValueError(f"frame_time must be a finite number of seconds >= 0, got {frame_time}")
        dt = self.settings.dt
        self._accumulator = min(self._accumulator + frame_time, self.settings.max_frame_time)
        # The tiny epsilon keeps 1/60 s from paying for 3.9999999 substeps of 1/240 s instead of 4.
        n = int(self._accumulator / dt + 1e-9)
        with wp.ScopedDevice(self.device):
            for _ in range(n):
                self._substep(dt)
        self._accumulator = max(self._accumulator - n * dt, 0.0)
        return self._accumulator / dt

    # ------------------------------------------------------------------ reading state
    def positions(self) -> np.ndarray:
        """All particle positions, (particle_count, 3) float32: a snapshot on the host."""
        points = self.x.numpy()
        # On the CPU, numpy() is a view of the live array, which the next step would overwrite.
        return points.copy() if self.device.is_cpu else points

    def previous_positions(self) -> np.ndarray:
        """Positions at the end of the previous substep (x_prev of the textbook form)."""
        return self.x_inertial.numpy() - self.delta.numpy()

    def render_positions(self, alpha: float) -> np.ndarray:
        """Positions interpolated between the last two substeps: x_prev + alpha (x - x_prev)."""
        x, x_prev = self.positions(), self.previous_positions()
        return x_prev + np.float32(alpha) * (x - x_prev)

    def diverged_particle(self) -> int | None:
        """The lowest index of a particle that is not finite or beyond ``position_bound``, or None. Checked on
        the device; the host reads back one integer, so it is cheap enough to ask once per frame."""
        n = self.model.particle_count
        with wp.ScopedDevice(self.device):
            if self._first_diverged is None:
                self._first_diverged = wp.empty(1, dtype=int)
            self._first_diverged.fill_(n)
            wp.launch(find_diverged, n, inputs=[self.x, self.settings.position_bound], outputs=[self._first_diverged])
            first = int(self._first_diverged.numpy()[0])
        return None if first == n else first

    def torn_count(self) -> int:
        """Sticks torn so far: one integer copied from the device, so it is cheap to ask every frame."""
        if not self._tear:
            return 0
        return int(self._torn_entries.numpy()[0]) // self.model.tear_entries_per_stick

    def torn_sticks(self) -> np.ndarray:
        """Which sticks are torn, a bool per stick in ``model.host_sticks`` order (all False without tearing)."""
        if not self._tear:
            return np.zeros(self.model.stick_count, bool)
        return self.model.torn_sticks(self.model.tear_stiffness.numpy())

    def stretch(self, points: np.ndarray | None = None) -> StretchStats:
        """Stretch over the structural sticks that are not torn."""
        points = self.positions() if points is None else points
        torn = self.torn_sticks() if self._tear else None
        return StretchStats.of(self.model.structural_stretch(points, torn))
