"""The Verlet solver: steps a State by dt with the stages of the table (warp_verlet/core/stages.py).

A solver holds no simulation data of its own. It keeps, per State it has stepped, the launches recorded
against that state's arrays (a cache, rebuilt for a new state), and scratch buffers that no step carries
over to the next (Jacobi's new positions, XPBD tensions). So one solver can step any number of states of its
model: a checkpoint and its clone give the same result.
"""

from __future__ import annotations

import weakref
from contextlib import contextmanager
from typing import Callable, Iterator

import numpy as np
import warp as wp

from warp_verlet.kernels.integrate import verlet_start

from .cpu_team import (COLOURED_SECONDS_PER_STICK, JACOBI_SECONDS_PER_ENTRY, MAX_THREADS, PhaseTeam, TeamRecording,
                       auto_threads)
from ..errors import ArgumentError, WarpVerletError
from .model import Model
from .precision import RESOLVED_SPACINGS, acceleration, smallest_dt, spacing_at
from ..input.scene import SimulationSettings
from ..launches import PhaseTask
from .stages import STAGES, Requirements
from .state import State


class VerletSolver:
    """Verlet integration with graph-coloured (or Jacobi) relaxation, collider clamping and tearing.

    ``req`` (stages.Requirements) says which stages run; ``threads`` is the CPU relaxation's thread count (None:
    chosen from the cores and the work per colour, and from what a phase costs each thread: less where the caller
    replays ``frames_captured``, cpu_team.auto_threads; CUDA always 1).
    """

    def __init__(self, model: Model, settings: SimulationSettings, req: Requirements, threads: int | None = None,
                 frames_captured: bool = False):
        self.model, self.settings, self.req = model, settings, req
        if req.precision != model.precision:
            raise ArgumentError(f"req.precision = {req.precision!r} but the model's positions are {model.precision}")
        self.precision = model.precision
        implicit_tethers = hasattr(model, "grid_tethers")
        if req.implicit_grid != (model.sticks_form in ("implicit", "tiled")) or bool(req.grid_pins) != implicit_tethers:
            raise ArgumentError(f"need (implicit sticks {req.implicit_grid}, implicit tethers {bool(req.grid_pins)}) "
                                f"does not match the model's {model.sticks_form} sticks: ask Requirements.of with the model's "
                                "stick_request")
        accel = np.add(settings.gravity, settings.wind)
        self.accel = model.position_dtype(*accel)  # in the positions' type, as every factor of the step
        self.accel_magnitude = acceleration(settings)
        self.threads = self._thread_count(threads, frames_captured)
        self.stage_names = tuple(s.name for s in STAGES if s.needed(req))
        self._scratch: dict[str, wp.array] = {}
        self._bound: weakref.WeakKeyDictionary[State, list] = weakref.WeakKeyDictionary()
        # Held weakly: a team belongs to the launches bound for one state (the relaxation stage holds it), so a
        # dropped state's team is collected and its worker threads stop (PhaseTeam's finalizer).
        self._teams: weakref.WeakSet[PhaseTeam] = weakref.WeakSet()
        self._recording: TeamRecording | None = None  # set while a frame on CPU threads is captured
        self.min_dt = self._smallest_resolved_dt()

    # ------------------------------------------------------------------ set-up
    def _thread_count(self, threads: int | None, frames_captured: bool) -> int:
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or not 1 <= threads <= MAX_THREADS):
            raise ArgumentError(f"threads must be a whole number in 1 .. {MAX_THREADS}, got {threads!r}")
        device = self.model.device
        if device.is_cuda:
            if threads not in (None, 1):
                raise WarpVerletError(f"threads = {threads} applies to the CPU only; on {device} the "
                                      "relaxation runs in parallel on the device")
            return 1
        if threads is not None:
            return threads
        m = self.model
        if self.settings.relaxation == "coloured":
            phase = m.stick_count / max(m.colour_count, 1) * COLOURED_SECONDS_PER_STICK
        else:
            phase = m.stick_count * JACOBI_SECONDS_PER_ENTRY  # two entries per stick over two phases per sweep
        return auto_threads(phase, captured=frames_captured)

    def scratch(self, name: str, count: int, dtype) -> wp.array:
        """A buffer that no step carries over to the next, shared by every state this solver steps."""
        if name not in self._scratch:
            self._scratch[name] = wp.empty(count, dtype=dtype, device=self.model.device)
        return self._scratch[name]

    def cached(self, name: str, make: Callable[[], object]) -> object:
        """A stage's working set that no step carries over to the next (made once by ``make``), shared by every
        state this solver steps, like :meth:`scratch`."""
        if name not in self._scratch:
            self._scratch[name] = make()
        return self._scratch[name]

    def team(self, phases: list[list[PhaseTask | None]], repeats: int | None = None) -> PhaseTeam | None:
        """A CPU thread team for a stage's phases (the relaxation's sweeps, the colliders' clamps), run ``repeats``
        times (None: once a sweep), or None when it runs on one thread."""
        if self.threads <= 1 or not phases:
            return None
        team = PhaseTeam([[t.run if t is not None else None for t in phase] for phase in phases],
                         self.settings.iterations if repeats is None else repeats)
        team.recording = self._recording
        self._teams.add(team)
        return team

    @contextmanager
    def recording(self) -> Iterator[TeamRecording]:
        """While a frame is captured on CPU threads: every team's run records its members' work
        (cpu_team.TeamRecording), member 0's issued into the capture around it."""
        self._recording = TeamRecording(self.threads)
        teams = list(self._teams)
        for team in teams:
            team.recording = self._recording
        try:
            yield self._recording
        finally:
            for team in teams + list(self._teams):
                team.recording = None
            self._recording = None

    def bind(self, state: State) -> list[tuple[str, Callable[[State, float], None]]]:
        """The stages of one substep against ``state``'s arrays, as (name, run(state, dt)), recorded once per
        state."""
        if state.model is not self.model:
            raise ArgumentError("this solver steps states of its own model only")
        if state not in self._bound:
            with wp.ScopedDevice(self.model.device):
                self._bound[state] = [(s.name, s.bind(self.model, state, self)) for s in STAGES if s.needed(self.req)]
        return [(name, bound.run) for name, bound in self._bound[state]]

    def before_replay(self, state: State) -> None:
        """What the stages bound to ``state`` need done on the host before a captured frame of it replays."""
        for _, bound in self._bound.get(state, ()):
            if bound.before_replay is not None:
                bound.before_replay()

    # ------------------------------------------------------------------ limits
    def _smallest_resolved_dt(self) -> float:
        """The smallest dt whose gravity-and-wind step |a| dt^2 is at least 4 spacings, in the positions'
        precision, of the scene's coordinates (warp_verlet/core/precision.py says why): about 2e-4 s for a 1 m scene
        in float32, 1e-8 s in float64. Without relaxation there is no limit."""
        if "relax" not in self.stage_names:
            return 0.0
        return smallest_dt(self.precision, self.accel_magnitude, self._coordinate_scale())

    def _coordinate_scale(self) -> float:
        """The scene's largest |rest coordinate|, m (1 without particles): what the positions' float spacing is
        taken at."""
        m = self.model
        return float(np.abs(m.rest_positions).max()) if m.particle_count else 1.0

    def check_step(self, state: State, dt: float) -> None:
        """Raise one clear error for a dt this solver cannot take from ``state``."""
        if not (dt > 0.0 and np.isfinite(dt)):
            raise ArgumentError(f"dt must be a positive finite number of seconds, got {dt}")
        if dt < self.min_dt:
            raise WarpVerletError(self.too_small(dt))
        if "relax" in self.stage_names and state.dt_prev is not None and dt * self.settings.max_dt_ratio < state.dt_prev:
            # The relaxation leaves a residual stretch after each step; a much shorter step removes it within
            # that step, and Verlet turns the move into velocity residual / dt: energy from nowhere (a drop
            # from 1/240 s to 1e-5 s gave a hanging cloth 10x the kinetic energy gravity had released).
            # Without relaxation there is no residual, and any sequence of steps is exact (test_integrate).
            raise WarpVerletError(
                f"dt fell from {state.dt_prev:.3g} s to {dt:.3g} s in one step; a step may shrink by at most a "
                f"factor max_dt_ratio = {self.settings.max_dt_ratio:g} (shrink it over several steps), or the "
                "relaxation's residual stretch would turn into spurious velocity")

    def too_small(self, dt: float, scene_dt: bool = False) -> str:
        """The error for a dt below ``min_dt``, with what lifts it (``scene_dt``: the scene's own fixed dt)."""
        p = self.precision
        frame_dt = 1.0 / self.settings.fps
        if frame_dt < self.min_dt:
            # No substep count lifts it: the acceleration itself is too weak to resolve at this frame rate.
            weakest = RESOLVED_SPACINGS * spacing_at(p, self._coordinate_scale()) / frame_dt ** 2
            remedies = [f"even one substep a frame is too short: gravity and wind add up to |a| = "
                        f"{self.accel_magnitude:.3g} m/s^2, which at {self.settings.fps:g} fps and {p} positions "
                        f"must be 0 or at least {weakest:.2g} m/s^2; set simulation.gravity and simulation.wind to "
                        "0 if the cloth should not accelerate"]
        else:
            remedies = ["raise it with fewer simulation.substeps"] if scene_dt else []
        if p == "float32":
            remedies.append('set simulation.precision = "float64", which lowers this limit to about 1e-8 s for a '
                            "1 m scene")
        return (f"dt = {dt:.3g} s is too small for {p} positions: one step's acceleration moves a particle by "
                f"|a| dt^2 = {self.accel_magnitude * dt * dt:.2g} m, "
                f"under 4 {p} spacings of this scene's coordinates, so the relaxation's rounding would cancel "
                f"it; the smallest dt resolved here is {self.min_dt:.3g} s"
                + (f" ({'; or '.join(remedies)})" if remedies else ""))

    # ------------------------------------------------------------------ stepping
    def step(self, state: State, dt: float) -> None:
        """Advance ``state`` by one substep of ``dt`` seconds (no checks: see :meth:`check_step`). Issues only
        device work, so a sequence of steps can be captured and replayed."""
        stages = self.bind(state)
        with wp.ScopedDevice(self.model.device):
            if state.dt_prev is None:
                # Exact start for constant acceleration: x_prev = x0 - v0 dt + a dt^2 / 2. The start reads v0 from the
                # increment's array, which it overwrites with the increment (never captured: it runs once).
                if state.start_velocity is not None:
                    state.particle_dq.assign(state.start_velocity)
                    state.start_velocity = None
                wp.launch(verlet_start, self.model.particle_count,
                          inputs=[state.particle_q, self.model.inv_mass, self.accel, self.model.position_scalar(dt)],
                          outputs=[state.particle_q_inertial, state.particle_dq])
                state.dt_prev = dt
            for _, run in stages:
                run(state, dt)
        state.dt_prev = dt
        state.time += dt
        state.steps += 1

    def close(self) -> None:
        """Stop the CPU thread teams (also done when the solver is collected)."""
        for team in list(self._teams):
            team.close()
