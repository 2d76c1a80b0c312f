"""Scenes that load but will not do what they say: warnings that ``validate`` and ``run`` print before a run.

Each check is a pure function of a validated :class:`~warp_verlet.input.scene.Scene` that returns messages (one line
each: what is wrong, why, and what to change). None of them refuses the scene; that is the loader's work
(``scene.py``). Host arithmetic only (numpy): ``validate`` imports none of warp and pxr.

- tethers that make tearing impossible (:func:`tether_warnings`);
- a cloth that starts inside a collider (:func:`start_inside_warnings`);
- a collider of thickness 0, on whose visible surface the cloth rests (:func:`thickness_warnings`);
- sticks that the run's own check will find at more than twice their length (:func:`stretch_warnings`).
"""

from __future__ import annotations

import math

import numpy as np

from ..colliders import kind_of
from .scene import ClothSpec, Scene

# runner.UNCONVERGED_STRETCH, the run's own check (a structural stick at twice its rest length), repeated here
# so that validate does not import the runner; tests/test_scene_warnings.py checks that the two agree.
UNCONVERGED_STRETCH = 1.0


def scene_warnings(scene: Scene) -> list[str]:
    """Every warning for ``scene``, in the order of the checks above."""
    return [*tether_warnings(scene), *start_inside_warnings(scene), *thickness_warnings(scene),
            *stretch_warnings(scene)]


def _g(x: float) -> str:
    return f"{x:.4g}"


# ------------------------------------------------------------------------------------------------ tethers


def tether_warnings(scene: Scene) -> list[str]:
    """A tether holds a free particle within ``tether_scale`` x its rest distance of its pin (kernels/tether.py),
    and a stick tears when it is longer than ``tear_threshold`` x its rest length (kernels/tear.py). With
    tether_scale <= tear_threshold, the tethers hold the cloth short of the stretch a tear needs: only what the
    stick sweeps after the tether pass pull past them can still tear a stick (tests/test_scene_warnings.py: a
    hanging 8 x 8 grid at 200 g tears without tethers and not at all with tethers at tether_scale 1). Not a
    sharp bound: that grid still tears at tether_scale 1.29 against a tear_threshold of 1.3 (the same test), so
    the warning says what the tethers do rather than that nothing can tear."""
    out = []
    for spec in scene.cloths:
        if not spec.uses_tethers or spec.tear_threshold is None:
            continue
        if spec.tether_scale <= spec.tear_threshold:
            out.append(
                f"cloth '{spec.name}': tethers with tether_scale = {_g(spec.tether_scale)} <= tear_threshold = "
                f"{_g(spec.tear_threshold)}: the tethers hold every particle within tether_scale x its rest "
                "distance of a pin, short of the stretch a tear needs, so a stick tears only where the sweeps "
                "after the tethers pull it further, if at all; to let it tear, raise tether_scale above "
                f"{_g(spec.tear_threshold)} or set tethers = false")
    return out


# ------------------------------------------------------------------------------------- the rest pose


def rest_positions(spec: ClothSpec) -> np.ndarray:
    """The cloth's particles at the start, (N, 3) float64, as topology.build_cloth places them."""
    if spec.mesh is not None:
        return np.asarray(spec.mesh.mesh.particle_points, np.float64)
    from ..geometry.topology import grid_positions  # numpy only

    return np.asarray(grid_positions(spec), np.float64)


def pinned_mask(spec: ClothSpec, count: int) -> np.ndarray:
    mask = np.zeros(count, bool)
    if spec.mesh is not None:
        mask[list(spec.mesh.pins)] = True
    else:
        cols = spec.resolution[1]
        mask[[r * cols + c for r, c in spec.pins]] = True
    return mask


def particle_spacing(spec: ClothSpec) -> float:
    """A grid's smaller spacing (size / (n - 1) along an axis of n > 1 particles); a mesh's median edge."""
    if spec.mesh is None:
        gaps = [s / (n - 1) for n, s in zip(spec.resolution, spec.size) if n > 1]
        return min(gaps)
    mesh = spec.mesh.mesh
    pairs, _ = mesh.faces.sides()
    points = np.asarray(mesh.particle_points, np.float64)
    lengths = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    lengths = lengths[lengths > 0]
    return float(np.median(lengths)) if len(lengths) else 0.0


# -------------------------------------------------------------------------------- inside a collider


