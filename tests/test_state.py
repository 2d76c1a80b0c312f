"""The State holds everything that changes in a run, and nothing else does: a clone is a checkpoint that steps
exactly like the original, assigning it back rolls the run back bit for bit, reset() replays the first run,
and the Model cannot be changed."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.core.model import Model
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.core.state import State

EPS32 = float(np.finfo(np.float32).eps)
SWEEP = {"type": "sphere", "radius": 0.15, "path": [[0.0, 0.2, -0.3, 0.6], [0.6, 0.2, -0.6, -0.6]]}
GROUND = {"type": "plane", "point": [0.0, -1.2, 0.0], "friction_coefficient": 0.3}


def busy(solver: str = "coloured", tethers: bool = False):
    """A flag in a gale that tears, swept by a moving sphere over the ground: every part of the State changes
    (positions, tear weights and counter, tether lengths when asked for, the collider clock and centres)."""
    soft = {"compliance": {"shear": 0.03}} if solver == "coloured" else {}
    extra = {"tethers": True, "tether_scale": 1.25} if tethers else {}
    return parse_scene({
        "simulation": {"fps": 60, "substeps": 4, "iterations": 6, "relaxation": solver, "wind": [60.0, 0.0, 40.0],
                       "damping": 0.5},
        "cloth": [{"resolution": [12, 16], "size": [0.6, 0.8], "pins": ["left-edge"], "mass": 0.1,
                   "sticks": ["structural", "shear"], "tear_threshold": 1.2, **soft, **extra}],
        "collider": [SWEEP, GROUND],
    }, file="<busy>")


CASES = {"coloured": ("coloured", False), "jacobi": ("jacobi", False), "tethers": ("coloured", True)}


def frame(sim: Simulator) -> tuple[np.ndarray, int, np.ndarray]:
    sim.step_frame()
    if sim.model.tears:
        sim.sync_tears()  # as the runner does: tethers cut off from their pin are dropped
    centres = sim.state.sphere_centres.numpy().copy()
    return sim.positions(), sim.torn_count(), centres


@pytest.mark.parametrize("case", list(CASES))
def test_a_clone_steps_exactly_like_the_original(case):
    sim = Simulator(busy(*CASES[case]), "cpu")
    for _ in range(5):
        sim.step_frame()
    twin = sim.state.clone()
    assert twin.model is sim.model
    for name, array in sim.state.arrays().items():  # independent copies, equal now
        other = twin.arrays()[name]
        assert other.ptr != array.ptr and np.array_equal(other.numpy(), array.numpy())
    dt = sim.settings.dt
    for _ in range(25 * 4):
        sim.step()
        sim.solver.step(twin, dt)
    assert np.array_equal(twin.positions(), sim.positions())
    assert sim.torn_count() > 0
    assert np.array_equal(twin.stick_weight.numpy(), sim.state.stick_weight.numpy())
    assert np.array_equal(twin.sphere_centres.numpy(), sim.state.sphere_centres.numpy())
    assert (twin.time, twin.steps, twin.dt_prev) == (sim.state.time, sim.state.steps, sim.state.dt_prev)


@pytest.mark.parametrize("case", list(CASES))
def test_assigning_a_checkpoint_replays_the_same_frames(case):
    sim = Simulator(busy(*CASES[case]), "cpu")  # frames replayed from a capture: assign keeps the addresses
    for _ in range(10):
        frame(sim)
    checkpoint = sim.state.clone()
    first = [frame(sim) for _ in range(30)]
    assert first[-1][1] > first[0][1]  # the run tears after the checkpoint
    assert not np.array_equal(first[-1][2], first[0][2])  # and the sphere moves on
    sim.state.assign(checkpoint)
    assert sim.state.time == checkpoint.time and sim.state.steps == checkpoint.steps == 40
    for n, (points, torn, centres) in enumerate(first):
        again = frame(sim)
        assert np.array_equal(again[0], points), f"frame {11 + n} differs after the rollback"
        assert again[1] == torn and np.array_equal(again[2], centres)
    # The checkpoint itself did not move.
    assert checkpoint.steps == 40 and not np.array_equal(checkpoint.positions(), sim.positions())


def test_a_state_of_another_model_cannot_be_assigned():
    a = Simulator(make_scene(resolution=[4, 4]), "cpu")
    b = Simulator(make_scene(resolution=[4, 4]), "cpu")
    with pytest.raises(ValueError, match="same model"):
        a.state.assign(b.state)
    with pytest.raises(ValueError, match="its own model"):
        a.solver.step(b.state, a.settings.dt)


@pytest.mark.parametrize("case", list(CASES))
def test_reset_then_running_again_reproduces_the_first_run(case):
    sim = Simulator(busy(*CASES[case]), "cpu")
    start = sim.positions()
    first = [frame(sim) for _ in range(30)]
    assert first[-1][1] > 0
    sim.reset()
    assert np.array_equal(sim.positions(), start) and sim.torn_count() == 0 and sim.time == 0.0 == sim.steps
    assert sim.state.dt_prev is None
    for n, (points, torn, centres) in enumerate(first):
        again = frame(sim)
        assert np.array_equal(again[0], points), f"frame {n + 1} differs after reset()"
        assert again[1] == torn and np.array_equal(again[2], centres)
    # And a second reset gives the same again (reset's starting state is not stepped).
    sim.reset()
    assert np.array_equal(frame(sim)[0], first[0][0])


def test_set_velocity_moves_free_particles_at_that_velocity_and_not_pins(device):
    # No gravity, no sticks solved: a free particle launched at v is at x0 + v t after any number of steps,
    # with the float32 budget of test_integrate (one rounding of the increment and of the coordinate per step).
    scene = make_scene({"fps": 30, "substeps": 3, "iterations": 0, "gravity": [0.0, 0.0, 0.0]}, resolution=[5, 6],
                       origin=[0.4, 1.3, -0.2], pins=["top-left", [2, 3]])
    sim = Simulator(scene, device)
    x0 = sim.positions().astype(np.float64)
    v = np.array([0.7, -1.1, 0.35])
    sim.state.set_velocity(v)
    pinned = np.array([0, 2 * 6 + 3])
    free = np.setdiff1d(np.arange(30), pinned)
    for f in range(1, 31):
        sim.step_frame()
        t = f / 30
        expected = x0 + v * t
        error = np.abs(sim.positions()[free] - expected[free]).max()
        assert error <= 3 * f * EPS32 * (np.abs(v).max() * t + np.abs(expected).max()), (f, error)
        assert np.array_equal(sim.positions()[pinned], x0[pinned].astype(np.float32))
    # One velocity per particle, from rest again: each moves at its own.
    sim.reset()
    per_particle = np.random.default_rng(0).normal(size=(30, 3))
    sim.state.set_velocity(per_particle)
    for _ in range(3):
        sim.step_frame()
    moved = sim.positions().astype(np.float64) - x0
    np.testing.assert_allclose(moved[free], per_particle[free] * 0.1, atol=1e-6)
    assert not moved[pinned].any()


def test_set_velocity_with_gravity_is_the_exact_parabola():
    scene = make_scene({"fps": 20, "substeps": 2, "iterations": 0}, resolution=[2, 2])
    sim = Simulator(scene, "cpu")
    x0 = sim.positions().astype(np.float64)
    v = np.array([1.0, 4.0, 0.0])
    sim.state.set_velocity(v)
    for _ in range(10):
        sim.step_frame()
    t = 0.5
    np.testing.assert_allclose(sim.positions(), x0 + v * t + 0.5 * np.array([0.0, -9.81, 0.0]) * t * t, atol=2e-6)


def test_set_velocity_refuses_non_finite_values():
    sim = Simulator(make_scene(resolution=[2, 2]), "cpu")
    with pytest.raises(ValueError, match="finite"):
        sim.state.set_velocity([0.0, np.nan, 0.0])


def test_set_positions_keeps_the_velocity():
    scene = make_scene({"fps": 10, "substeps": 1, "iterations": 0, "gravity": [0.0, 0.0, 0.0]}, resolution=[2, 2])
    sim = Simulator(scene, "cpu")
    sim.state.set_velocity([1.0, 0.0, 0.0])
    sim.step()
    shifted = sim.positions() + np.float32(5.0)
    sim.state.set_positions(shifted)
    sim.step()
    np.testing.assert_allclose(sim.positions() - shifted, np.tile([0.1, 0.0, 0.0], (4, 1)), atol=1e-6)


def test_the_model_is_immutable():
    sim = Simulator(busy(), "cpu")
    model = sim.model
    for name, value in [("inv_mass", None), ("stick_count", 0), ("tears", False), ("anything_new", 1)]:
        with pytest.raises(AttributeError, match="immutable"):
            setattr(model, name, value)
    assert model.stick_count > 0 and model.tears
    # Running writes none of its arrays: tearing and moving colliders change the State only.
    before = {k: v.numpy().copy() for k, v in vars(model).items() if hasattr(v, "numpy") and hasattr(v, "ptr")}
    for _ in range(30):
        sim.step_frame()
    assert sim.torn_count() > 0
    for name, values in before.items():
        assert np.array_equal(getattr(model, name).numpy(), values), f"the run wrote Model.{name}"


def test_one_model_serves_many_states():
    sim = Simulator(busy(), "cpu")
    other = State(sim.model)
    assert isinstance(sim.model, Model) and other.model is sim.model
    for _ in range(8):
        sim.solver.step(other, sim.settings.dt)
        sim.step()
    assert np.array_equal(other.positions(), sim.positions())


def test_a_velocity_or_positions_of_the_wrong_shape_is_an_argument_error_naming_the_shape():
    from warp_verlet.errors import ArgumentError

    sim = Simulator(make_scene(resolution=[4, 4]), "cpu")  # 16 particles
    for wrong in ([1.0, 2.0], np.zeros((5, 3)), [[1.0, 2.0, 3.0, 4.0]], "fast"):
        with pytest.raises(ArgumentError, match=r"velocity must be numbers of shape \(3,\) or \(16, 3\)"):
            sim.state.set_velocity(wrong)
    with pytest.raises(ArgumentError, match=r"points must have shape \(16, 3\).*got \(5, 3\)"):
        sim.state.set_positions(np.zeros((5, 3)))
    sim.state.set_velocity([1.0, 0.0, 0.0])  # the two shapes it documents are still taken
    sim.state.set_velocity(np.ones((16, 3)))


def test_the_increment_always_holds_metres_and_the_start_velocity_has_its_own_field():
    # particle_dq is x - x_prev's part in metres at every moment; a velocity given before the first step waits
    # in start_velocity (m/s, host), is carried by clone and assign, and becomes the first increment.
    sim = Simulator(make_scene({"gravity": [0.0, 0.0, 0.0], "damping": 0.0, "iterations": 0}, resolution=[3, 3],
                               pins=["top-left"]), "cpu", use_graph=False)
    state = sim.state
    state.set_velocity([2.0, 0.0, 0.0])
    assert not state.particle_dq.numpy().any()
    assert np.array_equal(state.start_velocity[1:], np.tile([2.0, 0.0, 0.0], (8, 1)))
    assert not state.start_velocity[0].any()  # the pin stays at rest
    twin = state.clone()
    assert np.array_equal(twin.start_velocity, state.start_velocity) and twin.start_velocity is not state.start_velocity
    dt = sim.dt
    sim.step(dt)
    assert state.start_velocity is None
    move = state.particle_dq.numpy()[1:, 0].astype(np.float64) + (state.particle_q.numpy() - state.particle_q_inertial.numpy())[1:, 0]
    np.testing.assert_allclose(move, 2.0 * dt, rtol=1e-5)  # the first step moved v dt, in metres
    state.assign(twin)  # back before the start: the velocity comes back with it
    assert state.start_velocity is not None and state.dt_prev is None
