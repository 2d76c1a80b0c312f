"""Float64 positions (``simulation.precision``): below the float32 floor on dt a cloth still falls as it should,
"auto" picks the type from the scene's dt, float32 stays refused there with an error naming the key, and the
float64 path is exact, deterministic and agrees with float32 where both resolve the step."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.errors import SceneError, WarpVerletError
from warp_verlet.core.memory import estimate
from warp_verlet.core.precision import coordinate_scale, smallest_dt
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

EPS64 = float(np.finfo(np.float64).eps)
G = np.array([0.0, -9.81, 0.0])
KEY = 'simulation.precision = "float64"'


def no_pushes():
    """The clamp kernels' empty ``pushes`` (collide_response.py): no stage reads their pushes here."""
    return wp.empty(0, dtype=wp.vec3)


def falling_cloth(precision: str, substeps: int, iterations: int = 4):
    """A free (unpinned) 9 x 9 cloth, 1 m, whose rest lengths (0.125 and 0.25 m, structural and bend) and
    coordinates are exact in float32, so that float64 starts with no stick error at all."""
    return make_scene({"fps": 60, "substeps": substeps, "iterations": iterations, "precision": precision},
                      resolution=[9, 9], size=[1.0, 1.0], origin=[0.25, 2.0, -0.5], sticks=["structural", "bend"])


@pytest.mark.parametrize("precision, gravity", [("float64", 1e-30), ("auto", 1e-12), ("float32", 1e-6)])
def test_an_acceleration_too_weak_for_any_substep_is_named_with_what_fixes_it(precision, gravity):
    # Below 4 float spacings per frame squared, no substep count resolves the acceleration: the error must name
    # gravity and wind and the weakest |a| this frame rate and precision resolve, not suggest fewer substeps.
    scene = make_scene({"fps": 60, "substeps": 1, "precision": precision, "gravity": [0.0, -gravity, 0.0]},
                       resolution=[4, 4], size=[1.0, 1.0], pins=["top-left"])
    with pytest.raises(WarpVerletError, match="even one substep a frame is too short") as refused:
        Simulator(scene, "cpu")
    message = str(refused.value)
    p = "float32" if precision == "float32" else "float64"
    weakest = 4 * float(np.spacing(np.float32(1.0) if p == "float32" else 1.0)) * 60.0 ** 2  # scale 1 m: the cloth's
    assert f"must be 0 or at least {weakest:.2g} m/s^2" in message and "simulation.gravity" in message
    assert "fewer simulation.substeps" not in message
    # At that bound one substep a frame is accepted.
    ok = make_scene({"fps": 60, "substeps": 1, "precision": p, "gravity": [0.0, -1.01 * weakest, 0.0]},
                    resolution=[4, 4], size=[1.0, 1.0], pins=["top-left"])
    Simulator(ok, "cpu").step_frame()


def fall_error(sim: Simulator, x0: np.ndarray, t: float) -> float:
    """max |x - (x0 + g t^2 / 2)| over particles, relative to the fall g t^2 / 2."""
    exact = x0 + 0.5 * G * t * t
    return float(np.abs(sim.positions().astype(np.float64) - exact).max() / (0.5 * 9.81 * t * t))


# ---------------------------------------------------------------------------------------------- below the floor


@pytest.mark.slow
def test_a_free_cloth_falls_freely_at_1000_substeps_in_float64(device):
    # dt = 1/60000 s: g dt^2 = 2.7e-9 m, a hundredth of a float32 spacing at y = 2 m (the floor here is
    # 3.12e-4 s: 53 substeps per frame at most). In float64 the sticks are relaxed 4 times per substep and the cloth still falls as
    # x0 + g t^2 / 2: every particle within 1e-9 of the fall after 20 frames (measured 1.7e-10 on the CPU; what
    # remains is the same rounding feedback as the float32 floor, with spacings 2^29 times finer).
    sim = Simulator(falling_cloth("float64", 1000), device)
    assert sim.precision == "float64" and sim.state.particle_q.dtype == wp.vec3d
    x0 = sim.positions()
    assert x0.dtype == np.float64
    for _ in range(20):
        sim.step_frame()
    assert fall_error(sim, x0, 20 / 60) < 1e-9

    # The same steps in float32 are refused, naming the key; forced past the check they fall short.
    with pytest.raises(WarpVerletError, match="too small for float32 positions") as refused:
        Simulator(falling_cloth("float32", 1000), device)
    assert KEY in str(refused.value) and "fewer simulation.substeps" in str(refused.value)
    f32 = Simulator(falling_cloth("float32", 4), device)
    x0 = f32.positions().astype(np.float64)
    for _ in range(20 * 1000):
        f32.solver.step(f32.state, 1 / 60000)  # no check_step: what the check prevents
    # Short by 0.27 of the 0.55 m fall on the CPU and by 1.8e-3 of it on CUDA (an H100, whose compiler contracts the
    # steps into FMAs that round differently): the relaxation's rounding cancels gravity. 1e-4 of the fall (55 um,
    # over 200 float32 spacings at 2 m) is 1e5 times the float64 bound above.
    assert fall_error(f32, x0, 20 / 60) > 1e-4