def start_inside_warnings(scene: Scene) -> list[str]:
    """Particles that start where the collider clamp would move them on the first substep, as each collider's
    kind finds them (``start_inside``): closer than radius + thickness to a sphere's centre (at time 0), or less
    than thickness above a plane on its free side. The clamp moves them out at once, a jump that Verlet turns
    into velocity; pinned ones it never moves, so they stay inside."""
    if not scene.colliders:
        return []
    out = []
    for spec in scene.cloths:
        points = rest_positions(spec)
        pinned = pinned_mask(spec, len(points))
        for collider in scene.colliders:
            report = kind_of(collider).start_inside(collider, points)
            inside, where, fix = report.inside, report.where, report.fix
            count = int(inside.sum())
            if not count:
                continue
            stuck = int((inside & pinned).sum())
            pins = f"; {stuck} of them pinned, which stay there (pins never move)" if stuck else ""
            out.append(f"cloth '{spec.name}' starts with {count} of {len(points)} particles {where}: the first "
                       f"substep pushes them out at once, a jump that becomes velocity{pins}; {fix}")
    return out


# ------------------------------------------------------------------------------------------ thickness


def thickness_warnings(scene: Scene) -> list[str]:
    """A collider of thickness 0 keeps the cloth on its visible surface, where the two z-fight in a render.
    Half the finest cloth's particle spacing keeps them apart without a visible gap."""
    zero = [c for c in scene.colliders if c.thickness == 0.0]
    if not zero:
        return []
    finest = min(scene.cloths, key=particle_spacing)
    suggestion = 0.5 * particle_spacing(finest)
    return [f"collider '{c.name}' has thickness 0: the cloth comes to rest on its visible surface and z-fights "
            f"with it in renders; give it a thickness, about half the finest cloth's particle spacing (cloth "
            f"'{finest.name}': thickness = {suggestion:.2g})" for c in zero]


# --------------------------------------------------------------------------------------------- stretch


def free_fall(scene: Scene) -> float:
    """How far a free particle falls in the whole run under gravity + wind and damping alone: the scene's
    Verlet recurrence x' = x + k (x - x_prev) + |a| dt^2 with k = exp(-damping dt), from rest, over its N steps,
    in closed form (a run may have billions of steps). Its increments v_n = |a| dt^2 (1 - k^n) / (1 - k) sum to
    |a| dt^2 / (1 - k) (N - k (1 - k^N) / (1 - k)); without damping, |a| dt^2 N (N + 1) / 2."""
    sim = scene.simulation
    a = math.hypot(*(g + w for g, w in zip(sim.gravity, sim.wind)))
    dt, steps = sim.dt, sim.frames * sim.substeps
    loss = -math.expm1(-sim.damping * dt)  # 1 - k, without the rounding of 1 - exp(...)
    if loss * steps < 1e-6:  # damping too weak to matter over the run (and the closed form would cancel)
        return a * dt * dt * steps * (steps + 1) / 2
    kept = -math.expm1(-sim.damping * dt * steps) / loss  # (1 - k^N) / (1 - k)
    return a * dt * dt / loss * (steps - (1.0 - loss) * kept)


def stretch_warnings(scene: Scene) -> list[str]:
    """The one case the stretch check can be predicted without running: no sweeps (iterations = 0), so no
    stick, tether or coarse level holds anything, and no collider to stop a fall. Then a pinned grid's free
    particles fall freely, and a stick from a pin to its free neighbour, of rest length L, is at least d - L
    long after a fall of d: over twice its length once d > 3 L. Anything else depends on the run (how far a
    correction travels in the sweeps a frame has against the load); the run's summary then names the cloth
    and the budget it ran at (runner.RunSummary)."""
    sim = scene.simulation
    if sim.iterations != 0 or scene.colliders or sim.multilevel:
        return []
    pinned = [c for c in scene.cloths
              if c.mesh is None and "structural" in c.sticks and 0 < c.pin_count < c.particle_count]
    if not pinned:
        return []
    fall = free_fall(scene)
    out = []
    for spec in pinned:
        longest = max(s / (n - 1) for n, s in zip(spec.resolution, spec.size) if n > 1)
        if fall > (2.0 + UNCONVERGED_STRETCH) * longest:
            out.append(
                f"cloth '{spec.name}': iterations = 0 relaxes no stick, so its free particles fall {_g(fall)} m in "
                f"{sim.frames} frames while its pins hold, and the sticks at the pins end at over "
                f"{1 + UNCONVERGED_STRETCH:g} x their length (the run will warn that the relaxation has not "
                "converged); give it iterations (at least 1), or target_stretch to choose the substeps")
    return out
