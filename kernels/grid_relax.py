"""Implicit grid sticks and tethers: on a uniform grid cloth, a stick's two ends follow from its thread index
and its colour, and its rest length from the grid's coordinates, so a sweep reads and writes only positions
and inverse masses (which a GPU's L2 can hold) instead of streaming every stick's ends, rest length and
weight from memory.

A colour is one (direction, parity) of the analytic grid colouring (warp_verlet/geometry/colouring.py): its sticks run
(r, c) -> (r + dr, c + dc) for anchors in a block of rows and columns, where one axis keeps only the anchors
whose ``(index // q) % 2`` is the colour's parity (q = 1 for neighbours, 2 for a bend stick, which spans two
cells). Thread k of the colour takes the k-th anchor in row-major order, the order the explicit arrays hold
the colour's sticks in.

Rest lengths are those the explicit path computes on the host (warp_verlet/geometry/topology.py): the float64 norm of
the difference of two float32 rest positions, rounded to float32. A grid's x depends on the column alone and its
other coordinate on the row alone, so a stick along the rows or the columns takes its rest length from a float32
table per row or per column, and a shear stick adds the squared column and row steps (float64 tables, rounded as
numpy rounds them) and takes the root: an addition, a square root and a rounding, which leave no room for a
fused multiply-add to change a bit. The projection is ``stick_correction`` (kernels/relax.py), the explicit
kernels' own arithmetic, so the two paths give the same positions bit for bit.

On a GPU each kernel runs a power of two of threads per row of anchors, so that a thread finds its row and column
with a shift and a mask, not a division (the threads past the row's last anchor return at once). On the CPU a
thread takes whole rows of anchors in one loop and reads the weights from the inverse masses, which stay in its
caches (kernels/relax.py says why a loop). Indices are tested for a sign they never have, so that the compiler
drops Warp's negative-index adjustment from them (kernels/relax.py says more).
"""

from typing import Any

import warp as wp

from .positions import for_positions, scaled
from .relax import compliant_correction, stick_correction
from .tether import within_pins


@wp.func
def anchor_index(k: int, q: int, parity: int):
    """The k-th index along an axis: every index when q is 0, else those whose (index // q) % 2 is ``parity``,
    for q = 1 or 2 (2 * q * (k // q) + parity * q + k % q, with shifts for the divisions)."""
    if q == 0:
        return k
    s = q - 1
    return ((k >> s) << (s + 1)) + (parity << s) + (k & s)


@wp.struct
class GridColour:
    """One colour of one grid cloth: anchors (r, c) = (anchor_index(k_r, row_q, parity) + row_first,
    anchor_index(k_c, col_q, parity) + col_first); each stick joins (r, c) to (r + dr, c + dc). A stick that
    crosses columns only takes its rest length from ``col_rest[c + col_shift]``, one that crosses rows only from
    ``row_rest[r]``, and one that crosses both (shear) computes it from ``col_sq[c + col_shift]`` and
    ``row_sq[r]`` (``use_col`` / ``use_row`` say which axes it crosses)."""

    first_particle: int
    grid_cols: int  # particles per row
    cols: int  # anchors per row in this colour
    col_bits: int  # threads per row of anchors: 2^col_bits >= cols (the surplus threads return at once)
    row_first: int
    col_first: int
    row_q: int
    col_q: int
    parity: int
    dr: int
    dc: int
    use_col: int
    use_row: int
    col_shift: int
    uniform_mass: int  # 1: every free particle weighs free_weight and the pins (the kernel's ``pins``) nothing
    free_weight: float


@wp.func
def particle_weight(g: GridColour, p: int, inv_mass: wp.array(dtype=float), pins: wp.array(dtype=int)):
    """inv_mass[p], found without reading it where the cloth's free particles share one inverse mass: 0 for one
    of the few pins, else the free particles' (the same float32 the array holds)."""
    if g.uniform_mass == 0:
        return inv_mass[p]
    for n in range(pins.shape[0]):
        if pins[n] == p:
            return float(0.0)
    return g.free_weight


@wp.func
def colour_stick(g: GridColour, kr: int, kc: int, col_rest: wp.array(dtype=float), row_rest: wp.array(dtype=float),
                 col_sq: wp.array(dtype=wp.float64), row_sq: wp.array(dtype=wp.float64)):
    """Particles i, j and the rest length of the colour's stick (kr, kc): row kr and column kc of its anchors."""
    r = anchor_index(kr, g.row_q, g.parity) + g.row_first
    c = anchor_index(kc, g.col_q, g.parity) + g.col_first
    i = g.first_particle + r * g.grid_cols + c
    j = i + g.dr * g.grid_cols + g.dc
    column = c + g.col_shift
    rest = float(0.0)
    if r < 0 or column < 0:  # never true: see the module docstring
        return -1, -1, rest
    if g.use_row == 0:
        rest = col_rest[column]
    elif g.use_col == 0:
        rest = row_rest[r]
    else:
        rest = wp.float32(wp.sqrt(col_sq[column] + row_sq[r]))
    return i, j, rest