def test_float64_exact_start_and_free_fall(device):
    # The integrator alone (no sweeps): the first step lands on x0 + g dt^2 / 2 (in float32 it would round
    # back to x0: g dt^2 / 2 = 1.4e-9 m is under half a spacing at 2 m), and every frame is on x0 + g t^2 / 2
    # within the float64 analogue of test_integrate's budget (one rounding of increment and coordinate per step).
    sim = Simulator(falling_cloth("float64", 1000, iterations=0), device)
    x0 = sim.positions()
    sim.step()
    dt = 1 / 60000
    np.testing.assert_allclose(sim.positions(), x0 + 0.5 * G * dt * dt, rtol=0, atol=4 * np.spacing(2.0))
    sim.reset()
    for frame in range(1, 11):
        sim.step_frame()
        t = frame / 60
        exact = x0 + 0.5 * G * t * t
        error = np.abs(sim.positions() - exact).max()
        assert error <= frame * 1000 * EPS64 * (0.5 * 9.81 * t * t + np.abs(exact).max()), (frame, error)


def test_float64_min_dt_is_the_float64_analogue():
    # 4 float64 spacings of the coordinates: 1.35e-8 s for this 2 m scene; a step below it is refused.
    sim = Simulator(falling_cloth("float64", 1000), "cpu")
    assert sim.min_dt == smallest_dt("float64", 9.81, 2.0) == pytest.approx(1.35e-8, rel=0.01)
    with pytest.raises(WarpVerletError, match="too small for float64 positions"):
        sim.step(1e-8)


# ---------------------------------------------------------------------------------------------- auto


@pytest.mark.parametrize("substeps, iterations, expected", [
    (4, 4, "float32"), (53, 4, "float32"), (54, 4, "float64"), (1000, 4, "float64"),
    (1000, 0, "float32"),  # no relaxation, no floor: the integrator alone is exact in float32 at any dt
])
def test_auto_picks_float64_below_the_float32_floor_only(substeps, iterations, expected):
    # The floor for this 2 m scene is 3.12e-4 s: 1 / (60 x 53) = 3.14e-4 s is above it, 1 / (60 x 54) below.
    scene = falling_cloth("auto", substeps, iterations)
    sim = Simulator(scene, "cpu")
    assert sim.precision == expected
    assert sim.state.particle_q.dtype == (wp.vec3d if expected == "float64" else wp.vec3)
    assert sim.state.particle_dq.dtype == sim.state.particle_q_inertial.dtype == sim.state.particle_q.dtype
    assert sim.model.inv_mass.dtype == wp.float32  # only positions change type


def test_the_memory_estimate_counts_24_bytes_per_float64_position():
    # Positions, prediction and increment per particle, plus the Jacobi scratch position: 12 bytes more each.
    for solver, positions in (("coloured", 3), ("jacobi", 4)):
        f32, f64 = (estimate(make_scene({"relaxation": solver, "precision": p}, resolution=[10, 12]))
                    for p in ("float32", "float64"))
        assert f64.device_bytes - f32.device_bytes == 120 * positions * 12


