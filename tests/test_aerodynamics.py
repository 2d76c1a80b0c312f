"""Air ([simulation.air]): drag and lift on each face against analytic answers (terminal velocity, an edge-on
fall), a flag that flutters in a steady stream, seeded gusts, no work at all without air, the memory estimate,
torn faces, and one SceneError per bad key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.builder import SceneBuilder
from warp_verlet.core.memory import estimate
from warp_verlet.core.simulator import Simulator
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene

G = 9.81


def even_sheet_masses(n: int, mass: float) -> tuple[float, list]:
    """(the cloth's mass key, particle_masses) of an n x n grid whose particles carry mass in proportion to their
    share of the sheet's area (a border particle half an inner one's, a corner a quarter), so that every particle
    feels the same acceleration from a uniform pressure and the sheet stays flat; the sheet weighs ``mass``."""
    inner = mass / (n - 1) ** 2
    borders = [[r, c, inner / 2 ** ((r in (0, n - 1)) + (c in (0, n - 1)))]
               for r in range(n) for c in range(n) if r in (0, n - 1) or c in (0, n - 1)]
    return inner * n * n, borders  # the key spreads inner to every particle; the borders override it


def falling_sheet(air: dict | None, orientation: str = "horizontal", precision: str = "float64", n: int = 16,
                  side: float = 1.0, mass: float = 0.05, **cloth) -> dict:
    key_mass, borders = even_sheet_masses(n, mass)
    simulation = {"fps": 60.0, "substeps": 4, "iterations": 4, "precision": precision, "damping": 0.0}
    if air is not None:
        simulation["air"] = air
    return {"simulation": simulation,
            "cloth": [{"resolution": [n, n], "size": [side, side], "orientation": orientation, "origin": [0, 10, 0],
                       "mass": key_mass, "particle_masses": borders, "sticks": ["structural", "shear"], **cloth}]}


def mean_height_per_frame(sim: Simulator, frames: int) -> np.ndarray:
    heights = [sim.state.positions()[:, 1].astype(np.float64).mean()]
    for _ in range(frames):
        sim.step_frame()
        heights.append(sim.state.positions()[:, 1].astype(np.float64).mean())
    return np.array(heights)


# ------------------------------------------------------------------------------------------- analytic answers

@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_a_flat_sheet_falls_at_its_terminal_velocity(precision, device):
    """Drag 1/2 rho C_d A v^2 balances m g at v = sqrt(2 m g / (rho C_d A)) (0.825 m/s for 50 g on 1 m^2): the
    sheet's mean speed over its last second is that within 0.5 % (well inside the 5 % asked of the model; it
    settles within about 0.3 s, the time constant v / g = 0.08 s)."""
    mass, side, rho, cd = 0.05, 1.0, 1.2, 1.2
    sim = Simulator(parse_scene(falling_sheet({"density": rho}, precision=precision, drag_coefficient=cd),
                                file="<test>"), device)  # on CUDA, captured frames
    heights = mean_height_per_frame(sim, 120)
    speed = -(heights[-1] - heights[-61])  # m over the last 60 frames (1 s)
    terminal = math.sqrt(2 * mass * G / (rho * cd * side * side))
    assert speed == pytest.approx(terminal, rel=5e-3)
    flat = sim.state.positions()[:, 1]
    assert np.ptp(flat) < 1e-4  # it stays flat, face-on to its fall


def test_a_sheet_falling_edge_on_falls_freely(device):
    """A vertical sheet falling along its own plane presents no area to the air (v_rel . n = 0 on every face):
    after 0.5 s it has fallen g t^2 / 2 within 0.1 %, while the same sheet face-on has fallen far less."""
    frames = 30
    edge_on = Simulator(parse_scene(falling_sheet({}, orientation="vertical"), file="<test>"), device)
    drop = mean_height_per_frame(edge_on, frames)
    t = frames / 60.0
    assert drop[0] - drop[-1] == pytest.approx(0.5 * G * t * t, rel=1e-3)
    face_on = Simulator(parse_scene(falling_sheet({}), file="<test>"), device)
    face_drop = mean_height_per_frame(face_on, frames)
    assert face_drop[0] - face_drop[-1] < 0.5 * (0.5 * G * t * t)


def test_a_mesh_of_triangles_falls_at_its_terminal_velocity():
    """A triangulated square (a mesh cloth, its mass spread by area so that it stays flat) reaches the same
    terminal velocity as the grid: the faces' areas and normals are those of triangles."""
    n, side, mass, rho, cd = 9, 1.0, 0.05, 1.2, 1.2
    u = np.linspace(0.0, side, n)
    xs, zs = np.meshgrid(u, u, indexing="ij")
    points = np.stack([xs.ravel(), np.full(n * n, 10.0), zs.ravel()], axis=1)
    tris = []
    for r in range(n - 1):
        for c in range(n - 1):
            a, b, d, e = r * n + c, (r + 1) * n + c, (r + 1) * n + c + 1, r * n + c + 1
            tris += [[a, b, d], [a, d, e]]
    builder = SceneBuilder()
    builder.set_simulation(fps=60.0, substeps=4, iterations=4, precision="float64", air={"density": rho})
    builder.add_mesh(points=points, faces=np.array(tris), mass=mass, sticks=["structural"], drag_coefficient=cd)
    sim = Simulator(builder.scene(), "cpu", use_graph=False)
    heights = mean_height_per_frame(sim, 120)
    terminal = math.sqrt(2 * mass * G / (rho * cd * side * side))
    assert -(heights[-1] - heights[-61]) == pytest.approx(terminal, rel=5e-3)


