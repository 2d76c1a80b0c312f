"""Spread the relaxation over CPU cores.

Warp runs a CPU kernel launch on one core. The sticks of one colour share no particle, so a colour's launch
can be cut into T contiguous pieces that T threads launch at once: Warp releases the GIL while a CPU kernel
runs, so the pieces run in parallel. The colours still run one after the other (a barrier between them), so
every particle sees its sticks in the same order as with one thread, and the result is bit-for-bit the same
whatever T is. Jacobi is cut by particle instead (each thread gathers for its own particles).

The cost is one barrier per colour, about 30 us with Python threads on the 2-core development machine: at
64^2 (about 1 000 sticks per thread per colour) that made a sweep 2.5x slower, at 256^2 (16 000) 1.5x
faster, at 512^2 1.8x. ``auto_threads`` therefore only threads when each thread gets at least
``MIN_WORK_PER_THREAD`` items per phase.
"""

from __future__ import annotations

import os
import threading
import weakref
from typing import Callable, Sequence

from .errors import WarpVerletError

MIN_WORK_PER_THREAD = 4096
"""Fewest items (sticks of a colour, or particles for Jacobi) per thread and phase worth a barrier."""


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def auto_threads(phase_sizes: Sequence[int], cores: int | None = None) -> int:
    """How many threads pay off for phases of these sizes: as many as the cores, but no more than leave
    ``MIN_WORK_PER_THREAD`` items of the average phase to each."""
    cores = usable_cores() if cores is None else cores
    if not phase_sizes:
        return 1
    average = sum(phase_sizes) / len(phase_sizes)
    return int(max(1, min(cores, average // MIN_WORK_PER_THREAD)))


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


class PhaseTeam:
    """T threads that run ``repeats`` passes over ``phases``, with a barrier after every phase.

    ``phases[p][t]`` is thread t's work in phase p (a callable, or None for nothing). The calling thread is
    member 0, so T - 1 worker threads are started; they sleep on the barrier between runs. An exception in
    any member stops the team and is raised by ``run``; a stopped team refuses to run again.
    """

    def __init__(self, phases: Sequence[Sequence[Callable[[], None] | None]], repeats: int):
        self.threads = len(phases[0]) if phases else 1
        if any(len(phase) != self.threads for phase in phases):
            raise ValueError("every phase needs one entry per thread")
        self._phases = [list(phase) for phase in phases]
        self._repeats = int(repeats)
        self._barrier = threading.Barrier(self.threads)
        self._state = {"error": None, "closed": False}
        self._workers = [
            threading.Thread(target=PhaseTeam._serve, args=(self._barrier, self._state, self._work_of(t)),
                             name=f"warp-verlet-relax-{t}", daemon=True)
            for t in range(1, self.threads)
        ]
        for worker in self._workers:
            worker.start()
        # The workers hold only the barrier, the state and their work, not the team, so the team can be
        # collected; collecting it (or interpreter exit) releases them.
        self._finalizer = weakref.finalize(self, PhaseTeam._release, self._barrier, self._state)

    def _work_of(self, member: int) -> Callable[[], None]:
        tasks = [phase[member] for phase in self._phases]
        barrier, repeats = self._barrier, self._repeats

        def work() -> None:
            for _ in range(repeats):
                for task in tasks:
                    if task is not None:
                        task()
                    barrier.wait()

        return work

    @staticmethod
    def _serve(barrier: threading.Barrier, state: dict, work: Callable[[], None]) -> None:
        while True:
            try:
                barrier.wait()  # the start of a run, or the release at close
                if state["closed"]:
                    return
                work()
            except threading.BrokenBarrierError:
                return
            except BaseException as exc:  # hand it to run(), and stop the others
                state["error"] = exc
                barrier.abort()
                return

    @staticmethod
    def _release(barrier: threading.Barrier, state: dict) -> None:
        state["closed"] = True
        barrier.abort()

    def run(self) -> None:
        """One run: every member does its work of every phase, ``repeats`` times; returns when all are done."""
        if self._state["closed"] or self._barrier.broken:
            raise WarpVerletError("the CPU relaxation threads stopped after an earlier error") from self._state["error"]
        work = self._work_of(0)
        try:
            self._barrier.wait()
            work()
        except threading.BrokenBarrierError:
            self._state["closed"] = True
            error = self._state["error"]
            raise (error if error is not None else WarpVerletError("the CPU relaxation threads stopped")) from None
        except BaseException:  # Ctrl-C or an error in member 0: free the workers before leaving
            self._release(self._barrier, self._state)
            raise

    def close(self) -> None:
        """Stop the worker threads (also done when the team is collected)."""
        self._finalizer()