@pytest.mark.parametrize("cloth", [
    {"resolution": [9, 9], "size": [1.0, 1.0], "origin": [0.25, 2.0, -0.5]},
    {"resolution": [5, 7], "size": [0.3, 2.7], "origin": [-3.1, 0.2, 1.7], "orientation": "horizontal"},
    {"resolution": [1, 20], "size": [0.0, 0.7], "origin": [-0.35, 0.1, 0.0]},
    {"resolution": [6, 1], "size": [1e-4, 0.0], "origin": [0.0, 0.0, 0.0]},
])
def test_coordinate_scale_from_the_specs_is_that_of_the_built_model(cloth):
    # "auto" is resolved before anything is built (the memory estimate needs it), from the cloth specs.
    scene = parse_scene({"cloth": [cloth, {"name": "b", "resolution": [2, 2], "size": [0.1, 0.1]}]}, file="<test>")
    sim = Simulator(scene, "cpu")
    assert coordinate_scale(scene) == float(np.abs(sim.model.rest_positions).max())


# ---------------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize("value, got", [("'double'", "str 'double'"), ("64", "int 64"), ("true", "boolean true"),
                                        ("'Float64'", "str 'Float64'")])
def test_a_bad_precision_names_the_key_and_the_choices(tmp_path, value, got):
    from warp_verlet.input.scene import load_scene

    path = tmp_path / "scene.toml"
    path.write_text(f"[simulation]\nprecision = {value}\n[[cloth]]\nresolution = [2, 2]\nsize = [1, 1]\n")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert info.value.key == "simulation.precision"
    assert str(info.value) == f"{path}: simulation.precision: expected one of 'auto', 'float32', 'float64', got {got}"


def test_float32_below_its_floor_names_the_new_key():
    # Explicit float32 with the scene's own dt below the floor: refused when the simulator starts (above), and a
    # step(dt) below it on a float32 simulator (auto resolved float32 from the scene's dt) is refused as well.
    sim = Simulator(falling_cloth("auto", 4), "cpu")
    assert sim.precision == "float32"
    with pytest.raises(WarpVerletError, match="smallest dt resolved here is 0.000312 s") as refused:
        sim.step(1e-5)
    assert KEY in str(refused.value) and "substeps" not in str(refused.value)


# ---------------------------------------------------------------------------------------------- every kernel


def launch_both(kernel, dim: int, make, device: str) -> list[list[np.ndarray]]:
    """Launch ``kernel`` once with float32 and once with float64 positions: ``make(vec, real)`` returns its
    arguments for that position type. Returns, per precision, every array argument after the launch."""
    out = []
    for vec, real in ((wp.vec3, wp.float32), (wp.vec3d, wp.float64)):
        with wp.ScopedDevice(device):
            args = make(vec, real)
            wp.launch(kernel, dim, inputs=args)
        out.append([a.numpy() for a in args if isinstance(a, wp.array)])
    return out