def test_lift_pushes_across_the_relative_wind():
    """A sheet held at 45 degrees in a horizontal stream (gravity off, pinned nowhere, over one substep from
    rest; at 4 substeps, where the overshoot limit does not bind): drag alone pushes along the normal, 1/2 rho C_d A U^2 cos^2(45) = 1/4 rho C_d A U^2 in all; lift adds
    1/2 rho C_l A U^2 cos sin = 1/4 rho C_l A U^2 across the stream. So the first step's mean acceleration,
    split into along and across the stream, is (rho A U^2 / 4m) (C_d / sqrt2 + 0, C_d / sqrt2 + C_l) in the
    frame below, within 0.1 %."""
    n, side, mass, rho, speed, cd, cl = 8, 1.0, 0.05, 1.2, 3.0, 1.2, 0.5
    key_mass, borders = even_sheet_masses(n, mass)
    # A vertical sheet (in x, y) turned 45 degrees about y: its normal is (-1, 0, 1) / sqrt2 or its opposite. The
    # stream blows along +x.
    sim = Simulator(parse_scene({
        "simulation": {"fps": 60.0, "substeps": 4, "iterations": 0, "precision": "float64",
                       "gravity": [0.0, 0.0, 0.0], "air": {"velocity": [speed, 0.0, 0.0], "density": rho}},
        "cloth": [{"resolution": [n, n], "size": [side, side], "origin": [0, 10, 0], "mass": key_mass,
                   "particle_masses": borders, "sticks": ["structural"], "drag_coefficient": cd,
                   "lift_coefficient": cl}]}, file="<test>"), "cpu", use_graph=False)
    rest = sim.state.positions()
    turned = rest.copy()
    turned[:, 0] = rest[:, 0] / math.sqrt(2.0)
    turned[:, 2] = rest[:, 0] / math.sqrt(2.0)
    sim.state.set_positions(turned)
    sim.step()
    dt = sim.dt
    # From rest the exact start (kernels/integrate.py) gives the uniform acceleration a dt^2 / 2 in the first
    # step; the air's per-particle acceleration enters that step as a dt^2.
    moved = (sim.state.positions() - turned).mean(axis=0) / (dt * dt)
    q = rho * side * side * speed * speed / (4.0 * mass)
    # The face's normal n ~ (-1, 0, 1)/sqrt2 (either sign): drag along n, q C_d sqrt2 n = q C_d (1, 0, -1) with
    # the stream's sign; lift across the stream (along -z here, on n's side): q C_l.
    assert moved[0] == pytest.approx(q * cd, rel=1e-3)
    assert moved[2] == pytest.approx(-q * (cd + cl), rel=1e-3)
    assert abs(moved[1]) < 1e-9 * q


# ------------------------------------------------------------------------------------------- the flag