@wp.func
def stick_weights(g: GridColour, i: int, j: int, inv_mass: wp.array(dtype=float), pins: wp.array(dtype=int),
                  read_weights: int):
    """The inverse masses of a stick's ends: read from ``inv_mass`` where ``read_weights`` is 1 (the CPU: the array
    stays in its caches, and reading it is cheaper than searching the pins), else found by particle_weight (a GPU,
    where it saves memory traffic); both give the same float32."""
    if read_weights != 0:
        return inv_mass[i], inv_mass[j]
    return particle_weight(g, i, inv_mass, pins), particle_weight(g, j, inv_mass, pins)


@wp.func
def project_grid_stick(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    g: GridColour,
    pins: wp.array(dtype=int),
    col_rest: wp.array(dtype=float),
    row_rest: wp.array(dtype=float),
    col_sq: wp.array(dtype=wp.float64),
    row_sq: wp.array(dtype=wp.float64),
    kr: int,
    kc: int,
    read_weights: int,
):
    """The rigid projection of the colour's stick (kr, kc) (relax_colour's, with ends and rest computed), its ends'
    weights as ``stick_weights`` finds them."""
    i, j, rest = colour_stick(g, kr, kc, col_rest, row_rest, col_sq, row_sq)
    if i < 0 or j < 0:  # never true (see colour_stick)
        return
    wi, wj = stick_weights(g, i, j, inv_mass, pins, read_weights)
    xi = x[i]
    xj = x[j]
    c = stick_correction(xi, xj, wi, wj, rest, 1.0)
    x[i] = xi + scaled(c, wi)
    x[j] = xj - scaled(c, wj)


@wp.kernel
def relax_grid_colour(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    g: GridColour,
    pins: wp.array(dtype=int),
    col_rest: wp.array(dtype=float),
    row_rest: wp.array(dtype=float),
    col_sq: wp.array(dtype=wp.float64),
    row_sq: wp.array(dtype=wp.float64),
    first_row: int,
    rows_per_thread: int,
):
    """Gauss-Seidel over one colour of implicit grid sticks (relax_colour with ends and rest computed), from the
    row of anchors ``first_row``. ``rows_per_thread`` 0 (a GPU): a thread per anchor, 2^col_bits threads per row
    of anchors. Else (the CPU, where Warp runs a launch's threads one after another): thread t takes
    ``rows_per_thread`` whole rows of anchors from first_row + t * rows_per_thread, in row-major order, in one
    loop (kernels/relax.py says why)."""
    t = wp.tid()
    if rows_per_thread == 0:
        kr = first_row + (t >> g.col_bits)
        kc = t & ((1 << g.col_bits) - 1)
        if kc < g.cols:
            project_grid_stick(x, inv_mass, g, pins, col_rest, row_rest, col_sq, row_sq, kr, kc, 0)
        return
    kr = first_row + t * rows_per_thread
    if kr < 0:  # never true (see colour_stick)
        return
    stop = kr + rows_per_thread
    while kr < stop:
        kc = int(0)
        while kc < g.cols:
            project_grid_stick(x, inv_mass, g, pins, col_rest, row_rest, col_sq, row_sq, kr, kc, 1)
            kc += 1
        kr += 1


@wp.func
def project_grid_stick_compliant(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    g: GridColour,
    pins: wp.array(dtype=int),
    col_rest: wp.array(dtype=float),
    row_rest: wp.array(dtype=float),
    col_sq: wp.array(dtype=wp.float64),
    row_sq: wp.array(dtype=wp.float64),
    compliance: float,
    inv_dt2: float,
    tension_first: int,
    tension: wp.array(dtype=float),
    kr: int,
    kc: int,
    read_weights: int,
):
    """The XPBD projection of the colour's stick (kr, kc) (relax_colour_compliant's, with ends and rest computed);
    its tension is tension[tension_first + kr * cols + kc]; ``read_weights`` as project_grid_stick's."""
    i, j, rest = colour_stick(g, kr, kc, col_rest, row_rest, col_sq, row_sq)
    k = tension_first + kr * g.cols + kc
    if i < 0 or j < 0 or k < 0:  # never true (see colour_stick)
        return
    wi, wj = stick_weights(g, i, j, inv_mass, pins, read_weights)
    xi = x[i]
    xj = x[j]
    # Weight 1: a cloth that tears keeps stick arrays.
    c, mu = compliant_correction(xi, xj, wi, wj, rest, 1.0, compliance, inv_dt2, tension[k])
    tension[k] = mu
    x[i] = xi + scaled(c, wi)
    x[j] = xj - scaled(c, wj)


