"""Distance sticks: the cloth's structural, shear and bend families, as stick arrays or, on one grid cloth,
computed from the grid in the kernel.

The Model builds the sticks themselves (warp_verlet/core/model.py: they are the cloth's core, which colouring,
tearing and the stretch metrics share); this module binds their sweeps.
"""

from __future__ import annotations

from .kind import ConstraintSet
from ..launches import (FLOAT, FLOAT64, INT, VEC2I, BoundStage, PhaseTask, copy_back_phase, elements_per_thread,
                        recorded, split_tasks, start_compliant_substep)


class Sticks(ConstraintSet):
    """Distance sticks (kernels/relax.py). Coloured: one launch per colour, XPBD where a stick is soft.
    Jacobi: a gather into a scratch buffer and a copy back, cut by particle."""

    name = "sticks"

    def needed(self, req) -> bool:
        return req.sticks > 0 and not req.implicit_grid and not req.stick_clusters

    def device_bytes(self, req) -> int:
        if req.relaxation == "coloured":
            # ends, rest, weight; soft sticks add a compliance (Model) and a tension (solver scratch)
            return req.sticks * (VEC2I + 2 * FLOAT + (2 * FLOAT if req.compliant else 0))
        # neighbour, rest and weight for both ends; a scratch position and a row start per particle
        return req.sticks * 2 * (INT + 2 * FLOAT) + req.particles * (req.position_bytes + INT)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.relax import relax_colour, relax_colour_compliant, relax_colour_tension, relax_jacobi

        m, x, threads = model, state.particle_q, solver.threads
        if m.relaxation == "coloured":
            def per_thread(n):  # (threads, sticks per thread) of a colour's piece of n sticks
                k = elements_per_thread(n, m.device)
                return n // k, k

            weight = state.stick_weight if m.tears else m.stick_weight
            if m.tension_tears and not m.compliant:  # rigid sticks that keep their tension for the tear stage
                tension = solver.scratch("stick_tension", m.stick_count, float)

                def make_rigid(f, n):
                    dim, k = per_thread(n)
                    return recorded(relax_colour_tension, dim,
                                    [x, m.inv_mass, m.stick_ends, m.stick_rest, weight, f, k], [tension])
                phases = [split_tasks(make_rigid, first, count, threads) for first, count in m.colour_ranges]
                if solver.req.global_iterations:  # the global correction starts the tension (kernels/global_solve.py)
                    return BoundStage(None, phases)
                return BoundStage(lambda state, dt: tension.zero_(), phases)
            if not m.compliant:
                def make(f, n):
                    dim, k = per_thread(n)
                    return recorded(relax_colour, dim, [x, m.inv_mass, m.stick_ends, m.stick_rest, weight, f, k])
                return BoundStage(None, [split_tasks(make, first, count, threads) for first, count in m.colour_ranges])
            tension = solver.scratch("stick_tension", m.stick_count, float)

            def make_soft(f, n):
                dim, k = per_thread(n)
                return recorded(relax_colour_compliant, dim, [x, m.inv_mass, m.stick_ends, m.stick_rest, weight,
                                                              m.stick_compliance, 0.0, f, k], [tension])
            phases = [split_tasks(make_soft, first, count, threads) for first, count in m.colour_ranges]
            launches = [task.launch for phase in phases for task in phase if task is not None]

            # With the global correction on, it starts the tension where its springs left it (kernels/global_solve.py).
            return BoundStage(start_compliant_substep(launches, tension, zero=not solver.req.global_iterations),
                              phases)

        weight = state.stick_weight if m.tears else m.neighbour_weight
        scratch = solver.scratch("jacobi_positions", m.particle_count, m.position_dtype)

        def gather(f, n):
            k = elements_per_thread(n, m.device)
            return recorded(relax_jacobi, n // k, [x, m.inv_mass, m.neighbour_start, m.neighbour, m.neighbour_rest,
                                                   weight, f, k, scratch])

        return BoundStage(None, [split_tasks(gather, 0, m.particle_count, threads),
                            copy_back_phase(x, scratch, m.particle_count, threads)])