FLAG = {"resolution": [20, 30], "size": [0.6, 1.0], "origin": [0.0, 2.0, 0.0], "mass": 0.09,
        "pins": ["left-edge"], "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0}}


def tip_path(simulation: dict, seconds: float) -> np.ndarray:
    """The flag's free corner's mid-height particle, frame by frame, after a tiny random push out of its plane
    (1e-4 m/s: in a perfectly flat flag in a stream along its plane nothing breaks the symmetry)."""
    rows, cols = FLAG["resolution"]
    sim = Simulator(parse_scene({"simulation": {"fps": 60.0, "substeps": 8, "iterations": 4, "damping": 2.0,
                                                **simulation}, "cloth": [FLAG]}, file="<test>"), "cpu",
                    use_graph=False)
    push = np.zeros((rows * cols, 3))
    push[:, 2] = 1e-4 * np.random.default_rng(1).standard_normal(rows * cols)
    sim.state.set_velocity(push)
    tip = []
    for _ in range(int(seconds * 60)):
        sim.step_frame()
        tip.append(sim.state.positions()[(rows // 2) * cols + cols - 1].astype(np.float64))
    return np.array(tip)


@pytest.mark.slow
def test_a_flag_flutters_in_a_steady_stream_and_not_in_a_uniform_wind():
    """In a steady 10 m/s stream the flag's tip keeps moving across the stream after the transient (its RMS
    across, over the last 2 s of 6, above 1 cm), fed by the air; the same flag pushed by a uniform `wind`
    acceleration (0.8 g along the stream) settles (RMS under 1 mm), its swing damped at the same rate."""
    air = tip_path({"air": {"velocity": [10.0, 0.0, 0.0]}}, 6.0)[-120:, 2]
    uniform = tip_path({"wind": [0.8 * G, 0.0, 0.0]}, 6.0)[-120:, 2]
    assert air.std() > 0.01
    assert uniform.std() < 0.001


# ------------------------------------------------------------------------------------------- gusts, keyframes

def gusty_positions(air: dict, device: str = "cpu", frames: int = 20) -> np.ndarray:
    sim = Simulator(make_scene({"substeps": 2, "iterations": 2, "air": air}, resolution=[8, 8],
                               pins=["top-left", "top-right"]), device)
    for _ in range(frames):
        sim.step_frame()
    return sim.state.positions()


def test_gusts_are_the_same_for_a_seed_and_differ_across_seeds(device):
    air = {"velocity": [2.0, 0.0, 0.0], "gust_speed": 3.0, "gust_length": 0.5, "gust_period": 0.4}
    first = gusty_positions({**air, "gust_seed": 7}, device)
    assert np.array_equal(first, gusty_positions({**air, "gust_seed": 7}, device))
    other = gusty_positions({**air, "gust_seed": 8}, device)
    still = gusty_positions({"velocity": [2.0, 0.0, 0.0]}, device)
    assert np.abs(other - first).max() > 1e-3 and np.abs(first - still).max() > 1e-3


def test_the_gusts_rms_speed_is_gust_speed():
    """The field the kernel reads, sampled over space and time on the host: its RMS speed is gust_speed within
    10 % (four sinusoids: the RMS of each is exact only on average over space and time)."""
    from warp_verlet.core.aerodynamics import gust_modes
    from warp_verlet.input.scene import AirSettings

    direction, wave, timing = gust_modes(AirSettings(gust_speed=2.0, gust_length=0.7, gust_period=0.5, gust_seed=3))
    rng = np.random.default_rng(0)
    x = rng.uniform(-20, 20, size=(20000, 3))
    t = rng.uniform(0, 100, size=20000)
    phase = x @ wave.T.astype(np.float64) - t[:, None] * timing[:, 0] + timing[:, 1]
    g = np.sin(phase) @ direction.astype(np.float64)
    assert math.sqrt((g * g).sum(axis=1).mean()) == pytest.approx(2.0, rel=0.1)


def test_keyframed_air_is_the_constant_air_while_its_keyframes_hold_it(device):
    """Keyframes [[0, v], [0.25, v], [0.5, 0]] give the constant air v up to 0.25 s (the device clock reads the
    keys at each step's start; the interpolation between two equal keys rounds to within an ulp of v, so the
    positions agree to 1e-5 m), and differ by centimetres after."""
    def heights(air: dict) -> list[np.ndarray]:
        sim = Simulator(make_scene({"substeps": 2, "iterations": 2, "air": air}, resolution=[6, 6],
                                   pins=["top-left"]), device)
        out = []
        for _ in range(30):
            sim.step_frame()
            out.append(sim.state.positions())
        return out

    constant = heights({"velocity": [3.0, 0.0, 1.0]})
    keyed = heights({"velocity": [[0.0, 3.0, 0.0, 1.0], [0.25, 3.0, 0.0, 1.0], [0.5, 0.0, 0.0, 0.0]]})
    frames_held = 15  # 0.25 s at 60 fps: the last step starts at 0.25 - dt, inside the hold
    assert max(np.abs(a - b).max() for a, b in zip(constant[:frames_held], keyed[:frames_held])) < 1e-5
    assert np.abs(constant[-1] - keyed[-1]).max() > 1e-3


# ------------------------------------------------------------------------------------------- no air, no work

SCENE_WITHOUT_AIR = dict(resolution=[8, 8], pins=["top-left"], sticks=["structural", "shear"])


@pytest.mark.parametrize("air", [{"density": 0.0, "velocity": [5.0, 0.0, 0.0]}, None])
def test_without_a_pushing_air_nothing_is_launched_or_allocated(air, launches):
    """A density of 0 (or cloths whose coefficients are both 0) is no air: bit-identical positions, the same
    launches and the same memory as a scene without [simulation.air]."""
    simulation = {"substeps": 2} if air is None else {"substeps": 2, "air": air}
    cloth = SCENE_WITHOUT_AIR if air is not None else {**SCENE_WITHOUT_AIR, "drag_coefficient": 0.0,
                                                      "lift_coefficient": 0.0}
    plain = Simulator(make_scene({"substeps": 2}, **SCENE_WITHOUT_AIR), "cpu", use_graph=False)
    other = Simulator(make_scene({**simulation, "air": air or {"velocity": [5.0, 0.0, 0.0]}}, **cloth), "cpu",
                      use_graph=False)
    issued = launches.of(other.step)
    assert issued == launches.of(plain.step) and "face_forces" not in issued
    for _ in range(10):
        plain.step_frame()
        other.step_frame()
    assert np.array_equal(plain.state.positions(), other.state.positions())
    assert estimate(make_scene({**simulation, "air": air or {"velocity": [5.0, 0.0, 0.0]}}, **cloth)).device_bytes \
        == estimate(make_scene({"substeps": 2}, **SCENE_WITHOUT_AIR)).device_bytes
    assert other.model.air is None and "air" not in [name for name, _ in other.stages()]


def test_air_launches_its_face_forces_before_the_step_that_gathers_them(launches):
    constant = Simulator(make_scene({"air": {"velocity": [3.0, 0.0, 0.0]}}, **SCENE_WITHOUT_AIR), "cpu",
                         use_graph=False)
    constant.step()
    issued = launches.of(constant.step)
    assert issued[:2] == ["face_forces", "verlet_step_air"] and "verlet_step" not in issued
    gusty = Simulator(make_scene({"air": {"gust_speed": 1.0}}, **SCENE_WITHOUT_AIR), "cpu", use_graph=False)
    gusty.step()
    assert launches.of(gusty.step)[:3] == ["face_forces", "advance_clock", "verlet_step_air"]


AIR_CASES = {
    "every-particle-pinned": ({"air": {"velocity": [3.0, 0.0, 0.0]}}, {"pins": ["top-edge", "bottom-edge",
                                                                             "left-edge", "right-edge"],
                                                                    "resolution": [2, 2]}),
    "constant": ({"air": {"velocity": [3.0, 0.0, 0.0]}}, {}),
    "keyframed-gusts-float64": ({"precision": "float64", "air": {"velocity": [[0, 1, 0, 0], [1, 4, 0, 0]],
                                                                 "gust_speed": 1.0}}, {}),
    "tear": ({"air": {"velocity": [3.0, 0.0, 0.0]}}, {"tear_threshold": 1.5}),
    "jacobi-tear-gusts": ({"relaxation": "jacobi", "air": {"gust_speed": 2.0}}, {"tear_threshold": 1.5}),
    "lift-only": ({"air": {}}, {"drag_coefficient": 0.0}),
}


@pytest.mark.parametrize("case", list(AIR_CASES))
def test_the_memory_estimate_counts_the_air(case):
    """As tests/test_memory.py checks every other case: the arrays allocated are the estimate, less the one-element
    counters it leaves out."""
    from test_memory import simulator_bytes

    simulation, cloth = AIR_CASES[case]
    scene = parse_scene({"simulation": simulation, "cloth": [{"resolution": [12, 9], "size": [1.0, 1.0],
                                                              "sticks": ["structural", "shear"], **cloth}]},
                        file="<test>")
    sim = Simulator(scene, "cpu", use_graph=False)
    sim.step()
    assert (sim.model.air is None) == (case == "every-particle-pinned")  # nothing moves: no air to compute
    counters = 4 * (scene.tears + (scene.simulation.relaxation == "jacobi"))
    assert simulator_bytes(sim) - estimate(scene, sim.model.sticks_form).device_bytes == counters


# ------------------------------------------------------------------------------------------- tearing

@pytest.mark.parametrize("relaxation", ["coloured", "jacobi"])
def test_a_torn_face_feels_no_air(relaxation, device):
    """Every structural stick torn: every face is torn, and the sheet in a stream falls exactly as in still
    air (free fall: shear sticks still hold it together)."""
    def torn_sheet(air: dict) -> Simulator:
        sim = Simulator(make_scene({"relaxation": relaxation, "air": air}, resolution=[6, 6],
                                   sticks=["structural", "shear"], tear_threshold=50.0), device)
        model = sim.model
        model.restore_tears(sim.state, model.host_sticks[model.structural])
        return sim

    windy, calm = torn_sheet({"velocity": [8.0, 0.0, 3.0]}), torn_sheet({"density": 0.0})
    for _ in range(10):
        windy.step_frame()
        calm.step_frame()
    assert np.array_equal(windy.state.positions(), calm.state.positions())
    # and intact, the stream moves it
    intact = Simulator(make_scene({"relaxation": relaxation, "air": {"velocity": [8.0, 0.0, 3.0]}},
                                  resolution=[6, 6], sticks=["structural", "shear"], tear_threshold=50.0), device)
    for _ in range(10):
        intact.step_frame()
    assert np.abs(intact.state.positions() - calm.state.positions()).max() > 1e-2


# ------------------------------------------------------------------------------------------- bad input

BAD_AIR = [
    ({"air": 3}, "simulation.air", "expected a table"),
    ({"air": {"velocity": [1.0, 2.0]}}, "simulation.air.velocity", "array of 3 numbers"),
    ({"air": {"velocity": [[0.0, 1.0, 2.0, 3.0], 4.0]}}, "simulation.air.velocity", "mix of numbers and arrays"),
    ({"air": {"velocity": [[1.0, 1.0, 2.0, 3.0], [0.5, 1.0, 2.0, 3.0]]}}, "simulation.air.velocity[1][0]",
     "must increase"),
    ({"air": {"velocity": "east"}}, "simulation.air.velocity", "expected"),
    ({"air": {"density": -1.0}}, "simulation.air.density", "[0.0, inf)"),
    ({"air": {"density": 1e39}}, "simulation.air.density", "float32"),
    ({"air": {"gust_speed": -2.0}}, "simulation.air.gust_speed", "[0.0, inf)"),
    ({"air": {"gust_length": 0.0}}, "simulation.air.gust_length", "(0.0, inf)"),
    ({"air": {"gust_period": -1.0}}, "simulation.air.gust_period", "(0.0, inf)"),
    ({"air": {"gust_seed": 1.5}}, "simulation.air.gust_seed", "integer"),
    ({"air": {"gust_seed": -1}}, "simulation.air.gust_seed", "integer"),
    ({"air": {"speed": 3.0}}, "simulation.air.speed", "unknown key"),
]


@pytest.mark.parametrize("simulation, key, problem", BAD_AIR, ids=[k for _, k, _ in BAD_AIR])
def test_each_bad_air_key_is_one_scene_error_naming_the_file_and_key(tmp_path, simulation, key, problem):
    with pytest.raises(SceneError) as info:
        parse_scene({"simulation": simulation, "cloth": [{"resolution": [3, 3], "size": [1.0, 1.0]}]},
                    file="air.toml")
    assert info.value.file == "air.toml" and info.value.key == key and problem in info.value.problem


@pytest.mark.parametrize("name", ["drag_coefficient", "lift_coefficient"])
@pytest.mark.parametrize("value, problem", [(-0.1, "[0.0, inf)"), ("high", "expected a number"),
                                            (1e39, "float32")])
def test_a_bad_coefficient_is_one_scene_error(name, value, problem):
    with pytest.raises(SceneError) as info:
        parse_scene({"cloth": [{"resolution": [3, 3], "size": [1.0, 1.0], name: value}]}, file="air.toml")
    assert info.value.file == "air.toml" and info.value.key == f"cloth[0].{name}" and problem in info.value.problem