@wp.kernel
def relax_grid_colour_compliant(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    g: GridColour,
    pins: wp.array(dtype=int),
    col_rest: wp.array(dtype=float),
    row_rest: wp.array(dtype=float),
    col_sq: wp.array(dtype=wp.float64),
    row_sq: wp.array(dtype=wp.float64),
    compliance: float,
    inv_dt2: float,
    first_row: int,
    tension_first: int,
    rows_per_thread: int,
    tension: wp.array(dtype=float),
):
    """XPBD over one colour of implicit grid sticks (relax_colour_compliant with ends and rest computed, one
    compliance for the colour's family), threads as relax_grid_colour's; ``tension`` holds the soft colours'
    sticks from ``tension_first``, a row of anchors after another."""
    t = wp.tid()
    if rows_per_thread == 0:
        kr = first_row + (t >> g.col_bits)
        kc = t & ((1 << g.col_bits) - 1)
        if kc < g.cols:
            project_grid_stick_compliant(x, inv_mass, g, pins, col_rest, row_rest, col_sq, row_sq, compliance,
                                         inv_dt2, tension_first, tension, kr, kc, 0)
        return
    kr = first_row + t * rows_per_thread
    if kr < 0:  # never true (see colour_stick)
        return
    stop = kr + rows_per_thread
    while kr < stop:
        kc = int(0)
        while kc < g.cols:
            project_grid_stick_compliant(x, inv_mass, g, pins, col_rest, row_rest, col_sq, row_sq, compliance,
                                         inv_dt2, tension_first, tension, kr, kc, 1)
            kc += 1
        kr += 1


@wp.kernel
def pull_grid_tethers(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    first_particle: int,
    grid_cols: int,
    pins: wp.array(dtype=int),
    pin_col_sq: wp.array2d(dtype=wp.float64),
    pin_row_sq: wp.array2d(dtype=wp.float64),
    tethers: int,
    scale: wp.float64,
    col_bits: int,
    first_row: int,
):
    """pull_tethers for a free particle of a grid cloth (2^col_bits threads per row from ``first_row``, the
    surplus returning at once), whose tethers are computed: its
    ``tethers`` nearest pins (ties to the lower pin, as warp_verlet/constraints/tethers.nearest_pins chooses them) at
    their rest-pose distances times ``scale``, from the squared column and row differences to each pin
    (pin_col_sq[pin, column], pin_row_sq[pin, row]), rounded to float32 as the tether table is."""
    t = wp.tid()
    r = first_row + (t >> col_bits)
    c = t & ((1 << col_bits) - 1)
    if c >= grid_cols:
        return
    p = first_particle + r * grid_cols + c
    if inv_mass[p] == 0.0:
        return
    last_distance = wp.float64(-1.0)
    last_pin = int(-1)
    first_pin = int(-1)
    first_limit = wp.float64(0.0)
    second_pin = int(-1)
    second_limit = wp.float64(0.0)
    for k in range(tethers):
        # The next pin in (distance, index) order after the last one taken. The distances are recomputed in
        # each round: a local array of them measured slower (it lives in local memory).
        best = int(-1)
        best_distance = wp.float64(0.0)
        for n in range(pins.shape[0]):
            rest_distance = wp.sqrt(pin_col_sq[n, c] + pin_row_sq[n, r])
            later = rest_distance > last_distance or (rest_distance == last_distance and n > last_pin)
            if later and (best < 0 or rest_distance < best_distance):
                best = n
                best_distance = rest_distance
        last_distance = best_distance
        last_pin = best
        limit = wp.float64(wp.float32(best_distance * scale))  # rounded to float32, as the tether table is
        if k == 0:
            first_pin = pins[best]
            first_limit = limit
        else:
            second_pin = pins[best]
            second_limit = limit
    xp = x[p]
    # The limits are float32 values, so exact in either precision of the positions.
    x[p] = within_pins(xp, x, first_pin, type(xp[0])(first_limit), second_pin, type(xp[0])(second_limit))


for_positions(relax_grid_colour, arrays=("x",))
for_positions(relax_grid_colour_compliant, arrays=("x",))
for_positions(pull_grid_tethers, arrays=("x",))
