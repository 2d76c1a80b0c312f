"""Tiled sweeps over implicit grid sticks: block Gauss-Seidel, each block holding a tile of the cloth in shared
memory while it runs every colour of its sticks, so that a sweep reads and writes each position about once
instead of once per colour.

A tile owns the sticks anchored in its TILE x TILE cells (a stick's anchor is its first particle, (r, c); its
other end is (r + dr, c + dc), dr in 0..2, dc in -1..2). A block loads the tile's region, its cells and the
halo those sticks reach (rows r0 .. r0 + TILE + 1, columns c0 - 1 .. c0 + TILE + 1), with the particles'
weights and the rest-length tables over those rows and columns, into shared memory; projects the tile's sticks
colour by colour in the analytic grid colouring's order, a thread per stick of the colour (a colour's sticks
share no particle, so its threads write disjoint cells; a barrier separates the colours); and writes the region
back. Each colour's geometry is a compile-time constant of the kernel, so its step unrolls to its own index
arithmetic.

Tiles are themselves coloured 2 x 2 by the parity of their tile row and column: the launch of one tile colour
runs tiles two apart, whose regions (TILE + 2 rows, TILE + 3 columns, starting TILE x 2 apart) share no
particle for any TILE >= 3, so the blocks of a launch neither read nor write each other's particles. A sweep is
four launches, Gauss-Seidel across them. TILE is a multiple of 4, so that a bend colour's parity pattern, which
repeats every 4 rows or columns, is the grid's in every tile.

Shared memory is written through the ``put_*`` stores and the block synchronised by ``block_barrier``, once where
the order needs it: after the staging, after each colour and before the write-back. Warp's own tile writes
(``tile_scatter_masked``) each end with a barrier, which at two writes a stick put twice as many barriers into a
sweep as its colours need, and a thread would wait on every one of them. The shared tiles are allocated
uninitialised (``tile_empty``): a projection reads only cells of its own sticks, which lie in the grid and are
staged first, so zero-filling them (a loop and barriers per tile) bought nothing
(bench/results/grid_tiles/barriers-and-fold.md).

A soft colour (XPBD) projects with its compliance and each stick's tension, which it reads and writes in global
memory where the launch per colour keeps it (kernels/grid_relax.py): a stick is projected once a sweep, by one
thread, so its tension needs no staging and no barrier.

The Verlet step and the tether pass before a sweep stay launches of their own. Taken into the staging (the first
tile to stage a particle moving it, bit for bit the same), they made each staged cell wait on a chain of dependent
loads, and measured slower (bench/results/grid_tiles/tiles-take-step.md). Taken into the write-back instead (a
``step`` kernel), the last sweep of a substep takes the *next* substep's step there: a cell's last writer in a
sweep is the tile launched last of those whose regions hold it, and nothing reads the cell after that write
until the next substep, so the tile that writes it last moves it on by the step (and the tether pass, which reads
only pins) with the very arithmetic of kernels/integrate.py, bit for bit the separate launch, and the step's loads
overlap the other blocks' work instead of waiting in a launch of their own. The solver decides where this applies
(core/stages.step_in_tiles).

The projection is ``stick_correction`` with the rest lengths and weights the implicit grid sticks use
(kernels/grid_relax.py), so every stick sees exactly the arithmetic of the other forms; only the order of the
projections differs. That order is a fixed sequence (tile colour, tile, stick colour, stick), which the CPU
runs literally (one lane per block) and a GPU runs with the independent projections of one step at once.
"""

import warp as wp

from .grid_relax import GridColour, anchor_index, particle_weight
from .positions import scaled
from .relax import compliant_correction, stick_correction
from .tether import within_reach

_KERNELS: dict = {}


@wp.func_native("WP_TILE_SYNC();")
def block_barrier():
    """Every thread of the block waits here until all have arrived, and sees the others' shared-memory writes."""
    ...