def grid_table_bytes(req) -> int:
    """The implicit grid sticks' tables: rest lengths 1 and 2 columns and rows apart, the squared steps of the
    shear sticks (float64), and the pins where the free particles weigh alike."""
    r, c = req.grid_rows, req.grid_cols
    steps = max(c - 1, 0) + max(c - 2, 0) + max(r - 1, 0) + max(r - 2, 0)
    return steps * FLOAT + (max(c - 1, 0) + max(r - 1, 0)) * FLOAT64 + req.weight_pins * INT


GRID_BLOCK_DIM = 128
"""Threads per block of the implicit grid sticks' launches: 128 ran faster per frame on an H100 than Warp's
default 256 and than 512 (bench/results/code_choices.md)."""


class GridSticks(ConstraintSet):
    """Implicit grid sticks (kernels/grid_relax.py): one launch per colour of the analytic grid colouring, in
    its order, each stick's ends and rest length computed from the thread index and the grid; the same
    positions as Sticks bit for bit. XPBD for the colours of a soft family."""

    name = "grid sticks"

    def needed(self, req) -> bool:
        return req.sticks > 0 and req.implicit_grid and not req.grid_tiles

    def device_bytes(self, req) -> int:
        return grid_table_bytes(req) + req.soft_sticks * FLOAT  # a tension per soft stick (solver scratch)

    def bind(self, model, state, solver) -> BoundStage:
        from warp_verlet.kernels.grid_relax import relax_grid_colour, relax_grid_colour_compliant

        g, x, threads = model.grid, state.particle_q, solver.threads
        tension = solver.scratch("grid_tension", g.soft_sticks, float) if g.soft_sticks else None

        def grid_threads(rows, col_bits):
            """(threads, rows of anchors a thread) for a piece of ``rows`` rows: on the CPU whole rows a thread
            (elements_per_thread), on a GPU a thread an anchor (0), 2^col_bits threads a row."""
            if model.device.is_cpu:
                per_thread = elements_per_thread(rows, model.device)
                return rows // per_thread, per_thread
            return rows << col_bits, 0

        phases, soft_launches = [], []
        for colour in g.colours:
            tables = [colour.pins, colour.col_rest, colour.row_rest, colour.col_sq, colour.row_sq]
            if colour.compliance > 0.0:
                def make(f, rows, colour=colour, tables=tables):
                    dim, per_thread = grid_threads(rows, colour.layout.col_bits)
                    return recorded(relax_grid_colour_compliant, dim,
                                    [x, model.inv_mass, colour.layout, *tables, colour.compliance, 0.0, f,
                                     colour.tension_first, per_thread], [tension], block_dim=GRID_BLOCK_DIM)
            else:
                def make(f, rows, colour=colour, tables=tables):
                    dim, per_thread = grid_threads(rows, colour.layout.col_bits)
                    return recorded(relax_grid_colour, dim, [x, model.inv_mass, colour.layout, *tables, f, per_thread],
                                    block_dim=GRID_BLOCK_DIM)
            phase = split_tasks(make, 0, colour.rows, threads)  # the CPU thread team cuts a colour by rows
            if colour.compliance > 0.0:
                soft_launches += [task.launch for task in phase if task is not None]
            phases.append(phase)
        if tension is None:
            return BoundStage(None, phases)

        return BoundStage(start_compliant_substep(soft_launches, tension), phases)


