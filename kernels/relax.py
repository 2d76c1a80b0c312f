"""Distance-stick relaxation (Jakobsen 2001), weighted by inverse mass.

For a rigid stick (i, j) with rest length L and current separation d = x_j - x_i, D = |d|, both ends move
along d by the error D - L, split by inverse mass: x_i += w_i / (w_i + w_j) * k * (D - L) * d / D and
x_j -= w_j / (w_i + w_j) * k * (D - L) * d / D. Pins have w = 0 and do not move; a stick between two
pins, or with D below MIN_LENGTH (coincident ends: no direction to push along), is skipped.

k is the stick's weight: 1 while it holds, 0 once torn (kernels/tear.py), so a torn stick keeps its slot.

A soft stick is an XPBD constraint (Macklin, Mueller, Chentanez 2016) with compliance alpha (m/N): with
alpha~ = alpha / dt^2 and the tension mu accumulated over the substep's sweeps (zeroed at its start), a
projection moves by s = (D - L - alpha~ mu) / (w_i + w_j + alpha~) and adds s to mu. It converges to the
spring of stiffness 1 / alpha at any substep and iteration count, where a per-sweep stiffness fraction
would make the cloth softer with fewer sweeps. With alpha = 0 it is the rigid projection.

A coloured launch gives each thread ``per_thread`` consecutive sticks of the colour, projected in order: 1 on a GPU,
and on the CPU a thread team's whole piece (warp_verlet/launches.elements_per_thread), where Warp runs a launch's
threads one after another and a loop inside the kernel keeps its arguments and indices in registers. Within a
colour the order of the sticks cannot change a bit (a Jacobi gather takes its particles the same way: each
writes only its own). The kernels also test that a stick's index and its ends are not negative, which they never
are: Warp indexes arrays the Python way (a negative index counts from the end), and knowing the sign lets the
compiler drop that adjustment from every index after the test, a few integer operations per index that measured
a large share of a CPU projection (bench/results/code_choices.md).
"""

from typing import Any

import warp as wp

from .positions import for_positions, scaled

MIN_LENGTH = wp.constant(1.0e-9)


@wp.func
def stick_correction(xi: Any, xj: Any, wi: float, wj: float, rest: float, k: float):
    """The move of particle i, per unit of w_i, that satisfies the stick: x_i += w_i * result. Computed in the
    positions' precision (the float32 masses, rest length and weight are converted first)."""
    d = xj - xi
    length = wp.length(d)
    w = type(length)(wi) + type(length)(wj)
    if w == type(length)(0.0) or length < type(length)(MIN_LENGTH):
        return type(d)(0.0)
    return d * (type(length)(k) * (length - type(length)(rest)) / (length * w))


@wp.func
def compliant_correction(xi: Any, xj: Any, wi: float, wj: float, rest: float, k: float, compliance: float,
                         inv_dt2: float, tension: float):
    """The XPBD form of stick_correction (see the module docstring): the move of particle i per unit of w_i,
    and the stick's new tension mu. With compliance 0 it is stick_correction's move bit for bit."""
    d = xj - xi
    length = wp.length(d)
    w = type(length)(wi) + type(length)(wj)
    if w == type(length)(0.0) or length < type(length)(MIN_LENGTH):
        return type(d)(0.0), tension
    alpha = type(length)(compliance) * type(length)(inv_dt2)
    mu = type(length)(tension)
    # The same operations, in the same order, as stick_correction: with alpha = 0 this is the rigid move.
    error = type(length)(k) * (length - type(length)(rest) - alpha * mu)
    return d * (error / (length * (w + alpha))), float(mu + error / (w + alpha))


@wp.func
def project_rigid(
    s: int,
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
):
    """Stick s's projection (stick_correction); the stick owns its two particles within its colour."""
    e = ends[s]
    i = e[0]
    j = e[1]
    if i < 0 or j < 0:  # never true (the module docstring says why it is here)
        return
    wi = inv_mass[i]
    wj = inv_mass[j]
    xi = x[i]
    xj = x[j]
    c = stick_correction(xi, xj, wi, wj, rest[s], weight[s])
    x[i] = xi + scaled(c, wi)
    x[j] = xj - scaled(c, wj)


@wp.kernel
def relax_colour(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    first: int,
    per_thread: int,
):
    """Gauss-Seidel over one colour: sticks first .. first + dim * per_thread - 1 share no particle, so every thread
    owns its particles and the writes need no atomics and are deterministic. Thread t projects the ``per_thread``
    sticks from first + t * per_thread in order (warp_verlet/launches.elements_per_thread: 1 on a GPU, a CPU piece's
    every stick on the CPU); within a colour the order cannot change a bit."""
    s = first + wp.tid() * per_thread
    if s < 0:  # never true (the module docstring says why it is here)
        return
    stop = s + per_thread
    while s < stop:
        project_rigid(s, x, inv_mass, ends, rest, weight)
        s += 1


