"""The pieces every stage and constraint kind binds its launches with: a recorded launch (a PhaseTask), the
work a stage does against one State (a BoundStage), and the byte sizes their memory declarations count in.

Kept apart from the table of stages (warp_verlet/core/stages.py), so that the constraint kinds
(warp_verlet/constraints/) and the collider kinds can bind launches without importing the table that lists
them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

VEC3, FLOAT, INT, VEC2I, FLOAT64 = 12, 4, 4, 8, 8
VEC3D = 24  # a float64 position


@dataclass(frozen=True)
class PhaseTask:
    """One launch of a phase, named by its kernel (or "copy" / "zero" for a memory operation)."""

    kernel: str
    run: Callable[[], None]
    launch: object = None  # the recorded wp.Launch, whose parameters (dt) can be updated in place


@dataclass
class BoundStage:
    """A stage's work against one State: ``run(state, dt)`` does it (the closures hold that state's arrays,
    never the State itself, so a solver's cache does not keep a dropped state alive); ``phases`` (constraint
    sets only) are the per-thread tasks of one sweep, phase after phase, which the CPU thread team may run
    instead; ``substep_phases`` (constraint sets only) are per-thread tasks that run once a substep, after ``run``
    and before the first sweep (a set's per-substep work that divides over threads, such as a search);
    ``before_replay()``, where given, must run before each replay of a captured frame (host state that the
    capture's work reads at replay, such as Warp's hash-grid descriptor)."""

    run: Callable[[Any, float], None] | None  # (a State, dt)
    phases: list[list[PhaseTask | None]] | None = None
    before_replay: Callable[[], None] | None = None
    substep_phases: list[list[PhaseTask | None]] | None = None


def recorded(kernel, dim: int, inputs: list, outputs: list | None = None, block_dim: int = 256) -> PhaseTask:
    """A launch recorded once (replaying it skips ``wp.launch``'s argument packing, which dominates small
    grids on the CPU: bench/results/code_choices.md), as a PhaseTask."""
    import warp as wp

    launch = wp.launch(kernel, dim, inputs=inputs, outputs=outputs or [], record_cmd=True, block_dim=block_dim)
    return PhaseTask(kernel.key, launch.launch, launch)


def elements_per_thread(count: int, device) -> int:
    """How many of a launch's ``count`` independent elements (a colour's piece) each thread takes, in order: one
    on a GPU; on the CPU, where Warp runs a launch's threads one after another, all of them, so that one loop
    inside the kernel runs the piece with its arguments and indices kept in registers (kernels/relax.py)."""
    return max(count, 1) if device.is_cpu else 1


def split_tasks(make: Callable[[int, int], PhaseTask], first: int, count: int, threads: int) -> list[PhaseTask | None]:
    """``count`` items from ``first`` cut into one piece per thread (None for an empty piece)."""
    return [make(f, n) if n else None for f, n in split(first, count, threads)]


# ---------------------------------------------------------------------------------------------- stages
def start_compliant_substep(launches: list, tension, zero: bool = True) -> Callable[[Any, float], None]:
    """A BoundStage's prepare for soft (XPBD) sticks: each substep gives ``launches`` its 1 / dt^2 and restarts the
    tension from zero (unless ``zero`` is False: an earlier stage has started it)."""
    def prepare(state, dt: float) -> None:
        inv_dt2 = 1.0 / (dt * dt)
        for launch in launches:
            launch.set_param_by_name("inv_dt2", inv_dt2)
        if zero:
            tension.zero_()

    return prepare


def split(first: int, count: int, parts: int) -> list[tuple[int, int]]:
    """``count`` items from ``first`` cut into ``parts`` contiguous (first, count) pieces, sizes differing by at
    most one; empty pieces are kept so that piece t always belongs to thread t."""
    base, extra = divmod(count, parts)
    pieces, start = [], first
    for t in range(parts):
        size = base + (1 if t < extra else 0)
        pieces.append((start, size))
        start += size
    return pieces


def noted_pushes(model, solver, owner: str):
    """The vec3 per particle that ``owner``'s clamps add their pushes to (clamp_noting_normals), from the solver's
    scratch; an empty array where no collider has friction, which the clamps do not write."""
    import warp as wp

    if not model.requirements.collider_friction:
        return wp.empty(0, dtype=wp.vec3, device=model.device)
    return solver.scratch(f"{owner}_pushes", model.particle_count, wp.vec3)


def clamp_noting_normals(x, clamps: list, snapshot, normal, pushes) -> list[PhaseTask]:
    """The colliders' ``clamps`` of the positions ``x``, between a copy of ``x`` into ``snapshot`` and the direction
    each particle was pushed into ``normal`` (0 where none was): the contact normals of a stage that works on the
    clamped prediction (the global correction, the line solves). Without friction a particle's move is its push.
    Friction shortens a sliding particle's move along the surface, which tilts the move off the normal by up to
    atan(mu) (into the collider, for a stage that lets the particle slide along the normal's plane), so where a
    collider has friction the clamps are bound with ``pushes`` (a vec3 per particle, else an empty array) and add
    each push to it, and the normal is theirs. Kernels only: a CPU frame capture replays kernels, not copies."""
    from warp_verlet.kernels.global_solve import contact_normals, copy_positions, zero_vectors

    n = x.shape[0]
    zero = [recorded(zero_vectors, n, [], [pushes])] if pushes.shape[0] else []
    return [recorded(copy_positions, n, [x], [snapshot]), *zero, *clamps,
            recorded(contact_normals, n, [x, snapshot, pushes], [normal])]


def copy_back_phase(x, scratch, count: int, threads: int) -> list[PhaseTask | None]:
    """The phase that ends a Jacobi gather: ``scratch``'s first ``count`` positions copied over ``x``, cut into one
    piece per thread. The tasks hold the arrays, not a solver: worker threads keep their tasks alive, and must not
    keep a solver alive."""
    import warp as wp

    def copy_back(f, n):
        return PhaseTask("copy", lambda: wp.copy(x, scratch, dest_offset=f, src_offset=f, count=n))

    return split_tasks(copy_back, 0, count, threads)
