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
loads, and measured slower (bench/results/grid_tiles/tiles-take-step.md).

The projection is ``stick_correction`` with the rest lengths and weights the implicit grid sticks use
(kernels/grid_relax.py), so every stick sees the arithmetic of the other forms (on CUDA with fast math's root
and division: SHARED_SWEEP_MATH); only the order of the projections differs. That order is a fixed sequence
(tile colour, tile, stick colour, stick), which the CPU runs literally (one lane per block) and a GPU runs with
the independent projections of one step at once.
"""

import warp as wp

from .grid_relax import GridColour, anchor_index, particle_weight
from .positions import scaled
from .relax import compliant_correction, stick_correction

_KERNELS: dict = {}

SHARED_SWEEP_MATH = {"fast_math": True}
"""Module options of the sweeps that hold their region in shared memory (these tiles and the clustered sweep,
kernels/stick_clusters.py). Their data sits on chip, so on CUDA their time is in the projection's float32
arithmetic, and fast math takes its square root and division from the hardware's approximations (within 2 ulp;
denormals flush to zero) instead of the longer correctly rounded sequences: the same stretch in less time
(bench/results/grid_tiles/fast-math.md). The CPU compiles the same code to the same bits either way. A launch
per colour keeps correctly rounded arithmetic: its module holds the computed tether pass too, which must agree
bit for bit with the tether table's, and its explicit and implicit forms with each other."""


def shared_sweep_options(max_registers: int | None) -> dict:
    """``wp.kernel``'s options for a shared-memory sweep: SHARED_SWEEP_MATH, and ``max_registers`` a CUDA thread at
    most (None: the compiler's choice)."""
    options = {"module_options": SHARED_SWEEP_MATH}
    if max_registers is not None:
        options["cuda_max_registers"] = max_registers
    return options


@wp.func_native("WP_TILE_SYNC();")
def block_barrier():
    """Every thread of the block waits here until all have arrived, and sees the others' shared-memory writes."""
    ...


MAX_TILED_COLOURS = 12
"""The most stick colours a tiled sweep takes (three families of four): the length of its per-colour vectors."""
colour_floats = wp.types.vector(length=MAX_TILED_COLOURS, dtype=float)
colour_ints = wp.types.vector(length=MAX_TILED_COLOURS, dtype=int)


def relax_grid_tiles(tile: int, colours: tuple, max_registers: int | None = None, vector=wp.vec3):
    """The tiled sweep's kernel for tiles of ``tile`` x ``tile`` cells and the given colours, each
    ``(dr, dc, col_first, parity_axis, q, parity, soft)`` (parity_axis 0: rows, 1: columns; soft: XPBD, the
    colour's compliance, its first tension and its anchors per row given at launch), in sweep order. One
    kernel per (tile, colours, max_registers, vector): the shared tiles' shapes and each colour's geometry are
    compile-time constants, so a colour's step unrolls to its own index arithmetic. ``max_registers`` caps a
    CUDA thread's registers (None: the compiler's choice), so that more blocks fit on a multiprocessor;
    ``vector`` is the positions' type (wp.vec3 or wp.vec3d), which the shared region holds too."""
    if tile < 4 or tile % 4:
        raise AssertionError(f"a tile's side must be a multiple of 4 (a bend colour's parity repeats every 4 rows or "
                             f"columns, and two tiles apart must share no particle), got {tile}")
    key = (tile, tuple(colours), max_registers, vector)
    if key not in _KERNELS:
        _KERNELS[key] = _make_kernel(tile, tuple(colours), max_registers, vector)
    return _KERNELS[key]


def _make_kernel(tile: int, colours: tuple, max_registers: int | None, vector):
    TILE_SIDE = tile
    HALF = tile // 2
    REGION_ROWS = tile + 2
    REGION_COLS = tile + 3
    REGION = REGION_ROWS * REGION_COLS
    STICKS = tile * tile // 2  # a colour's sticks in a tile: one axis keeps half its anchors
    COLOURS = colours
    VEC = vector

    @wp.func
    def region_cell(e: int):
        """Row and column, in the tile's region, of the region's e-th cell (row-major)."""
        return e // REGION_COLS, e % REGION_COLS

    @wp.func_native("t.data(wp::tile_coord(i, j)) = value;")
    def put_point(t: wp.tile(dtype=VEC, shape=(REGION_ROWS, REGION_COLS), storage="shared"), i: int, j: int,
                  value: VEC): ...

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

    @wp.kernel(module="unique", **shared_sweep_options(max_registers))
    def relax_grid_tiles(
        x: wp.array(dtype=VEC),
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
    ):
        """One sweep of every colour over the tiles of one tile colour (tile row parity, tile column parity):
        block k takes tile (parity_row + 2 (k // tiles_across), parity_col + 2 (k % tiles_across)). ``layout``
        is any colour's (the kernel reads the cloth's first particle, row length and weights from it). A soft
        colour n's stick with anchor (r, c) keeps its tension (mu, zeroed at the substep's start) where the
        launch-per-colour form keeps it: tension[tension_first[n] + kr * anchors_per_row[n] + kc], (kr, kc) its
        place among the colour's anchors (kernels/grid_relax.py)."""
        block, lane = wp.tid()
        threads = wp.block_dim()
        first = layout.first_particle
        grid_cols = layout.grid_cols
        r0 = (tile_row_parity + 2 * (block // tiles_across)) * TILE_SIDE
        c0 = (tile_col_parity + 2 * (block % tiles_across)) * TILE_SIDE
        # Everything a projection reads is staged in shared memory first: the region's positions and weights,
        # and the rest-length tables over its columns and rows, so that the colours' steps, which a barrier
        # separates, wait on no global load.
        region = wp.tile_empty(shape=(REGION_ROWS, REGION_COLS), dtype=VEC, storage="shared")
        weight = wp.tile_empty(shape=(REGION_ROWS, REGION_COLS), dtype=float, storage="shared")
        col_rest = wp.tile_empty(shape=(2, REGION_COLS), dtype=float, storage="shared")  # 1 and 2 columns apart
        col_step = wp.tile_empty(shape=REGION_COLS, dtype=wp.float64, storage="shared")  # squared, 1 apart
        row_rest = wp.tile_empty(shape=(2, REGION_ROWS), dtype=float, storage="shared")
        row_step = wp.tile_empty(shape=REGION_ROWS, dtype=wp.float64, storage="shared")

        e = lane
        while e < REGION:
            rr, rc = region_cell(e)
            gr = r0 + rr
            gc = c0 - 1 + rc
            if gr < grid_rows and gc >= 0 and gc < grid_cols:
                put_point(region, rr, rc, x[first + gr * grid_cols + gc])
                put_weight(weight, rr, rc, particle_weight(layout, first + gr * grid_cols + gc, inv_mass, pins))
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
                x[first + gr * grid_cols + gc] = region[rr, rc]
            e += threads

    return relax_grid_tiles