@wp.func
def project_compliant(
    s: int,
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    compliance: float,
    inv_dt2: float,
    tension: wp.array(dtype=float),
):
    """Stick s's XPBD projection (compliance 0: the rigid move), accumulating its tension mu."""
    e = ends[s]
    i = e[0]
    j = e[1]
    if i < 0 or j < 0:  # never true (the module docstring says why it is here)
        return
    wi = inv_mass[i]
    wj = inv_mass[j]
    xi = x[i]
    xj = x[j]
    c, mu = compliant_correction(xi, xj, wi, wj, rest[s], weight[s], compliance, inv_dt2, tension[s])
    tension[s] = mu
    x[i] = xi + scaled(c, wi)
    x[j] = xj - scaled(c, wj)


@wp.kernel
def relax_colour_compliant(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    compliance: wp.array(dtype=float),
    inv_dt2: float,
    first: int,
    per_thread: int,
    tension: wp.array(dtype=float),
):
    """XPBD over one colour (see the module docstring), ``per_thread`` sticks a thread as relax_colour; ``tension`` is
    mu, in N s^2, per stick. It is computed in the positions' precision and stored as float32: it restarts from 0
    every substep, so its rounding does not accumulate across steps."""
    s = first + wp.tid() * per_thread
    if s < 0:  # never true (the module docstring says why it is here)
        return
    stop = s + per_thread
    while s < stop:
        project_compliant(s, x, inv_mass, ends, rest, weight, compliance[s], inv_dt2, tension)
        s += 1


@wp.kernel
def relax_colour_tension(
    x: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    ends: wp.array(dtype=wp.vec2i),
    rest: wp.array(dtype=float),
    weight: wp.array(dtype=float),
    first: int,
    per_thread: int,
    tension: wp.array(dtype=float),
):
    """relax_colour for a cloth that tears by tension: the same moves bit for bit (compliant_correction with
    compliance 0), and each stick adds its Lagrange multiplier to ``tension`` (mu, N s^2, zeroed at the substep's
    start), so that mu / dt^2 is the force it transmitted over the substep (kernels/tear.py). Each stick is
    written only by the thread that projects it; ``per_thread`` sticks a thread, as relax_colour."""
    s = first + wp.tid() * per_thread
    if s < 0:  # never true (the module docstring says why it is here)
        return
    stop = s + per_thread
    while s < stop:
        project_compliant(s, x, inv_mass, ends, rest, weight, 0.0, 0.0, tension)
        s += 1


@wp.func
def gather_particle(
    i: int,
    x_in: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    neighbour_start: wp.array(dtype=int),
    neighbour: wp.array(dtype=int),
    neighbour_rest: wp.array(dtype=float),
    neighbour_weight: wp.array(dtype=float),
    x_out: wp.array(dtype=Any),
):
    """Particle i's Jacobi update (relax_jacobi), its sticks' corrections summed in their order."""
    xi = x_in[i]
    wi = inv_mass[i]
    if wi == 0.0:
        x_out[i] = xi
        return
    total = type(xi)(0.0)
    start = neighbour_start[i]
    end = neighbour_start[i + 1]
    if start < 0:  # never true (the module docstring says why it is here)
        return
    n = start
    while n < end:  # not range(), whose loop handles either sign of step: slower on the CPU
        j = neighbour[n]
        if j >= 0:  # never false (the module docstring)
            total += stick_correction(xi, x_in[j], wi, inv_mass[j], neighbour_rest[n], neighbour_weight[n])
        n += 1
    count = end - start
    if count > 0:
        xi = xi + total * (type(xi[0])(wi) / type(xi[0])(float(count)))
    x_out[i] = xi


@wp.kernel
def relax_jacobi(
    x_in: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=float),
    neighbour_start: wp.array(dtype=int),
    neighbour: wp.array(dtype=int),
    neighbour_rest: wp.array(dtype=float),
    neighbour_weight: wp.array(dtype=float),
    first: int,
    per_thread: int,
    x_out: wp.array(dtype=Any),
):
    """Jacobi: every particle gathers the corrections of all its sticks from the same old positions and
    applies their average (Mueller et al. 2007, section 3.5). The gather form needs no atomics, so the
    sum order is fixed and the result is bit-for-bit repeatable on every device. Threads cover particles
    first .. first + dim * per_thread - 1, ``per_thread`` each in order (a CPU thread team takes one piece each,
    warp_verlet/core/cpu_team.py; warp_verlet/launches.elements_per_thread: all of a piece's particles in one
    thread on the CPU, one a thread on a GPU)."""
    i = first + wp.tid() * per_thread
    if i < 0:  # never true (the module docstring says why it is here)
        return
    stop = i + per_thread
    while i < stop:
        gather_particle(i, x_in, inv_mass, neighbour_start, neighbour, neighbour_rest, neighbour_weight, x_out)
        i += 1


for_positions(relax_colour, arrays=("x",))
for_positions(relax_colour_compliant, arrays=("x",))
for_positions(relax_colour_tension, arrays=("x",))
for_positions(relax_jacobi, arrays=("x_in", "x_out"))
