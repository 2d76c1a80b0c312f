"""Spread the relaxation over CPU cores.

Warp runs a CPU kernel launch on one core. The sticks of one colour share no particle, so a colour's launch
can be cut into T contiguous pieces that T threads launch at once: Warp releases the GIL while a CPU kernel
runs, so the pieces run in parallel. The colours still run one after the other (a barrier between them), so
every particle sees its sticks in the same order as with one thread, and the result is bit-for-bit the same
whatever T is. Jacobi is cut by particle instead (each thread gathers, then copies back, its own particles).

Each thread pays a fixed cost per phase (its Python launch, under the GIL, and its share of the barrier),
so a phase of one-thread time W is fastest on about sqrt(W / LAUNCH_COST_S) threads (W / T + T x cost is
least there). ``auto_threads`` picks that, capped by the cores and MAX_AUTO_THREADS.

Measured (bench/thread_scaling.py, hanging cloth 4 x 8, coloured): on the 2-core development EPYC 64^2
ran 3x slower on 2 threads, 128^2 1.15x slower, 256^2 1.45x faster and 512^2 1.8x; on a 16-core Xeon
128^2 gained 1.1x at best (2 threads), 256^2 2.1x (4 threads) and 1024^2 5.5x on 8 threads
(bench/results/xeon16).

A whole frame of fixed substeps is captured instead (``TeamRecording``, ``FrameTeam``; Simulator.step_frame): one
graph a thread, in which each phase's piece is followed by a barrier kernel that waits in C++
(kernels/team_barrier.py), and each thread replays its own graph. A frame then costs one Python hand-off per
thread instead of one per thread and phase, and the positions are still those of one thread, bit for bit.
"""

from __future__ import annotations

import math
import os
import threading
import weakref
from typing import Callable, Sequence

from warp_verlet.errors import ArgumentError, WarpVerletError

LAUNCH_COST_S = 13e-6
"""Fixed cost per thread and phase. With it, a 128^2 colour stays on one thread (two were slower on a 2-core
machine) and a 256^2 colour is cut over a few (bench/results/code_choices.md)."""

CAPTURED_PHASE_COST_S = 4e-6
"""The same cost where a frame is captured, one graph a thread meeting at barriers in C++ (``FrameTeam``). The
barrier alone costs 1.4-1.6 us a phase on two threads of the 2-core EPYC; 4 us keeps a 64^2 cloth on one thread
there, where a run's cache is written beside the relaxation and two threads made the whole run slower, and gives
a 128^2 one two, which ran it 1.7x faster (bench/results/cpu_threads/captured/README.md)."""

MAX_AUTO_THREADS = 8
"""The barrier's cost grows with the thread count, and past 8 threads the speed-up stopped being repeatable
from run to run (bench/results/code_choices.md), so automatic stops at 8."""

MAX_THREADS = 1024
"""The most relaxation threads anyone may ask for. Each is an OS thread that meets the others at a barrier
after every colour, so more threads than cores only waits (1000 threads on 2 cores ran 7,000x slower), and
some 10^4 to 10^5 threads exhaust what a process may start."""

COLOURED_SECONDS_PER_STICK = 6.3e-9
"""One thread's time per coloured stick projection (6.2-6.4 ns on both machines above)."""

JACOBI_SECONDS_PER_ENTRY = 4.8e-9
"""One thread's time per Jacobi gather entry (two per stick), copy back included."""


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def auto_threads(phase_seconds: float, cores: int | None = None, captured: bool = False) -> int:
    """Threads for phases that take ``phase_seconds`` on one thread: sqrt(phase_seconds / cost) rounded down (when
    in doubt, fewer), at least 1, at most the cores and MAX_AUTO_THREADS; the cost is LAUNCH_COST_S, or
    CAPTURED_PHASE_COST_S where the frames are ``captured``."""
    cores = usable_cores() if cores is None else cores
    cost = CAPTURED_PHASE_COST_S if captured else LAUNCH_COST_S
    best = math.floor(math.sqrt(max(phase_seconds, 0.0) / cost))
    return int(max(1, min(best, cores, MAX_AUTO_THREADS)))