def kernel_cases():
    """(name, kernel, dim, make) for every kernel that reads or writes positions, on random float32 data:
    positions within 2 m, masses with pins among them, stretched and compressed sticks, friction."""
    from warp_verlet.kernels import collide_plane, collide_sphere, guard, integrate, relax, tear, tether

    rng = np.random.default_rng(11)
    n = 4000
    x = rng.uniform(-2.0, 2.0, (n, 3)).astype(np.float32)
    x_in = (x + rng.normal(0.0, 1e-3, (n, 3))).astype(np.float32)
    dq = rng.normal(0.0, 1e-3, (n, 3)).astype(np.float32)
    w = rng.choice([0.0, 0.5, 1.0, 4.0], n).astype(np.float32)
    ends = np.arange(n, dtype=np.int32).reshape(-1, 2)
    length = np.linalg.norm(x[ends[:, 1]] - x[ends[:, 0]], axis=1)
    rest = (length * rng.uniform(0.7, 1.3, len(ends))).astype(np.float32)
    ones = np.ones(len(ends), np.float32)
    start = np.r_[0, np.cumsum(np.full(n, 2))].astype(np.int32)  # every particle: two random neighbours
    nbr = rng.integers(0, n, 2 * n).astype(np.int32)
    nbr_rest = (np.linalg.norm(x[nbr] - np.repeat(x, 2, axis=0), axis=1) * rng.uniform(0.7, 1.3, 2 * n)).astype(np.float32)
    pinned = np.flatnonzero(w == 0)[:2].astype(np.int32)
    free = np.flatnonzero(w > 0).astype(np.int32)
    reach = np.linalg.norm(x[free][:, None] - x[pinned][None], axis=2) * rng.uniform(0.5, 1.5, (len(free), 2))
    tether_pin = np.full((n, 2), -1, np.int32)  # a row per particle (constraints/tethers.TetherTable)
    tether_pin[w == 0, 0] = -2
    tether_pin[free] = pinned
    tether_length = np.full((n, 2), np.inf, np.float32)
    tether_length[free] = reach

    def f(a, dtype=float):
        return wp.array(a, dtype=dtype)

    def q(vec, a=x):
        return wp.array(a, dtype=vec)

    return [
        ("verlet_start", integrate.verlet_start, n,
         lambda vec, real: [q(vec), f(w), vec(1.5, -9.81, 2.0), real(1 / 240), q(vec, x_in), q(vec, dq)]),
        ("verlet_step", integrate.verlet_step, n,
         lambda vec, real: [q(vec), q(vec, x_in), q(vec, dq), f(w), real(0.99), vec(1e-4, -6e-4, 2e-5)]),
        ("relax_colour", relax.relax_colour, len(ends),
         lambda vec, real: [q(vec), f(w), f(ends, wp.vec2i), f(rest), f(ones), 0, 1]),
        ("relax_colour_compliant", relax.relax_colour_compliant, len(ends),
         lambda vec, real: [q(vec), f(w), f(ends, wp.vec2i), f(rest), f(ones), f(np.full(len(ends), 1e-4, np.float32)),
                            57600.0, 0, 1, f(np.zeros(len(ends), np.float32))]),
        ("relax_jacobi", relax.relax_jacobi, n,
         lambda vec, real: [q(vec), f(w), f(start, int), f(nbr, int), f(nbr_rest), f(np.ones(2 * n, np.float32)), 0,
                            1, q(vec, np.zeros_like(x))]),
        ("pull_tethers", tether.pull_tethers, n,
         lambda vec, real: [q(vec), 0, wp.array2d(tether_pin, dtype=int), wp.array2d(tether_length, dtype=float), 1]),
        ("collide_planes", collide_plane.collide_planes, n,
         lambda vec, real: [q(vec), q(vec, x_in), q(vec, dq), f(w), f(np.array([[0.0, -0.5, 0.0], [1.0, 0.0, 0.0]],
                            np.float32), wp.vec3), f(np.array([[0.0, 1.0, 0.0], [-0.6, 0.0, 0.8]], np.float32), wp.vec3),
                            f(np.array([0.01, 0.0], np.float32)),
                            f(np.array([[0.3, 0.4], [0.0, 0.0]], np.float32), wp.vec2), no_pushes(), 0]),
        ("collide_spheres", collide_sphere.collide_spheres, n,
         lambda vec, real: [q(vec), q(vec, x_in), q(vec, dq), f(w), f(np.array([[0.5, 0.5, 0.0], [-1.0, 0.0, 1.0]],
                            np.float32), wp.vec3), f(np.array([1.0, 0.7], np.float32)),
                            f(np.array([[0.4, 0.5], [0.0, 0.0]], np.float32), wp.vec2), no_pushes(), 0]),
        ("tear_sticks", tear.tear_sticks, len(ends),
         lambda vec, real: [q(vec), f(ends, wp.vec2i), f(rest), f(ones), f(np.zeros(1, np.int32), int)]),
        ("find_diverged", guard.find_diverged, n,
         lambda vec, real: [q(vec), 1.9, f(np.full(1, n, np.int32), int)]),
    ]


@pytest.mark.parametrize("case", range(10), ids=lambda k: kernel_cases()[k][0])
def test_every_position_kernel_computes_the_same_in_float64(device, case):
    # One launch each from the same float32 data: the float64 instance must agree with the float32 one to a few
    # float32 roundings (positions to 8 spacings at 2 m; XPBD tensions to the rounding of D - L over w + alpha~;
    # tear flags, counters and the diverged index exactly). A float64 kernel that dropped a term or a conversion would be off by far
    # more: the moves here are 1e-3 to 1 m.
    name, kernel, dim, make = kernel_cases()[case]
    f32, f64 = launch_both(kernel, dim, make, device)
    for a, b in zip(f32, f64):
        if a.dtype.kind in "iu" or name == "tear_sticks":
            assert np.array_equal(a, b), name
        elif a.ndim == 2:  # positions
            np.testing.assert_allclose(b, a, rtol=0, atol=8 * np.spacing(np.float32(2.0)), err_msg=name)
        else:  # XPBD tension (D - L) / (w + alpha~): float32 rounds D (sticks up to 7 m) and w + alpha~ >= 5.76
            np.testing.assert_allclose(b, a, rtol=1e-5, atol=4 * np.spacing(np.float32(8.0)) / 5.76, err_msg=name)
    with wp.ScopedDevice(device):
        inputs = [m.numpy() for m in make(wp.vec3, wp.float32) if isinstance(m, wp.array)]
    assert any(not np.array_equal(a, b0) for a, b0 in zip(f32, inputs)), f"{name} changed nothing"