GRID_TILE = 16
"""Cells per side of a tiled sweep's tile (kernels/grid_tiles.py), a multiple of 4; a block runs one thread per
stick of a colour in the tile (half its cells)."""
GRID_TILE_MAX_REGISTERS = 64
"""Registers a CUDA thread of the tiled sweep may use on a grid of GRID_TILE_CAPPED_FROM particles or more (None:
the compiler's choice). At 64, eight 128-thread blocks fit a multiprocessor's registers, more than the compiler's
choice lets fit; fewer registers spill (bench/results/grid_tiles/registers.md has the measurements)."""
GRID_TILE_CAPPED_FROM = 1024 * 1024
"""Particles from which the tiled sweep's registers are capped. A smaller grid's launch fits on the device at the
compiler's occupancy, so the cap only costs it instructions (bench/results/grid_tiles/registers.md)."""


class GridTiles(ConstraintSet):
    """Implicit grid sticks swept tile by tile (kernels/grid_tiles.py): a block holds a tile of the cloth and
    its halo in shared memory and projects every colour of the tile's sticks there; four launches a sweep, one
    per tile colour. Float32 positions; XPBD for the colours of a soft family, with their tensions where
    GridSticks keeps them. The same projections as GridSticks in another order (block Gauss-Seidel), so not the
    same positions bit for bit."""

    name = "grid tiles"

    def needed(self, req) -> bool:
        return req.sticks > 0 and req.grid_tiles

    def device_bytes(self, req) -> int:
        return grid_table_bytes(req) + req.soft_sticks * FLOAT  # a tension per soft stick (solver scratch)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.grid_tiles import MAX_TILED_COLOURS, colour_floats, colour_ints, relax_grid_tiles

        g, x, tile = model.grid, state.particle_q, GRID_TILE
        geometry = tuple((c.layout.dr, c.layout.dc, c.layout.col_first, int(c.layout.row_q == 0),
                          c.layout.row_q or c.layout.col_q, c.layout.parity, c.compliance > 0.0) for c in g.colours)
        if len(g.colours) > MAX_TILED_COLOURS or any(c.layout.row_first or (c.layout.col_q and c.layout.col_first)
                                                     for c in g.colours):
            raise AssertionError("the tiled kernel expects at most 12 colours, anchored from row 0, with the "
                                 "column parity counted from column 0")
        pad = [0] * (MAX_TILED_COLOURS - len(g.colours))
        soft = (colour_floats(*[c.compliance for c in g.colours], *pad),
                colour_ints(*[c.tension_first for c in g.colours], *pad),
                colour_ints(*[c.layout.cols for c in g.colours], *pad))
        # Rigid, the kernel has no soft colour and reads no tension: any float array fills the argument.
        tension = solver.scratch("grid_tension", g.soft_sticks, float) if g.soft_sticks else g.col_rest1
        registers = GRID_TILE_MAX_REGISTERS if g.rows * g.cols >= GRID_TILE_CAPPED_FROM else None
        kernel = relax_grid_tiles(tile, geometry, registers, model.position_dtype)
        tiles_down, tiles_across = -(-g.rows // tile), -(-g.cols // tile)
        tasks = []
        for row_parity in (0, 1):
            for col_parity in (0, 1):
                down, across = (tiles_down - row_parity + 1) // 2, (tiles_across - col_parity + 1) // 2
                if down * across == 0:
                    continue
                launch = wp.launch_tiled(
                    kernel, dim=[down * across], block_dim=tile * tile // 2, record_cmd=True, device=model.device,
                    inputs=[x, model.inv_mass, g.colours[0].layout, g.colours[0].pins, g.col_rest1, g.col_rest2,
                            g.row_rest1, g.row_rest2, g.col_sq1, g.row_sq1, g.rows, row_parity, col_parity, across,
                            *soft, 0.0, tension])
                tasks.append(PhaseTask(kernel.key, launch.launch, launch))
        # One thread runs a tile colour: on the CPU a tiled launch's shared memory is one buffer for the process,
        # so two threads' launches would write over each other. The CPU thread team's other threads wait.
        idle = [None] * (solver.threads - 1)
        prepare = start_compliant_substep([t.launch for t in tasks], tension) if g.soft_sticks else None
        return BoundStage(prepare, [[task, *idle] for task in tasks])
