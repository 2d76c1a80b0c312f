"""Which float type a scene's positions use, and the smallest step that type resolves.

Positions are float32 unless the scene's step is too small for float32. The limit: one step's acceleration
moves a particle by |a| dt^2, and when that is under 4 spacings of the float type at the scene's coordinates,
x + step rounds back (nearly) to x, the relaxation corrects the rounding-level stick errors, and that
correction enters the implicit velocity (summed-form Verlet, kernels/integrate.py) and cancels the
acceleration: in float32 a cloth at small enough steps fell short, or did not fall at all
(bench/results/code_choices.md). Without relaxation nothing feeds rounding back into velocity, so there is no limit.

float64 has the same limit 2^29 times lower in |a| dt^2 (about 1e-8 s for a 1 m scene under gravity, far
below the 1.7e-6 s of the most substeps a scene may ask for), so ``simulation.precision = "auto"`` (the
default) picks float64 exactly when the scene's dt is below the float32 limit.

This module imports neither warp nor the kernels: the memory estimate needs the resolved precision (a float64
position is 24 bytes, not 12) before anything is built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..input.scene import PRECISIONS  # noqa: F401  (the scene key's values, re-exported here)

if TYPE_CHECKING:  # pragma: no cover
    from ..input.scene import Scene, SimulationSettings

RESOLVED_SPACINGS = 4.0
"""|a| dt^2 must be at least this many spacings of the coordinates."""


def acceleration(settings: "SimulationSettings") -> float:
    """|gravity + wind|, m/s^2: the acceleration every free particle feels."""
    return float(np.linalg.norm(np.add(settings.gravity, settings.wind)))


def spacing_at(precision: str, scale: float) -> float:
    """One spacing of ``precision`` ("float32" or "float64") at coordinates as large as ``scale`` m (a scale under
    1 mm counts as 1 mm), m."""
    dtype = np.float32 if precision == "float32" else np.float64
    return float(np.spacing(dtype(max(scale, 1e-3))))


def smallest_dt(precision: str, accel: float, scale: float) -> float:
    """The smallest dt whose step |a| dt^2 is at least 4 spacings, in ``precision`` ("float32" or "float64"),
    of coordinates as large as ``scale`` m (a scale under 1 mm counts as 1 mm). 0 without acceleration."""
    if accel == 0.0:
        return 0.0
    return float(np.sqrt(RESOLVED_SPACINGS * spacing_at(precision, scale) / accel))


def coordinate_scale(scene: "Scene") -> float:
    """The largest |coordinate| of the scene's rest positions, m, from the cloth specs without building them:
    a mesh's from its particles; a grid spans its origin to origin + its size along its axes, and rounding to float32 keeps the largest
    magnitude at a corner (equal to ``np.abs(model.rest_positions).max()``, which tests/test_precision.py checks)."""
    corners = []
    for spec in scene.cloths:
        if spec.mesh is not None:  # a mesh's particles are known once the scene is loaded
            corners.extend(spec.mesh.mesh.particle_points)
            continue
        height, width = spec.size
        down = 1 if spec.orientation == "vertical" else 2
        sign = -1.0 if spec.orientation == "vertical" else 1.0
        for r in (0.0, height if spec.resolution[0] > 1 else 0.0):
            for c in (0.0, width if spec.resolution[1] > 1 else 0.0):
                p = np.zeros(3)
                p[0] = c
                p[down] = sign * r
                corners.append(p + np.asarray(spec.origin, np.float64))
    return float(np.abs(np.asarray(corners).astype(np.float32)).max())


def resolve(scene: "Scene", relaxes: bool) -> str:
    """"float32" or "float64": the scene's ``simulation.precision``, with "auto" resolved from its dt.
    ``relaxes``: whether a substep runs the relaxation (without it there is no limit, so auto is float32)."""
    asked = scene.simulation.precision
    if asked != "auto":
        return asked
    if not relaxes:
        return "float32"
    limit = smallest_dt("float32", acceleration(scene.simulation), coordinate_scale(scene))
    return "float64" if scene.simulation.dt < limit else "float32"