D = 1e-11  # m: 1e-4 of a float32 spacing at 1.25 m, so only float64 arithmetic throughout sees it
X = 1.25  # exact in float32, as the collider data and rest lengths below


def f64_case(name: str):
    """(kernel, dim, arguments, check) for one kernel on float64 positions, set up so that the right answer
    differs from the input by D or by D / 3."""
    from warp_verlet.kernels import collide_plane, collide_sphere, guard, integrate, relax, tear, tether

    def q(*rows):
        return wp.array(np.array(rows, np.float64), dtype=wp.vec3d)

    def f(*values, dtype=float):
        return wp.array(np.array(values), dtype=dtype)

    stick = lambda: q([X, 0, 0], [X + 0.125 + D, 0, 0])  # noqa: E731  rest 0.125 m, stretched by D
    moved = [[X + D / 2, 0, 0], [X + 0.125 + D / 2, 0, 0]]  # equal masses: each end takes half
    ends = lambda: f([0, 1], dtype=wp.vec2i)  # noqa: E731
    planes = (f([0.0, X, 0.0], dtype=wp.vec3), f([0.0, 1.0, 0.0], dtype=wp.vec3), f(0.0), f([0.0, 0.0], dtype=wp.vec2),
              no_pushes(), 0)
    cases = {
        "verlet_step": (integrate.verlet_step, 1,
                        [q([X, X, X]), q([X, X, X]), q([D, 0, 0]), f(1.0), wp.float64(1.0), wp.vec3d(0.0, -2 * D, 0.0)],
                        {0: [[X + D, X - 2 * D, X]], 2: [[D, -2 * D, 0]]}),
        "relax_colour": (relax.relax_colour, 1, [stick(), f(1.0, 1.0), ends(), f(0.125), f(1.0), 0, 1], {0: moved}),
        # alpha~ = 1e-4 m/N x 1e4 / s^2 = 1: each end moves w D / (w_i + w_j + alpha~) = D / 3, the tension is D / 3.
        "relax_colour_compliant": (relax.relax_colour_compliant, 1, [stick(), f(1.0, 1.0), ends(), f(0.125), f(1.0),
                                   f(1e-4), 1e4, 0, 1, f(0.0)], {0: [[X + D / 3, 0, 0], [X + 0.125 + 2 * D / 3, 0, 0]],
                                                                  9: [D / 3]}),
        "relax_jacobi": (relax.relax_jacobi, 2, [stick(), f(1.0, 1.0), f(0, 1, 2, dtype=int), f(1, 0, dtype=int),
                         f(0.125, 0.125), f(1.0, 1.0), 0, 1, q([0, 0, 0], [0, 0, 0])], {8: moved}),
        "pull_tethers": (tether.pull_tethers, 1, [q([X, X, X], [X + 0.5 + D, X, X]), 1,
                         wp.array2d(np.array([[0]]), dtype=int), wp.array2d(np.array([[0.5]]), dtype=float), 1],
                         {0: [[X, X, X], [X + 0.5, X, X]]}),
        "collide_planes": (collide_plane.collide_planes, 1, [q([0.7, X - D, 0.2]), q([0.7, X - D, 0.2]), q([0, 0, 0]),
                           f(1.0), *planes], {0: [[0.7, X, 0.2]]}),
        "collide_spheres": (collide_sphere.collide_spheres, 1, [q([X + 0.5 - D, 0, 0]), q([X + 0.5 - D, 0, 0]), q([0, 0, 0]),
                            f(1.0), f([X, 0.0, 0.0], dtype=wp.vec3), f(0.5), f([0.0, 0.0], dtype=wp.vec2),
                            no_pushes(), 0],
                            {0: [[X + 0.5, 0, 0]]}),
        # Sticks D longer and D shorter than their 0.25 m tear length: only the first tears.
        "tear_sticks": (tear.tear_sticks, 2, [q([X, 0, 0], [X + 0.25 + D, 0, 0], [X, 1, 0], [X + 0.25 - D, 1, 0]),
                        f([0, 1], [2, 3], dtype=wp.vec2i), f(0.25, 0.25), f(1.0, 1.0), f(0, dtype=int)],
                        {3: [0.0, 1.0], 4: [1]}),
        "find_diverged": (guard.find_diverged, 2, [q([1.5 - D, 0, 0], [0, 0, 1.5 + D]), 1.5, f(2, dtype=int)], {2: [1]}),
    }
    return cases[name]


