"""The friendly driver: one scene's Model, State and solver, with frame stepping, capture and queries.

Which kernels a substep launches is decided by the table in warp_verlet/core/stages.py, from the scene. A
substep is

1. ``verlet_step`` (gravity and wind folded into one acceleration on the host, damping per second),
2. relaxation: ``iterations`` sweeps, each one launch of ``relax_colour`` (``relax_colour_compliant`` when
   a stick is soft) per colour (Gauss-Seidel across colours), or one ``relax_jacobi`` gather plus a copy
   (Jacobi); on a GPU, one grid cloth that cannot tear computes its sticks instead of reading them
   (``relax_grid_colour``, kernels/grid_relax.py, bit-identical; ``constraint_sets`` names the choice),
3. collider clamping, once, after the sweeps: each collider kind's clamp (``collide_spheres``, ``collide_planes``)
   for the kinds the scene has, in registry order (moving spheres are first placed on the device clock),
4. ``tear_sticks``, only when a cloth of the scene can tear,

and nothing else unless the scene asks for it. A frame's fixed-dt substeps are captured once (a CUDA graph, or
Warp's CPU capture) and replayed, so the host issues one launch per frame. On the CPU, larger grids also cut
every colour over several threads (warp_verlet/core/cpu_team.py), each replaying its own graph of the frame; the
result is bit-identical either way.
"""

from __future__ import annotations

import warnings
from contextlib import nullcontext
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import warp as wp

from warp_verlet.kernels.guard import find_diverged

from ..errors import ArgumentError, StateError, WarpVerletError
from ..machine import available_host_bytes
from .memory import check_fits
from .model import Model
from ..input.scene import Scene
from .cpu_team import FrameReplayer, FrameTeam
from .solver import VerletSolver
from .budget import FLOAT32_FLOOR, MAX_SUBSTEPS, Budget
from ..constraints import kinds as constraint_kinds
from .stages import Requirements
from .state import State
from .warp_setup import ensure_kernel_cache


def resolve_device(name: str | None = None):
    """``None`` picks CUDA when present, else the CPU. Accepts "cpu", "cuda" and "cuda:N"."""
    ensure_kernel_cache(note=warnings.warn)  # a clear error, not Warp's PermissionError, when it cannot compile
    if name is None:
        return wp.get_device("cuda" if wp.is_cuda_available() else "cpu")
    if not isinstance(name, str):
        raise ArgumentError(f"device must be None or a string 'cpu', 'cuda' or 'cuda:N', got {name!r}")
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