NO_STEP, STEP, STEP_TETHERED = 0, 1, 2
"""What a tiled launch's write-back does besides writing the positions: nothing; the next substep's Verlet step
(kernels/integrate.verlet_step) on the particles it writes last in the sweep; or that step and the first sweep's
tether pass (verlet_step_tethered)."""

MAX_TILED_COLOURS = 12
"""The most stick colours a tiled sweep takes (three families of four): the length of its per-colour vectors."""
colour_floats = wp.types.vector(length=MAX_TILED_COLOURS, dtype=float)
colour_ints = wp.types.vector(length=MAX_TILED_COLOURS, dtype=int)


def relax_grid_tiles(tile: int, colours: tuple, max_registers: int | None = None, step: int = NO_STEP,
                     tethers: int = 0):
    """The tiled sweep's kernel for tiles of ``tile`` x ``tile`` cells and the given colours, each
    ``(dr, dc, col_first, parity_axis, q, parity, soft)`` (parity_axis 0: rows, 1: columns; soft: XPBD, the
    colour's compliance, its first tension and its anchors per row given at launch), in sweep order. One
    kernel per (tile, colours, max_registers, step): the shared tiles' shapes and each colour's geometry are
    compile-time constants, so a colour's step unrolls to its own index arithmetic. ``max_registers`` caps a
    CUDA thread's registers (None: the compiler's choice), so that more blocks fit on a multiprocessor.
    ``step``: NO_STEP, or the next substep's Verlet step taken in the write-back (STEP, or STEP_TETHERED with
    the first sweep's tether pass too, ``tethers`` a particle in the table; see the module docstring)."""
    if tile < 4 or tile % 4:
        raise AssertionError(f"a tile's side must be a multiple of 4 (a bend colour's parity repeats every 4 rows or "
                             f"columns, and two tiles apart must share no particle), got {tile}")
    key = (tile, tuple(colours), max_registers, step, tethers if step == STEP_TETHERED else 0)
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