F64_CASES = ["verlet_step", "relax_colour", "relax_colour_compliant", "relax_jacobi", "pull_tethers", "collide_planes",
             "collide_spheres", "tear_sticks", "find_diverged"]


@pytest.mark.parametrize("name", F64_CASES)
def test_every_position_kernel_resolves_moves_far_below_a_float32_spacing(device, name):
    # Each float64 kernel must compute in float64 throughout: a move or an error of D = 1e-11 m at coordinates of
    # 1.25 m (1e-4 of a float32 spacing) comes out right to a few float64 spacings. A kernel that rounded any
    # step through float32 (the stick error D - L, a tether's distance, a collider's depth) would move nothing.
    with wp.ScopedDevice(device):
        kernel, dim, args, expected = f64_case(name)
        wp.launch(kernel, dim, inputs=args)
    for index, value in expected.items():
        got = args[index].numpy()
        atol = 8 * np.spacing(2.0) if got.dtype == np.float64 else 1e-6 * np.abs(value).max()  # float32 tension
        np.testing.assert_allclose(got, np.array(value, dtype=got.dtype), rtol=0, atol=atol, err_msg=name)


def busy(precision: str, solver: str = "coloured"):
    """Every float64 kernel at once: pins with tethers, soft sticks, a sphere rising through the cloth (it
    tears), and a plane."""
    cloth = {"resolution": [14, 14], "size": [1.0, 1.0], "origin": [-0.5, 0.6, 0.0], "orientation": "horizontal",
             "sticks": ["structural", "shear", "bend"], "pins": ["top-edge"], "tear_threshold": 1.1,
             "tethers": True, "tether_scale": 2.0}
    if solver == "coloured":
        cloth["compliance"] = {"bend": 1e-3}
    colliders = [{"type": "sphere", "radius": 0.2, "friction_coefficient": 0.3, "path": [[0.0, 0.0, 0.0, 0.6], [0.4, 0.0, 1.2, 0.6]]},
                 {"type": "plane", "point": [0.0, -0.4, 0.0], "friction_coefficient": 0.5, "thickness": 0.01}]
    return parse_scene({"simulation": {"fps": 60, "substeps": 8, "iterations": 6, "relaxation": solver,
                                       "precision": precision}, "cloth": [cloth], "collider": colliders},
                       file="<test>")


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_two_float64_runs_are_bit_identical(device, solver):
    # On the CPU the second run cuts the relaxation over two threads (and is not captured): still the same bits.
    runs = []
    for threads in (1, 2) if device == "cpu" else (None, None):
        sim = Simulator(busy("float64", solver), device, threads=threads)
        frames = []
        for _ in range(24):
            sim.step_frame()
            sim.sync_tears()  # drops the tethers of torn-off pieces, as the runner does
            frames.append(sim.positions())
        runs.append((np.array(frames), sim.torn_count()))
    assert runs[0][1] > 0  # it tore: tear_sticks and the tether cut ran in float64
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


def test_the_cache_gets_float32_points_from_a_float64_run(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_verlet.apps.runner import run_scene

    scene = falling_cloth("float64", 100)
    summary = run_scene(scene, tmp_path / "f64.usdc", device="cpu", frames=3, overlap=False)
    sim = Simulator(scene, "cpu")
    for _ in range(3):
        sim.step_frame()
    stage = Usd.Stage.Open(str(tmp_path / "f64.usdc"))
    mesh = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    points = np.asarray(mesh.GetPointsAttr().Get(Usd.TimeCode(3)))
    assert points.dtype == np.float32 and summary.frames == 3
    np.testing.assert_array_equal(points, sim.positions().astype(np.float32))