class StretchReadback:
    """The RMS structural stretch for the target_stretch budget, reduced on the device in a fixed order
    (kernels/readback.py: per piece of a grid row, or per chunk of structural sticks, then sums of partial sums),
    so that one float64 crosses to the host and the same positions always give the same number. On CUDA the
    number is copied into pinned host memory behind an event and read at the next frame boundary, a frame late,
    so that the host never waits for the device; on the CPU the launches are synchronous and it is read at once.
    A grid with implicit sticks needs no arrays but the partial sums; other cloths upload their structural
    sticks once."""

    STICKS_PER_THREAD = 64
    COLUMNS_PER_THREAD = 32  # of a grid row: enough threads that a 1024^2 sum is not one long loop per row
    SUMS_PER_THREAD = 32

    def __init__(self, model: Model, device):
        from warp_verlet.kernels.positions import instance
        from warp_verlet.kernels.readback import chunk_stretch, grid_row_stretch

        self.device = device
        with wp.ScopedDevice(device):
            if model.sticks_form in ("implicit", "tiled"):
                top, g = model.cloths[0].topology, model.grid
                chunk = self.COLUMNS_PER_THREAD
                count = top.rows * -(-top.cols // chunk)
                kernel = instance(grid_row_stretch, model.position_dtype)
                self._inputs = [model.cloths[0].first, top.rows, top.cols, g.col_sq1, g.row_sq1, chunk]
                self._weight_at = None
            else:
                chosen = np.flatnonzero(model.structural)
                entry = np.zeros(model.stick_count, np.int32)
                if model.tears:  # the weight entry that says whether a stick is torn
                    entry[model._tear_entry_stick] = np.arange(len(model._tear_entry_stick), dtype=np.int32)
                chunk = self.STICKS_PER_THREAD
                count = max(1, -(-len(chosen) // chunk))
                kernel = instance(chunk_stretch, model.position_dtype)
                self._inputs = [wp.array(model.host_sticks[chosen].astype(np.int32), dtype=wp.vec2i),
                                wp.array(model.host_rest[chosen].astype(np.float32), dtype=float),
                                wp.array(entry[chosen], dtype=int),
                                wp.empty(0, dtype=float),  # the State's live weights where a cloth can tear
                                chunk]
                self._weight_at = 3
            self._first = (kernel, count)
            self._tears = model.tears
            levels = [(wp.empty(count, dtype=wp.float64), wp.empty(count, dtype=int))]
            while count > 1:
                count = -(-count // self.SUMS_PER_THREAD)
                levels.append((wp.empty(count, dtype=wp.float64), wp.empty(count, dtype=int)))
            self._levels = levels
            self._rms = wp.empty(1, dtype=wp.float64)
            self._host = wp.empty(1, dtype=wp.float64, device="cpu", pinned=device.is_cuda)
        self._event = None

    def launch(self, state: State) -> None:
        """Reduce ``state``'s stretch and start its copy to the host."""
        from warp_verlet.kernels.readback import finish_rms, sum_chunks

        kernel, count = self._first
        inputs = list(self._inputs)
        if self._weight_at is not None and self._tears:
            inputs[self._weight_at] = state.stick_weight
        with wp.ScopedDevice(self.device):
            wp.launch(kernel, count, inputs=[state.particle_q, *inputs], outputs=list(self._levels[0]))
            for (sums, counts), (out_sums, out_counts) in zip(self._levels, self._levels[1:]):
                wp.launch(sum_chunks, out_sums.shape[0], inputs=[sums, counts, self.SUMS_PER_THREAD],
                          outputs=[out_sums, out_counts])
            wp.launch(finish_rms, 1, inputs=list(self._levels[-1]), outputs=[self._rms])
            wp.copy(self._host, self._rms)
            self._event = wp.record_event() if self.device.is_cuda else None

    def read(self) -> float:
        """The last launched reduction's RMS (waits for it on CUDA, which a frame later costs nothing)."""
        if self._event is not None:
            wp.synchronize_event(self._event)
        return float(self._host.numpy()[0])


def build_model(scene: Scene, device, colouring: str = "auto", sticks: str = "auto", particle_order: str = "auto"):
    """The immutable Model of ``scene`` on ``device`` (a resolved Warp device), its memory need checked first:
    (model, the scene's Requirements, the MemoryNeed). The requirements are derived once, here: the memory check,
    the model and the solver all read them, and a scene that cannot fit is refused before any of it is
    allocated. ``colouring``, ``sticks`` and ``particle_order`` as for :class:`Simulator`."""
    from .model import stick_form

    form = stick_form(sticks, colouring, device)
    req = Requirements.of(scene, form)
    memory = check_fits(scene, str(device), device.free_memory if device.is_cuda else None, available_host_bytes(),
                        form, req)
    with wp.ScopedDevice(device):
        model = Model(scene, device, colouring, sticks, req, particle_order)
    return model, model.requirements, memory


class Simulator:
    """One scene on one device: the friendly driver over a :class:`Model`, one :class:`State` and a
    :class:`VerletSolver`.

    ``step(dt)`` runs one substep of any dt (time-step-corrected Verlet); ``step_frame()`` runs the scene's
    fixed substeps of one frame; ``advance(frame_time)`` is the real-time entry point with a clamped
    accumulator. ``state`` is everything that changes: ``state.clone()`` is a checkpoint, ``state.assign(c)``
    restores it, ``reset()`` goes back to the start.
    """

    def __init__(self, scene: Scene, device: str | None = None, colouring: str = "auto", use_graph: bool = True,
                 threads: int | None = None, sticks: str = "auto", particle_order: str = "auto"):
        """``sticks``: "auto" computes a grid cloth's sticks in the kernels on a GPU where the scene allows it
        (one grid cloth that cannot tear, the coloured solver: stages.implicit_grid_obstacle) and keeps stick
        arrays otherwise and on the CPU (model.stick_form says why), and sweeps float32 ones of a large grid, rigid
        or soft, tile by tile in shared memory (kernels/grid_tiles.py); "explicit" always keeps them; "implicit"
        insists on a launch per colour, in the explicit sticks' order and with their positions bit for bit;
        "tiled" insists on tiles; "clustered" sweeps stick arrays (a mesh's) cluster by cluster in shared memory
        (constraints/stick_clusters.py), which "auto" chooses for float32 stick arrays on a GPU from
        stages.MIN_CLUSTERED_PARTICLES on (``model.clusters_refused`` says why where their layout is refused).
        ``constraint_sets`` says what was chosen. ``particle_order``: "auto" holds a mesh cloth's particles in
        Morton order on the device where the scene's order scatters its sticks across memory, so that a launch
        reads memory forward (warp_verlet/geometry/particle_order.py); "morton" always does; "input" holds them as
        the scene numbers them. Either way every method here takes and gives particles in the scene's order: only
        the Gauss-Seidel order differs."""
        self.scene = scene
        self.settings = scene.simulation
        self.device = resolve_device(device)
        self.model, req, self.memory = build_model(scene, self.device, colouring, sticks, particle_order)
        self._sticks = self.model.stick_request
        with wp.ScopedDevice(self.device):
            self.state = State(self.model)
        # A frame's substeps are captured once and replayed: a CUDA graph, or on the CPU Warp's own capture
        # (replayed in C++, bit-identical, and faster: bench/results/code_choices.md); on CPU threads one graph a
        # thread, which meet at barriers in C++ (cpu_team.FrameTeam).
        self._use_graph = use_graph and all(
            kind.capturable(self.device) for kind in constraint_kinds() if kind.needed(req)) and all(
            kind.capturable(specs, self.device) for kind, specs in self.model.colliders.kinds
            if hasattr(kind, "capturable"))  # a collider kind may say its launches do not replay (a refit)
        self.solver = VerletSolver(self.model, self.settings, req, threads, frames_captured=self._use_graph)
        self.threads = self.solver.threads
        self.min_dt = self.solver.min_dt
        self.precision = self.model.precision  # "float32" or "float64": the scene's precision, "auto" resolved
        self._initial = None  # a clone of the start, made by the first reset()
        self._accumulator = 0.0
        self._first_diverged = None  # allocated by the first divergence check
        self._gather = None  # render_points: (the particles asked for, their device copy, the output)
        self._scene_order = None  # positions() of a renumbered cloth: (each scene particle's device index, output)
        self._stretch_arrays = None  # device_stretch: structural sticks and the sums, made at its first call
        self._frame_graphs: dict[int, object] = {}  # substeps -> the captured frame (a FrameTeam on CPU threads)
        self._replayer: FrameReplayer | None = None  # the threads that replay FrameTeams, started at the first replay
        self._substep_in_frame = 0  # substeps advance() has taken since the last frame boundary
        self.clamped_seconds = 0.0  # what the last advance() dropped from its bank (a stall)
        self.budget = self._new_budget()
        self._readback: StretchReadback | None = None  # the budget's stretch, reduced on the device
        self._pending_substeps: int | None = None  # a frame whose stretch is on its way to the host (CUDA)
        if self.dt < self.min_dt:
            raise WarpVerletError(self.solver.too_small(self.dt, scene_dt=True))

    def _new_budget(self) -> Budget | None:
        """The target_stretch budget at its start (None without a target), capped by the float32 floor."""
        if self.settings.target_stretch is None:
            return None
        floor = int(1.0 / (self.settings.fps * self.min_dt)) if self.min_dt > 0 else self.settings.max_substeps
        cap = max(1, min(self.settings.max_substeps, floor))
        return Budget(self.settings.target_stretch, self.settings.substeps, cap,
                      FLOAT32_FLOOR if floor < self.settings.max_substeps else MAX_SUBSTEPS,
                      min_substeps=min(self.settings.min_substeps, cap))

    @property
    def substeps(self) -> int:
        """Substeps of the next frame: the scene's, or what the target_stretch budget chose."""
        return self.budget.substeps if self.budget is not None else self.settings.substeps

    @property
    def dt(self) -> float:
        """The fixed step of the next frame, in seconds."""
        return 1.0 / (self.settings.fps * self.substeps)

    @property
    def time(self) -> float:
        """Simulated seconds."""
        return self.state.time

    @property
    def steps(self) -> int:
        """Substeps taken."""
        return self.state.steps

    @property
    def colliders(self):
        return self.model.colliders

    @property
    def replays_frames(self) -> bool:
        """Whether a whole frame is stepped by replaying its captured substeps (a CUDA graph, or Warp's CPU
        capture), rather than launch by launch from Python: what the scene, the device and the threads allow."""
        return self._use_graph

    def stages(self) -> list[tuple[str, Callable[[float], None]]]:
        """The stages of one substep, in order, as (name, run(dt)) on this simulator's state: only those the
        scene uses (the table in warp_verlet/core/stages.py). ``bench/throughput.py`` times them one by one."""
        state = self.state
        return [(name, lambda dt, run=run: run(state, dt)) for name, run in self.solver.bind(state)]

    @property
    def constraint_sets(self) -> tuple[str, ...]:
        """The constraint sets a sweep projects, in order (constraints.CONSTRAINT_KINDS): "grid sticks" and "grid
        tethers" where they are computed from the grid, "sticks" and "tethers" where they are arrays."""
        if "relax" not in self.solver.stage_names:
            return ()
        return tuple(c.name for c in constraint_kinds() if c.needed(self.solver.req))

    def reset(self) -> None:
        """Back to the state the simulator started from (rest positions, at rest, nothing torn)."""
        if self._initial is None:
            self._initial = State(self.model)
        self.state.assign(self._initial)
        self._accumulator = 0.0
        self._substep_in_frame = 0
        self.budget = self._new_budget()
        self._pending_substeps = None

    # ------------------------------------------------------------------ stepping
    def step(self, dt: float | None = None) -> None:
        """Advance by one substep of ``dt`` seconds (the scene's fixed dt by default)."""
        try:
            dt = self.dt if dt is None else float(dt)
        except (TypeError, ValueError):
            raise ArgumentError(f"dt must be a number of seconds, got {dt!r}") from None
        self.solver.check_step(self.state, dt)
        self._check_dt_fits(dt)
        self.solver.step(self.state, dt)

    def _check_dt_fits(self, dt: float) -> None:
        """Refuse a dt whose step cannot end inside ``position_bound``: the kernels square dt in float32, which
        overflows to inf past about 1.8e19 s, and a step whose gravity-and-wind move |a| dt^2 alone exceeds the
        bound has diverged before it starts (1e300 s left every position non-finite)."""
        bound = self.settings.position_bound
        float32_max = float(np.finfo(np.float32).max)
        if dt * dt <= float32_max and self.solver.accel_magnitude * dt * dt <= bound:
            return
        a = self.solver.accel_magnitude
        largest = min(np.sqrt(float32_max), np.sqrt(bound / a) if a > 0 else np.inf)
        raise ArgumentError(f"dt = {dt:.3g} s is too large: one step must keep |a| dt^2 = {a * dt * dt:.3g} m "
                            f"within simulation.position_bound = {bound:g} m and dt^2 within float32, so dt "
                            f"may be at most {largest:.3g} s here")

    def step_frame(self) -> None:
        """The scene's ``substeps`` fixed steps of one frame, replayed from a capture (a CUDA graph, or Warp's
        CPU capture) once the first frame (which initialises x_prev) has run, unless the CPU relaxation is
        threaded. With a target_stretch, the budget then chooses the next frame's substeps from this frame's
        stretch (one host copy of the positions per frame)."""
        if not self.at_frame_boundary:
            raise StateError("step_frame() runs whole frames, but advance() stopped mid-frame: finish_frame() first")
        n, dt, state = self.substeps, self.dt, self.state
        if state.dt_prev is not None:
            self.solver.check_step(state, dt)
        with wp.ScopedDevice(self.device):
            if not self._use_graph or state.dt_prev != dt:
                for _ in range(n):
                    self.solver.step(state, dt)
            else:
                if n not in self._frame_graphs:
                    self._frame_graphs[n] = self._capture_frame(n, dt)
                self.solver.before_replay(state)
                frame = self._frame_graphs[n]
                if isinstance(frame, FrameTeam):
                    if self._replayer is None:
                        self._replayer = FrameReplayer(self.threads)
                    self._replayer.run(frame)
                else:
                    wp.capture_launch(frame)
                state.time += n * dt
                state.steps += n
        self._end_frame()

    def _capture_frame(self, n: int, dt: float):
        """``n`` substeps of ``dt`` captured, not run: a graph, or on CPU threads a FrameTeam of one graph a thread
        (the calling thread's capture records member 0's work and every stage's own; the others' are recorded by
        the teams and captured after it)."""
        state = self.state
        time, steps = state.time, state.steps
        with self.solver.recording() if self.threads > 1 else nullcontext() as recording:
            with wp.ScopedCapture() as capture:
                for _ in range(n):
                    self.solver.step(state, dt)
        state.time, state.steps = time, steps  # capture recorded the work; it has not run yet
        if recording is None:
            return capture.graph
        return FrameTeam([capture.graph, *recording.member_graphs()], recording)

    def advance(self, frame_time: float, on_frame: Callable[[], bool | None] | None = None) -> float:
        """Real-time stepping: bank ``frame_time`` seconds, run as many fixed substeps as it pays for, and
        return the interpolation factor alpha in [0, 1) for :meth:`render_positions`.

        The bank is clamped to ``max_frame_time`` so that a stall (a debugger pause, a slow frame) cannot
        queue more substeps than the next frame can afford: the spiral of death. ``clamped_seconds`` says how
        much the last call dropped.

        ``on_frame()`` is called each time a frame's ``substeps`` substeps are complete (a frame is 1/fps
        simulated seconds, whatever the substeps); when it returns True, stepping stops there, at the frame
        boundary, and the rest of the bank waits for the next call (``advance(0.0)`` spends it): the moment to
        :meth:`retune` or record a frame."""
        if not (frame_time >= 0.0 and np.isfinite(frame_time)):
            raise ArgumentError(f"frame_time must be a finite number of seconds >= 0, got {frame_time}")
        banked = self._accumulator + frame_time
        self.clamped_seconds = max(banked - self.settings.max_frame_time, 0.0)
        self._accumulator = min(banked, self.settings.max_frame_time)
        dt = self.dt
        # The tiny epsilon keeps 1/60 s from paying for 3.9999999 substeps of 1/240 s instead of 4.
        while self._accumulator / dt + 1e-9 >= 1.0:
            n = self.substeps
            if self.at_frame_boundary and self._accumulator / (n * dt) + 1e-9 >= 1.0 and self._use_graph:
                self.step_frame()  # a whole frame banked: its capture replayed (bit-identical, one launch)
                self._accumulator = max(self._accumulator - n * dt, 0.0)
            else:
                self.solver.step(self.state, dt)
                self._accumulator = max(self._accumulator - dt, 0.0)
                self._substep_in_frame += 1
                if self._substep_in_frame < n:
                    continue
                self._end_frame()
            dt = self.dt  # a target_stretch budget may have chosen other substeps for the next frame
            if on_frame is not None and on_frame():
                break
        return self._accumulator / dt

    def finish_frame(self, on_frame: Callable[[], bool | None] | None = None) -> None:
        """Run substeps up to the next frame boundary (a whole frame when at one), outside real time: "step
        one frame" of a paused viewer. The bank is left as it is."""
        with wp.ScopedDevice(self.device):
            while True:
                self.step()
                self._substep_in_frame += 1
                if self._substep_in_frame == self.substeps:
                    break
        self._end_frame()
        if on_frame is not None:
            on_frame()

    @property
    def at_frame_boundary(self) -> bool:
        """Whether the substeps taken make whole frames (where :meth:`retune` may change them)."""
        return self._substep_in_frame == 0

    def _end_frame(self) -> None:
        """At a frame boundary: the budget observes a frame's stretch, reduced on the device. On CUDA it reads the
        previous frame's (whose copy has long arrived) and queues this one's, so the host never waits for the
        device; the budget ignores a late observation of a frame run at other substeps than it now chooses."""
        self._substep_in_frame = 0
        if self.budget is None:
            return
        if self._readback is None:
            self._readback = StretchReadback(self.model, self.device)
        ran = self.substeps
        if self.device.is_cpu:
            self._readback.launch(self.state)
            self.budget.observe(self._readback.read(), ran)
            return
        self.settle_budget()
        self._readback.launch(self.state)
        self._pending_substeps = ran

    def settle_budget(self) -> None:
        """Let the budget observe the last frame's stretch now, where it waits to be read a frame late (CUDA): a
        run's summary calls it before reporting what the budget chose."""
        if self._pending_substeps is not None and self.budget is not None:
            self.budget.observe(self._readback.read(), self._pending_substeps)
        self._pending_substeps = None

    def retune(self, **changes) -> None:
        """Change simulation settings that the model does not hold (gravity, wind, damping, substeps,
        iterations, target_stretch, ...) from the next substep on: a new solver over the same model and state.
        Only at a frame boundary, so every frame stays ``substeps`` equal steps of 1/fps seconds. Settings
        that need another model (another precision) raise ArgumentError: build a new Simulator then
        (:meth:`take_state`)."""
        if not self.at_frame_boundary:
            raise StateError("retune() changes the substeps of whole frames: call it at a frame boundary "
                             "(advance()'s on_frame, or after finish_frame())")
        settings = replace(self.settings, **changes)
        scene = replace(self.scene, simulation=settings)
        req = Requirements.of(scene, self._sticks)
        if req.precision != self.model.precision:
            raise ArgumentError(f"these settings need {req.precision} positions and this model holds "
                                f"{self.model.precision}: build a new Simulator")
        solver = VerletSolver(self.model, settings, req, self.threads if self.device.is_cpu else None,
                              frames_captured=self._use_graph)
        if 1.0 / (settings.fps * settings.substeps) < solver.min_dt:
            raise WarpVerletError(solver.too_small(1.0 / (settings.fps * settings.substeps), scene_dt=True))
        self.solver.close()
        self.scene, self.settings, self.solver = scene, settings, solver
        self.min_dt = solver.min_dt
        self._drop_frames()  # they replay the old solver's launches
        if changes.keys() & {"target_stretch", "substeps", "max_substeps", "min_substeps"}:
            self.settle_budget()
            self.budget = self._new_budget()

    def take_state(self, other: "Simulator") -> None:
        """Continue from ``other``'s state: a simulator of an edited scene with the same particles (a pin released,
        another tear threshold) picks up the positions, velocities, time, tears and sphere centres where
        ``other`` left them, at a frame boundary."""
        if other.model.particle_count != self.model.particle_count:
            raise ArgumentError(f"take_state needs the same particles: {other.model.particle_count} there, "
                                f"{self.model.particle_count} here")
        if not other.at_frame_boundary:
            raise StateError("take_state() continues from a frame boundary; the other simulator is mid-frame")
        mine, theirs = self.state, other.state
        for name in ("particle_q", "particle_q_inertial", "particle_dq"):  # through the scene's order
            values = other.model.to_scene_order(getattr(theirs, name).numpy())
            getattr(mine, name).assign(self.model.to_device_order(values).astype(self.model.host_position_dtype))
        for name in mine.collider_array_names:  # each collider kind's moving part (sphere centres, the clock)
            if getattr(theirs, name, None) is not None and getattr(mine, name) is not None:
                wp.copy(getattr(mine, name), getattr(theirs, name))
        if self.model.tears and other.model.tears and other.torn_count():
            self.model.restore_tears(mine, other.model.scene_particles(other.model.host_sticks[other.torn_sticks()]))
            self.sync_tears()
        mine.time, mine.steps, mine.dt_prev = theirs.time, theirs.steps, theirs.dt_prev
        mine.start_velocity = None if theirs.start_velocity is None else self.model.to_device_order(
            other.model.to_scene_order(theirs.start_velocity)).astype(self.model.host_position_dtype)
        self._accumulator = other._accumulator

    # ------------------------------------------------------------------ reading state
    def positions(self) -> np.ndarray:
        """All particle positions in the scene's order, (particle_count, 3) float32 (float64 where
        ``model.precision`` is): a snapshot on the host (``state.positions()``, gathered on the device where the
        Model renumbered a cloth: a host gather of a million points costs tens of milliseconds a frame)."""
        if self.model.device_particle is None:
            return self.state.positions()
        from warp_verlet.kernels.positions import instance
        from warp_verlet.kernels.readback import gather_positions

        if self._scene_order is None:
            with wp.ScopedDevice(self.device):
                self._scene_order = (wp.array(self.model.device_particle, dtype=int),
                                     wp.empty(self.model.particle_count, dtype=self.model.position_dtype))
        index, out = self._scene_order
        wp.launch(instance(gather_positions, self.model.position_dtype), len(index), device=self.device,
                  inputs=[self.state.particle_q, index], outputs=[out])
        return out.numpy().copy() if self.device.is_cpu else out.numpy()

    def previous_positions(self) -> np.ndarray:
        """Positions at the end of the previous substep (x_prev of the textbook form)."""
        return self.state.previous_positions()

    def render_positions(self, alpha: float) -> np.ndarray:
        """Positions interpolated between the last two substeps: x_prev + alpha (x - x_prev)."""
        x = self.positions()
        if self.state.dt_prev is None:  # before the first step (or after set_velocity) there is no last substep
            return x
        x_prev = self.previous_positions()
        return x_prev + x.dtype.type(alpha) * (x - x_prev)

    def render_points(self, particles: np.ndarray, alpha: float) -> np.ndarray:
        """``render_positions(alpha)[particles]`` as float32 (K, 3), gathered on the device, so that only the K
        points cross to the host (a viewer drawing a 1024 x 1024 cloth as 256 x 256 copies 0.8 MB, not 36 MB).
        ``particles`` (scene indices) is uploaded once and reused while the same array is passed."""
        from warp_verlet.kernels.positions import instance
        from warp_verlet.kernels.readback import gather_drawn

        if self._gather is None or self._gather[0] is not particles:
            with wp.ScopedDevice(self.device):
                on_device = self.model.device_particles(np.asarray(particles, np.int32)).astype(np.int32)
                self._gather = (particles, wp.array(on_device, dtype=int),
                                wp.empty(len(particles), dtype=wp.vec3f))
        _, index, out = self._gather
        q = self.state
        alpha = 1.0 if q.dt_prev is None else float(alpha)  # no last substep yet: the positions themselves
        wp.launch(instance(gather_drawn, self.model.position_dtype), len(index), device=self.device,
                  inputs=[q.particle_q, q.particle_q_inertial, q.particle_dq, index, alpha], outputs=[out])
        return out.numpy().copy() if self.device.is_cpu else out.numpy()

    def device_stretch(self) -> StretchStats:
        """:meth:`stretch`, reduced on the device: three numbers come back instead of every position, for a
        viewer's readout. Its sum's order (and so the RMS's last bits) may vary between runs on a GPU, so the
        budget and the run summary use :meth:`stretch`."""
        from warp_verlet.kernels.positions import instance
        from warp_verlet.kernels.readback import structural_stretch

        m = self.model
        with wp.ScopedDevice(self.device):
            if self._stretch_arrays is None:
                chosen = np.flatnonzero(m.structural)
                entry = np.zeros(m.stick_count, np.int32)
                if m.tears:  # the weight entry that says whether a stick is torn (either of a Jacobi stick's two)
                    entry[m._tear_entry_stick] = np.arange(len(m._tear_entry_stick), dtype=np.int32)
                self._stretch_arrays = (wp.array(m.host_sticks[chosen].astype(np.int32), dtype=wp.vec2i),
                                        wp.array(m.host_rest[chosen].astype(np.float32), dtype=float),
                                        wp.array(entry[chosen], dtype=int), wp.zeros(1, dtype=wp.float64),
                                        wp.zeros(1, dtype=float), wp.zeros(1, dtype=int))
            ends, rest, entry, sum_squares, largest, count = self._stretch_arrays
            weight = self.state.stick_weight if m.tears else wp.empty(0, dtype=float)
            for a in (sum_squares, largest, count):
                a.zero_()
            wp.launch(instance(structural_stretch, m.position_dtype), len(ends),
                      inputs=[self.state.particle_q, ends, rest, entry, weight], outputs=[sum_squares, largest, count])
            n = int(count.numpy()[0])
        if n == 0:
            return StretchStats(0.0, 0.0)
        return StretchStats(float(largest.numpy()[0]), float(np.sqrt(sum_squares.numpy()[0] / n)))

    def diverged_particle(self) -> int | None:
        """The scene index of a particle that is not finite or beyond ``position_bound`` (the lowest such on the
        device), or None. Checked on the device; the host reads back one integer, so it is cheap enough to ask
        once per frame."""
        n = self.model.particle_count
        with wp.ScopedDevice(self.device):
            if self._first_diverged is None:
                self._first_diverged = wp.empty(1, dtype=int)
            self._first_diverged.fill_(n)
            wp.launch(find_diverged, n, inputs=[self.state.particle_q, self.settings.position_bound],
                      outputs=[self._first_diverged])
            first = int(self._first_diverged.numpy()[0])
        return None if first == n else int(self.model.scene_particles(first))

    def torn_count(self) -> int:
        """Sticks torn so far: one integer copied from the device, so it is cheap to ask every frame."""
        if not self.model.tears:
            return 0
        return int(self.state.torn_entries.numpy()[0]) // self.model.tear_entries_per_stick

    def torn_sticks(self) -> np.ndarray:
        """Which sticks are torn, a bool per stick in ``model.host_sticks`` order (all False without tearing)."""
        if not self.model.tears:
            return np.zeros(self.model.stick_count, bool)
        return self.model.torn_sticks(self.state.stick_weight.numpy())

    def sync_tears(self) -> np.ndarray:
        """Let the constraint sets react to the sticks torn so far (tethers cut off from their pin are
        dropped), and return which sticks are torn. Call it when ``torn_count()`` has changed; the runner does,
        once per frame."""
        torn = self.torn_sticks()
        for constraint_set in constraint_kinds():
            if constraint_set.needed(self.solver.req):
                constraint_set.on_tear(self.model, self.state, torn)
        return torn

    def stretch(self, points: np.ndarray | None = None) -> StretchStats:
        """Stretch over the structural sticks that are not torn."""
        points = self.positions() if points is None else points
        torn = self.torn_sticks() if self.model.tears else None
        return StretchStats.of(self.model.structural_stretch(points, torn))

    def close(self) -> None:
        """Stop the CPU relaxation threads now (they also stop when the simulator is collected)."""
        self._drop_frames()
        self.solver.close()

    def _drop_frames(self) -> None:
        """Forget the captured frames, and stop the threads that replay them on the CPU."""
        self._frame_graphs.clear()
        if self._replayer is not None:
            self._replayer.close()
            self._replayer = None