class PhaseTeam:
    """T threads that run ``repeats`` passes over ``phases``, with a barrier after every phase.

    ``phases[p][t]`` is thread t's work in phase p (a callable, or None for nothing). The calling thread is
    member 0, so T - 1 worker threads are started; they sleep on the barrier between runs. An exception in
    any member stops the team and is raised by ``run``; a stopped team refuses to run again.
    """

    def __init__(self, phases: Sequence[Sequence[Callable[[], None] | None]], repeats: int):
        self.threads = len(phases[0]) if phases else 1
        # While a frame is captured (Simulator.step_frame), run() records each member's work there instead.
        self.recording: TeamRecording | None = None
        if any(len(phase) != self.threads for phase in phases):
            raise ArgumentError("every phase needs one entry per thread")
        self._phases = [list(phase) for phase in phases]
        self._repeats = int(repeats)
        self._barrier = threading.Barrier(self.threads)
        self._state = {"error": None, "closed": False}
        self._workers = [
            threading.Thread(target=PhaseTeam._serve, args=(self._barrier, self._state, self._work_of(t)),
                             name=f"warp-verlet-relax-{t}", daemon=True)
            for t in range(1, self.threads)
        ]
        for started, worker in enumerate(self._workers):
            try:
                worker.start()
            except RuntimeError as exc:  # the process may start no more threads
                PhaseTeam._release(self._barrier, self._state)
                raise WarpVerletError(f"cannot start {self.threads} relaxation threads ({exc}; {started + 1} "
                                      "were running): ask for fewer") from None
        self._own_work = self._work_of(0)
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
        """One run: every member does its work of every phase, ``repeats`` times; returns when all are done. While a
        recording is set, member 0's work is issued (into the frame's capture) and the others' recorded instead."""
        if self.recording is not None:
            self.recording.team_run(self._phases, self._repeats)
            return
        if self._state["closed"] or self._barrier.broken:
            raise WarpVerletError("the CPU relaxation threads stopped after an earlier error") from self._state["error"]
        try:
            self._barrier.wait()
            self._own_work()
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


def yield_address() -> int:
    """The address of the C library's ``sched_yield`` (``SwitchToThread`` on Windows): what a thread waiting at the
    native barrier calls to give its core to the others."""
    import ctypes
    import sys

    if sys.platform == "win32":
        function = ctypes.windll.kernel32.SwitchToThread
    else:
        function = ctypes.CDLL(None).sched_yield
    return ctypes.cast(function, ctypes.c_void_p).value


class TeamRecording:
    """One frame of a CPU thread team, recorded for capture: while it is set on the solver's teams, a team's run()
    issues member 0's tasks (so that the frame's capture on the calling thread records them, with every stage's
    single-thread work) and lists every other member's, each phase followed by a barrier. ``member_graphs()`` then
    captures each other member's list as its own graph. Each team run starts with a barrier too, so that no member
    starts a phase before member 0 has done the frame's work that comes before it."""

    def __init__(self, threads: int):
        import warp as wp

        from warp_verlet.kernels.team_barrier import team_barrier

        self.threads = threads
        self.barrier_state = wp.zeros(3, dtype=int, device="cpu")  # arrived, generation, aborted
        self.barrier = wp.launch(team_barrier, 1, inputs=[self.barrier_state, threads, wp.uint64(yield_address())],
                                 device="cpu", record_cmd=True)
        self._others: list[list[Callable[[], None] | None]] = [[] for _ in range(threads - 1)]  # None: a barrier

    def team_run(self, phases: Sequence[Sequence[Callable[[], None] | None]], repeats: int) -> None:
        if len(phases[0]) != self.threads:
            raise WarpVerletError(f"a team of {len(phases[0])} threads in a frame recorded for {self.threads}")
        self._barrier_for_all()
        for _ in range(repeats):
            for phase in phases:
                if phase[0] is not None:
                    phase[0]()
                for ops, task in zip(self._others, phase[1:]):
                    if task is not None:
                        ops.append(task)
                self._barrier_for_all()

    def _barrier_for_all(self) -> None:
        self.barrier.launch()
        for ops in self._others:
            ops.append(None)

    def member_graphs(self) -> list:
        """Members 1 .. T-1's recorded work, each captured as a graph (after member 0's capture has ended)."""
        import warp as wp

        graphs = []
        for ops in self._others:
            with wp.ScopedCapture(device="cpu") as capture:
                for task in ops:
                    (task or self.barrier.launch)()
            graphs.append(capture.graph)
        return graphs


class FrameTeam:
    """A frame captured on a CPU thread team: ``graphs[t]`` is thread t's, all meeting at the barriers of
    ``recording``'s state (kept alive with the graphs that read it). A FrameReplayer runs it."""

    def __init__(self, graphs: list, recording: TeamRecording):
        self.graphs = graphs
        self.barrier_state = recording.barrier_state

    def abort(self) -> None:
        """Release every thread waiting at one of the frame's barriers (its abort flag, in the CPU array's own
        memory)."""
        self.barrier_state.numpy()[2] = 1


class FrameReplayer:
    """T threads (a PhaseTeam of one phase) that replay a FrameTeam's graphs, thread t graph t, all at once. One
    replayer serves every frame captured for a simulator (a frame of each substep count), so that its threads are
    started once. An error in one thread sets the frame's abort flag, so that the others do not wait for it at a
    barrier forever, and the replayer refuses to run again."""

    def __init__(self, threads: int):
        self._current: list[FrameTeam | None] = [None]
        self._team = PhaseTeam([[self._member(t, self._current) for t in range(threads)]], repeats=1)

    @staticmethod
    def _member(t: int, current: list) -> Callable[[], None]:
        import warp as wp

        def replay() -> None:
            frame = current[0]
            try:
                wp.capture_launch(frame.graphs[t])
            except BaseException:
                frame.abort()  # the other threads would wait for this one at a barrier forever
                raise

        return replay

    def run(self, frame: FrameTeam) -> None:
        self._current[0] = frame
        try:
            self._team.run()
        finally:
            self._current[0] = None

    def close(self) -> None:
        self._team.close()
