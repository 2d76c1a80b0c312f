"""A barrier between the CPU threads of a relaxation team (warp_verlet/core/cpu_team.py, ``NativeBarrier``).

Between two phases (two colours of a sweep, say) every thread must finish the first before any starts the second.
On the CPU, a frame cut over T threads is captured as T graphs, one a thread, each replayed by its own thread in
Warp's C++ loop, and each graph launches ``team_barrier`` after each of its thread's pieces (``FrameTeam``); a team
that steps without capture launches it from Python after each piece (``PhaseTeam``). Either way the thread waits
in C++, with the GIL released, where a Python barrier's wake-ups cost each thread more
(bench/results/cpu_threads/native-phases).

The barrier is the usual counter and generation (a sense-reversing barrier): the last thread to arrive resets the
counter and advances the generation, and the others wait until the generation moves. Its atomics order memory
(acquire and release), so every write of a phase is seen by every thread after the barrier. A waiting thread yields
its core to the OS every ``SPINS_PER_YIELD`` turns (``yield_to_os``: the address of the C library's
``sched_yield``), so that more threads than free cores still make progress. A set abort flag releases every
waiting thread at once (the frame is then discarded: an error stopped one of them).

``state`` holds three ints: the arrived count, the generation, the abort flag. On a GPU the kernel does nothing
(a CUDA graph orders its own launches); it is only launched on the CPU.
"""

import warp as wp

SPINS_PER_YIELD = 256
"""Turns of the wait loop between two yields to the OS (a turn is one atomic load, a few nanoseconds)."""

_WAIT = f"""
#if !defined(__CUDA_ARCH__)
    int* arrived = (int*)&state.data[0];
    int* generation = (int*)&state.data[1];
    int* aborted = (int*)&state.data[2];
    typedef int32_t (*yield_t)();
    int32_t seen = __atomic_load_n(generation, __ATOMIC_ACQUIRE);
    if (__atomic_add_fetch(arrived, 1, __ATOMIC_ACQ_REL) == threads) {{
        __atomic_store_n(arrived, 0, __ATOMIC_RELAXED);
        __atomic_store_n(generation, seen + 1, __ATOMIC_RELEASE);
    }} else {{
        int32_t turns = 0;
        while (__atomic_load_n(generation, __ATOMIC_ACQUIRE) == seen
               && __atomic_load_n(aborted, __ATOMIC_RELAXED) == 0) {{
            if (++turns == {SPINS_PER_YIELD}) {{
                ((yield_t)yield_to_os)();
                turns = 0;
            }}
        }}
    }}
#endif
"""


@wp.func_native(_WAIT)
def wait_for_team(state: wp.array(dtype=int), threads: int, yield_to_os: wp.uint64):
    """Return once ``threads`` callers have arrived (or the abort flag, state[2], is set)."""
    ...


@wp.kernel
def team_barrier(state: wp.array(dtype=int), threads: int, yield_to_os: wp.uint64):
    """Launched with dim 1 by each thread of a team, or in its captured graph: that thread waits here for the
    others."""
    wait_for_team(state, threads, yield_to_os)