def _make_kernel(tile: int, colours: tuple, max_registers: int | None, step: int, tethers: int):
    TILE_SIDE = tile
    STEPS = step != NO_STEP
    TETHERED = step == STEP_TETHERED
    TETHERS = max(tethers, 1)
    HALF = tile // 2
    REGION_ROWS = tile + 2
    REGION_COLS = tile + 3
    REGION = REGION_ROWS * REGION_COLS
    # The step's staged values: the summed form's prediction and increment, and each tether's pin and length, of
    # the cells the block writes last (one cell where the kernel takes no step).
    STEP_ROWS, STEP_COLS = (REGION_ROWS, REGION_COLS) if STEPS else (1, 1)
    TETHER_COLS = STEP_COLS * TETHERS if TETHERED else 1
    STICKS = tile * tile // 2  # a colour's sticks in a tile: one axis keeps half its anchors
    COLOURS = colours

    @wp.func
    def region_cell(e: int):
        """Row and column, in the tile's region, of the region's e-th cell (row-major)."""
        return e // REGION_COLS, e % REGION_COLS

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_point(t: wp.tile(dtype=wp.vec3, shape=(REGION_ROWS, REGION_COLS), storage="shared"), i: int, j: int,
                  value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_weight(t: wp.tile(dtype=float, shape=(REGION_ROWS, REGION_COLS), storage="shared"), i: int, j: int,
                   value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_col_rest(t: wp.tile(dtype=float, shape=(2, REGION_COLS), storage="shared"), i: int, j: int,
                     value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_row_rest(t: wp.tile(dtype=float, shape=(2, REGION_ROWS), storage="shared"), i: int, j: int,
                     value: float): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_col_step(t: wp.tile(dtype=wp.float64, shape=(REGION_COLS,), storage="shared"), i: int,
                     value: wp.float64): ...

    @wp.func_native("t.data(wp::tile_coord(i)) = value;")
    def put_row_step(t: wp.tile(dtype=wp.float64, shape=(REGION_ROWS,), storage="shared"), i: int,
                     value: wp.float64): ...

    @wp.func
    def writes_last(r: int, c: int, own_order: int, tiles_wide: int):
        """Whether the tile of launch order ``own_order`` (2 x tile row parity + tile column parity) is the last
        in the sweep to write cell (r, c): of the tiles whose regions hold the cell (its own; the tile above,
        for its first two rows; the tile to the right, for its last column; the tile to the left, for its first
        two columns), the one launched last."""
        tr = r // TILE_SIDE
        tc = c // TILE_SIDE
        up = r % TILE_SIDE < 2 and tr > 0
        right = c % TILE_SIDE == TILE_SIDE - 1 and tc + 1 < tiles_wide
        left = c % TILE_SIDE < 2 and tc > 0
        last = int(0)
        for dr in range(2):
            if dr == 0 or up:
                for dc in range(-1, 2):
                    if dc == 0 or (dc == 1 and right) or (dc == -1 and left):
                        last = wp.max(last, 2 * ((tr - dr) % 2) + (tc + dc) % 2)
        return last == own_order

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_step(t: wp.tile(dtype=wp.vec3, shape=(STEP_ROWS, STEP_COLS), storage="shared"), i: int, j: int,
                 value: wp.vec3): ...

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_tether_pin(t: wp.tile(dtype=int, shape=(STEP_ROWS, TETHER_COLS), storage="shared"), i: int, j: int,
                       value: int): ...

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_tether_length(t: wp.tile(dtype=float, shape=(STEP_ROWS, TETHER_COLS), storage="shared"), i: int, j: int,
                          value: float): ...

    options = {} if max_registers is None else {"cuda_max_registers": max_registers}

    @wp.kernel(module="unique", **options)
    def relax_grid_tiles(
        x: wp.array(dtype=wp.vec3),
        inv_mass: wp.array(dtype=float),
        layout: GridColour,
        pins: wp.array(dtype=int),
        col_rest1: wp.array(dtype=float),
        col_rest2: wp.array(dtype=float),
        row_rest1: wp.array(dtype=float),
        row_rest2: wp.array(dtype=float),
        col_sq: wp.array(dtype=wp.float64),
        row_sq: wp.array(dtype=wp.float64),
        grid_rows: int,
        tile_row_parity: int,
        tile_col_parity: int,
        tiles_across: int,
        compliance: colour_floats,
        tension_first: colour_ints,
        anchors_per_row: colour_ints,
        inv_dt2: float,
        tension: wp.array(dtype=float),
        x_inertial: wp.array(dtype=wp.vec3),
        delta: wp.array(dtype=wp.vec3),
        velocity_scale: float,
        accel_offset: wp.vec3,
        tether_pin: wp.array2d(dtype=int),
        tether_length: wp.array2d(dtype=float),
        tiles_wide: int,
    ):
        """One sweep of every colour over the tiles of one tile colour (tile row parity, tile column parity):
        block k takes tile (parity_row + 2 (k // tiles_across), parity_col + 2 (k % tiles_across)). ``layout``
        is any colour's (the kernel reads the cloth's first particle, row length and weights from it). A soft
        colour n's stick with anchor (r, c) keeps its tension (mu, zeroed at the substep's start) where the
        launch-per-colour form keeps it: tension[tension_first[n] + kr * anchors_per_row[n] + kc], (kr, kc) its
        place among the colour's anchors (kernels/grid_relax.py). With the step (``step`` of relax_grid_tiles), the
        particles this block writes last in the sweep (``writes_last``) then take the next substep's Verlet step
        (``velocity_scale``, ``accel_offset``, the summed form's ``x_inertial`` and ``delta``) and, tethered, the
        tether pass from the table's row of p, whose rows are the cloth's free particles in order and ``pins`` its
        pins; a row of the grid holds ``tiles_wide`` tiles. Without it those arguments are not read."""
        block, lane = wp.tid()
        threads = wp.block_dim()
        first = layout.first_particle
        grid_cols = layout.grid_cols
        r0 = (tile_row_parity + 2 * (block // tiles_across)) * TILE_SIDE
        c0 = (tile_col_parity + 2 * (block % tiles_across)) * TILE_SIDE
        # Everything a projection reads is staged in shared memory first: the region's positions and weights,
        # and the rest-length tables over its columns and rows, so that the colours' steps, which a barrier
        # separates, wait on no global load.
        region = wp.tile_empty(shape=(REGION_ROWS, REGION_COLS), dtype=wp.vec3, storage="shared")
        weight = wp.tile_empty(shape=(REGION_ROWS, REGION_COLS), dtype=float, storage="shared")
        col_rest = wp.tile_empty(shape=(2, REGION_COLS), dtype=float, storage="shared")  # 1 and 2 columns apart
        col_step = wp.tile_empty(shape=REGION_COLS, dtype=wp.float64, storage="shared")  # squared, 1 apart
        row_rest = wp.tile_empty(shape=(2, REGION_ROWS), dtype=float, storage="shared")
        row_step = wp.tile_empty(shape=REGION_ROWS, dtype=wp.float64, storage="shared")
        inertial = wp.tile_empty(shape=(STEP_ROWS, STEP_COLS), dtype=wp.vec3, storage="shared")
        increment = wp.tile_empty(shape=(STEP_ROWS, STEP_COLS), dtype=wp.vec3, storage="shared")
        pin_of = wp.tile_empty(shape=(STEP_ROWS, TETHER_COLS), dtype=int, storage="shared")
        reach = wp.tile_empty(shape=(STEP_ROWS, TETHER_COLS), dtype=float, storage="shared")
        own_order = 2 * tile_row_parity + tile_col_parity

        e = lane
        while e < REGION:
            rr, rc = region_cell(e)
            gr = r0 + rr
            gc = c0 - 1 + rc
            if gr < grid_rows and gc >= 0 and gc < grid_cols:
                p = first + gr * grid_cols + gc
                put_point(region, rr, rc, x[p])
                w = particle_weight(layout, p, inv_mass, pins)
                put_weight(weight, rr, rc, w)
                if wp.static(STEPS):
                    # The step's inputs are staged with the positions, so that their loads overlap the sweep's
                    # and the write-back waits on none.
                    if w != 0.0 and writes_last(gr, gc, own_order, tiles_wide):
                        put_step(inertial, rr, rc, x_inertial[p])
                        put_step(increment, rr, rc, delta[p])
                        if wp.static(TETHERED):
                            row = p - first  # the table's row: the free particles before p
                            for n in range(pins.shape[0]):
                                if pins[n] < p:
                                    row -= 1
                            for k in range(TETHERS):
                                put_tether_pin(pin_of, rr, rc * TETHERS + k, tether_pin[row, k])
                                put_tether_length(reach, rr, rc * TETHERS + k, tether_length[row, k])
            e += threads
        k = lane
        while k < REGION_COLS:
            gc = c0 - 1 + k
            if gc >= 0 and gc < col_rest1.shape[0]:
                put_col_rest(col_rest, 0, k, col_rest1[gc])
                put_col_step(col_step, k, col_sq[gc])
            if gc >= 0 and gc < col_rest2.shape[0]:
                put_col_rest(col_rest, 1, k, col_rest2[gc])
            k += threads
        k = lane
        while k < REGION_ROWS:
            gr = r0 + k
            if gr < row_rest1.shape[0]:
                put_row_rest(row_rest, 0, k, row_rest1[gr])
                put_row_step(row_step, k, row_sq[gr])
            if gr < row_rest2.shape[0]:
                put_row_rest(row_rest, 1, k, row_rest2[gr])
            k += threads
        block_barrier()

        for n in range(wp.static(len(COLOURS))):
            dr = wp.static(COLOURS[n][0])
            dc = wp.static(COLOURS[n][1])
            col_first = wp.static(COLOURS[n][2])
            q = wp.static(COLOURS[n][4])
            parity = wp.static(COLOURS[n][5])
            k = lane
            while k < STICKS:  # not range(), whose loop handles either sign of its step
                # The colour's k-th anchor in the tile: half the rows (or columns) keep anchors, those whose
                # (index // q) % 2 is the colour's parity (a tile starts on a multiple of 4, so the pattern is
                # the grid's), all of the other axis.
                lr = int(0)
                lc = int(0)
                if wp.static(COLOURS[n][3] == 0):
                    lr = anchor_index(k // TILE_SIDE, q, parity)
                    lc = k % TILE_SIDE
                else:
                    lr = k // HALF
                    lc = anchor_index(k % HALF, q, parity)
                r = r0 + lr
                c = c0 + lc
                active = r + dr < grid_rows and c >= col_first and c + wp.max(dc, 0) < grid_cols
                ic = lc + 1
                jr = lr + dr
                jc = ic + dc
                if active:
                    # The rest length as grid_relax.colour_stick finds it, from the staged tables (column
                    # c - 1 of the grid is the region's column ic - 1).
                    rest = float(0.0)
                    if wp.static(dr == 0):
                        rest = col_rest[wp.static(1 if abs(dc) == 2 else 0), ic + wp.static(-1 if dc < 0 else 0)]
                    elif wp.static(dc == 0):
                        rest = row_rest[wp.static(1 if dr == 2 else 0), lr]
                    else:
                        rest = wp.float32(wp.sqrt(col_step[ic + wp.static(-1 if dc < 0 else 0)] + row_step[lr]))
                    wi = weight[lr, ic]
                    wj = weight[jr, jc]
                    xi = region[lr, ic]
                    xj = region[jr, jc]
                    if wp.static(COLOURS[n][6]):
                        # The anchor's place among the colour's: the parity axis keeps q of every 2q indices.
                        kr = r
                        kc = c - col_first
                        if wp.static(COLOURS[n][3] == 0):
                            kr = q * (r // (2 * q)) + r % q
                        else:
                            kc = q * (c // (2 * q)) + c % q
                        t = tension_first[n] + kr * anchors_per_row[n] + kc
                        d, mu = compliant_correction(xi, xj, wi, wj, rest, 1.0, compliance[n], inv_dt2, tension[t])
                        tension[t] = mu
                    else:
                        d = stick_correction(xi, xj, wi, wj, rest, 1.0)
                    put_point(region, lr, ic, xi + scaled(d, wi))
                    put_point(region, jr, jc, xj - scaled(d, wj))
                k += threads
            # A colour's sticks share no particle, so its writes need no order among themselves; the next
            # colour reads them.
            block_barrier()

        e = lane
        while e < REGION:
            rr, rc = region_cell(e)
            gr = r0 + rr
            gc = c0 - 1 + rc
            if gr < grid_rows and gc >= 0 and gc < grid_cols:
                p = first + gr * grid_cols + gc
                value = region[rr, rc]
                if wp.static(STEPS):
                    # kernels/integrate.py's step and tether pass, in their arithmetic, on the position the
                    # sweep leaves here
                    if weight[rr, rc] != 0.0 and writes_last(gr, gc, own_order, tiles_wide):
                        step = (increment[rr, rc] + (value - inertial[rr, rc])) * velocity_scale + accel_offset
                        value = value + step
                        x_inertial[p] = value
                        delta[p] = step
                        if wp.static(TETHERED):
                            for k in range(TETHERS):
                                a = pin_of[rr, rc * TETHERS + k]
                                if a >= 0:
                                    value = within_reach(value, x[a], reach[rr, rc * TETHERS + k])
                x[p] = value
            e += threads

    return relax_grid_tiles
