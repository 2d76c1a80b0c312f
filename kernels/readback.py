"""What a viewer reads back each frame, computed on the device so that only the result crosses to the host:
the drawn particles' interpolated positions (a few thousand vec3 instead of every particle's three arrays),
and the structural stretch reduced to three numbers (instead of every position and a numpy pass over every
stick)."""

from typing import Any

import warp as wp

from .positions import for_positions


@wp.kernel
def gather_drawn(x: wp.array(dtype=Any), x_inertial: wp.array(dtype=Any), dq: wp.array(dtype=Any),
                 particle: wp.array(dtype=int), alpha: float, out: wp.array(dtype=wp.vec3f)):
    """out[i]: particle[i] between its position after the previous substep (x_inertial - dq, as
    ``State.previous_positions``) and now, ``alpha`` of the way: what ``Simulator.render_positions`` gives."""
    i = wp.tid()
    p = particle[i]
    now = x[p]
    before = x_inertial[p] - dq[p]
    v = before + (now - before) * type(now[0])(alpha)
    out[i] = wp.vec3f(wp.float32(v[0]), wp.float32(v[1]), wp.float32(v[2]))


@wp.kernel
def gather_positions(x: wp.array(dtype=Any), index: wp.array(dtype=int), out: wp.array(dtype=Any)):
    """out[i] = x[index[i]]: every position put in another order (a renumbered cloth's back in the scene's), on
    the device, so that the host copies them once and gathers nothing."""
    i = wp.tid()
    out[i] = x[index[i]]


@wp.kernel
def structural_stretch(x: wp.array(dtype=Any), ends: wp.array(dtype=wp.vec2i), rest: wp.array(dtype=float),
                       weight_entry: wp.array(dtype=int), weight: wp.array(dtype=float),
                       sum_squares: wp.array(dtype=wp.float64), largest: wp.array(dtype=float),
                       count: wp.array(dtype=int)):
    """|D - L| / L of structural stick i in float64 (as ``Model.structural_stretch`` on the host), skipped when
    torn (its weight entry is 0; ``weight`` is empty for a scene that cannot tear); summed as squares, maxed
    and counted with atomics (the sum's order, and so its last bits, may vary between runs on a GPU)."""
    i = wp.tid()
    if weight.shape[0] > 0:
        if weight[weight_entry[i]] == 0.0:
            return
    a = x[ends[i][0]]
    b = x[ends[i][1]]
    dx = wp.float64(b[0]) - wp.float64(a[0])
    dy = wp.float64(b[1]) - wp.float64(a[1])
    dz = wp.float64(b[2]) - wp.float64(a[2])
    length = wp.sqrt(dx * dx + dy * dy + dz * dz)
    r = wp.float64(rest[i])
    s = wp.abs(length - r) / r
    wp.atomic_add(sum_squares, 0, s * s)
    wp.atomic_max(largest, 0, wp.float32(s))
    wp.atomic_add(count, 0, 1)


for_positions(gather_drawn, arrays=("x", "x_inertial", "dq"))
for_positions(gather_positions, arrays=("x", "out"))
for_positions(structural_stretch, arrays=("x",))


@wp.func
def squared_stretch(a: Any, b: Any, rest: float):
    """((|b - a| - L) / L)^2 in float64, as ``Model.structural_stretch`` computes it on the host."""
    dx = wp.float64(b[0]) - wp.float64(a[0])
    dy = wp.float64(b[1]) - wp.float64(a[1])
    dz = wp.float64(b[2]) - wp.float64(a[2])
    r = wp.float64(rest)
    s = (wp.sqrt(dx * dx + dy * dy + dz * dz) - r) / r
    return s * s


@wp.kernel
def grid_row_stretch(x: wp.array(dtype=Any), first_particle: int, rows: int, cols: int,
                     col_sq: wp.array(dtype=wp.float64), row_sq: wp.array(dtype=wp.float64), chunk: int,
                     sums: wp.array(dtype=wp.float64), counts: wp.array(dtype=int)):
    """Columns k * chunk .. (k + 1) * chunk - 1 of row r of a grid cloth that cannot tear (thread r * chunks per
    row + k): the squared stretch of their structural sticks, (r, c)-(r, c+1) and (r, c)-(r+1, c), summed in
    column order (a fixed order: the same sum on every run), rest lengths from the implicit sticks' squared
    steps (kernels/grid_relax.py)."""
    t = wp.tid()
    per_row = (cols + chunk - 1) // chunk
    r = t // per_row
    first = (t - r * per_row) * chunk
    total = wp.float64(0.0)
    n = int(0)
    row = first_particle + r * cols
    for c in range(first, wp.min(first + chunk, cols)):
        a = x[row + c]
        if c + 1 < cols:
            total += squared_stretch(a, x[row + c + 1], wp.float32(wp.sqrt(col_sq[c])))
            n += 1
        if r + 1 < rows:
            total += squared_stretch(a, x[row + cols + c], wp.float32(wp.sqrt(row_sq[r])))
            n += 1
    sums[t] = total
    counts[t] = n


@wp.kernel
def chunk_stretch(x: wp.array(dtype=Any), ends: wp.array(dtype=wp.vec2i), rest: wp.array(dtype=float),
                  weight_entry: wp.array(dtype=int), weight: wp.array(dtype=float), chunk: int,
                  sums: wp.array(dtype=wp.float64), counts: wp.array(dtype=int)):
    """Structural sticks t * chunk .. (t + 1) * chunk - 1 (of a list of them): their squared stretch summed in
    order, torn ones left out (``weight`` empty: none can tear)."""
    t = wp.tid()
    total = wp.float64(0.0)
    n = int(0)
    for i in range(t * chunk, wp.min((t + 1) * chunk, ends.shape[0])):
        holds = True
        if weight.shape[0] > 0:
            holds = weight[weight_entry[i]] != 0.0
        if holds:
            total += squared_stretch(x[ends[i][0]], x[ends[i][1]], rest[i])
            n += 1
    sums[t] = total
    counts[t] = n


@wp.kernel
def sum_chunks(sums: wp.array(dtype=wp.float64), counts: wp.array(dtype=int), chunk: int,
               out_sums: wp.array(dtype=wp.float64), out_counts: wp.array(dtype=int)):
    """Partial sums t * chunk .. (t + 1) * chunk - 1 added in order: one level of a reduction whose order is
    fixed, so that its result is the same on every run (atomics would add in the order threads arrive)."""
    t = wp.tid()
    total = wp.float64(0.0)
    n = int(0)
    for i in range(t * chunk, wp.min((t + 1) * chunk, sums.shape[0])):
        total += sums[i]
        n += counts[i]
    out_sums[t] = total
    out_counts[t] = n


@wp.kernel
def finish_rms(sums: wp.array(dtype=wp.float64), counts: wp.array(dtype=int), rms: wp.array(dtype=wp.float64)):
    """The RMS from the last partial sum and count (0 where nothing was counted)."""
    rms[0] = wp.float64(0.0)
    if counts[0] > 0:
        rms[0] = wp.sqrt(sums[0] / wp.float64(counts[0]))


for_positions(grid_row_stretch, arrays=("x",))
for_positions(chunk_stretch, arrays=("x",))
