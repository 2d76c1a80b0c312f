"""The two position types, and the instantiation of the generic kernels that read or write positions.

Positions (the State's ``particle_q``, ``particle_q_inertial``, ``particle_dq`` and the Jacobi scratch) are
``wp.vec3`` (float32) or ``wp.vec3d`` (float64), chosen per scene (warp_verlet/core/precision.py). Every kernel that
touches them is one generic source (``typing.Any`` for the position arrays and for the scalars in position
units); everything else it reads (masses, rest lengths, weights, collider data) stays float32 and is
converted to the position scalar inside, where float32 to float32 is the identity: the float32 instance
computes exactly what the float32-only kernel did.

Both instances are declared when a kernel module is imported, so a module is compiled once with both and
never reloaded at the first launch of the other type (a reload cannot happen inside a CUDA graph capture).
"""

from typing import Any

import warp as wp

POSITION_TYPES = ((wp.vec3f, wp.float32), (wp.vec3d, wp.float64))
"""(vector, scalar) of float32 and of float64 positions."""

_INSTANCES: dict = {}  # (generic kernel, position vector type) -> its concrete instance


def for_positions(kernel, arrays: tuple[str, ...] = (), vectors: tuple[str, ...] = (), scalars: tuple[str, ...] = ()):
    """Instantiate a generic ``kernel`` for both position types: ``arrays`` name its position arrays,
    ``vectors`` and ``scalars`` its arguments in position units (m, or the step's factors)."""
    for vec, real in POSITION_TYPES:
        types = {name: wp.array(dtype=vec) for name in arrays}
        types.update({name: vec for name in vectors})
        types.update({name: real for name in scalars})
        _INSTANCES[kernel, vec] = wp.overload(kernel, types)
    return kernel


def instance(kernel, vec):
    """The concrete instance of ``kernel`` for positions of type ``vec``. Launching it directly skips the
    inference of the generic argument types that ``wp.launch`` does on every call, which costs more than the
    launch itself on the CPU (bench/results/code_choices.md); it matters for a launch issued every substep
    outside a capture."""
    return _INSTANCES[kernel, vec]


@wp.func
def scaled(v: Any, s: float):
    """``v * s`` with the float32 ``s`` converted to ``v``'s scalar type first."""
    return v * type(v[0])(s)


@wp.func
def to_vec3(v: Any):
    """A vector of the positions' type as float32 (the identity for float32): for a correction or a direction,
    which need not the positions' precision."""
    return wp.vec3(float(v[0]), float(v[1]), float(v[2]))


@wp.func
def shifted(x: Any, d: wp.vec3, s: float):
    """``x + s d``, with the float32 move ``s d`` converted to ``x``'s type first."""
    return x + type(x)(type(x[0])(d[0] * s), type(x[0])(d[1] * s), type(x[0])(d[2] * s))
