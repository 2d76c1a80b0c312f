"""The live session without a browser: real-time ticks, edits at frame boundaries, pins, tearing, dragging,
the event log and recording (warp_verlet/apps/live_session.py, Simulator.advance/retune/take_state)."""

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.output.cache_reader import open_cache, read_cloths
from warp_verlet.errors import StateError, WarpVerletError
from warp_verlet.apps.live_session import LiveSession
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.output.usd_writer import validate_cache

FRAME = 1 / 60
HANGING = dict(resolution=[12, 12], pins=["top-left", "top-right"], sticks=["structural", "shear"], tethers=False)


def ticks(session, frames: int, per_frame: int = 1):
    """``frames`` frames of wall time, in ``per_frame`` ticks each."""
    for _ in range(frames * per_frame):
        session.tick(FRAME / per_frame)


def mean(session) -> np.ndarray:
    return np.concatenate(session.current_points()).mean(axis=0)


def test_ticks_run_real_time_and_count_frames():
    session = LiveSession(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu")
    ticks(session, 10, per_frame=3)  # 30 ticks of 1/180 s: 40 substeps, 10 frames
    assert session.sim.steps == 40 and session.frame == 10
    assert session.readout().recorded == 11  # frame 0 and 10 frames


def test_edits_wait_for_the_frame_boundary():
    session = LiveSession(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu")
    session.tick(1 / 240)  # one substep: mid-frame
    assert not session.sim.at_frame_boundary
    session.set_substeps(8)
    assert session.sim.substeps == 4  # not yet
    session.tick(3 / 240)  # the frame's 3 remaining substeps
    assert session.frame == 1 and session.sim.substeps == 8
    # Every frame is 1/60 s whatever its substeps: 4 of 1/240 s, then 8 of 1/480 s.
    ticks(session, 1)
    assert session.sim.time == pytest.approx(2 / 60, abs=1e-9) and session.frame == 2


def test_retune_mid_frame_is_refused_and_step_frame_too():
    sim = Simulator(make_scene({"substeps": 4}, **HANGING), "cpu")
    sim.advance(1 / 240)
    with pytest.raises(StateError, match="frame boundary"):
        sim.retune(iterations=2)
    with pytest.raises(StateError, match="finish_frame"):
        sim.step_frame()
    sim.finish_frame()
    assert sim.steps == 4
    sim.retune(iterations=2)
    sim.step_frame()
    assert sim.steps == 8


def test_wind_moves_the_cloth_along_the_wind():
    # A vertical cloth in the XY plane, pinned at its top corners: wind along +Z blows it out of its plane.
    session = LiveSession(make_scene({"damping": 1.0}, **HANGING), "cpu")
    ticks(session, 30)
    before = mean(session)
    session.set_wind((0.0, 0.0, 2.0), 9.81)  # any length of direction: 1 g along +Z
    ticks(session, 60)
    shift = mean(session) - before
    # A pendulum pushed sideways by 1 g swings towards 45 degrees: the centre moves out by several cm along +Z
    # and hardly at all along X (the cloth is symmetric about its centre line).
    assert shift[2] > 0.05 and abs(shift[0]) < 1e-3
    assert session.sim.settings.wind == pytest.approx((0.0, 0.0, 9.81))


def test_a_rebuilt_simulator_continues_the_motion_exactly():
    """take_state: a rebuild that changes nothing the motion feels (a tear threshold no stick reaches) gives
    the positions of a session never rebuilt, bit for bit: positions, implicit velocity, time and dt_prev all
    carried over."""
    scene = make_scene({"substeps": 4}, **HANGING)
    plain, rebuilt = LiveSession(scene, "cpu"), LiveSession(scene, "cpu")
    ticks(plain, 20)
    ticks(rebuilt, 20)
    rebuilt.set_tear_threshold(1e6)
    ticks(plain, 20)
    ticks(rebuilt, 20)
    assert rebuilt.sim.model.tears and not plain.sim.model.tears
    np.testing.assert_array_equal(rebuilt.sim.positions(), plain.sim.positions())
    assert rebuilt.sim.time == plain.sim.time


def test_released_cloth_falls_at_g():
    """All pins released: no external force but gravity, so the centre of mass accelerates at exactly g
    (the sticks' corrections are equal and opposite between equal masses), from the velocity it had."""
    scene = make_scene({"substeps": 4, "damping": 0.0}, **HANGING)
    session = LiveSession(scene, "cpu")
    ticks(session, 20)
    for pin in session.pins():
        session.release_pin(pin)
    ticks(session, 1)
    assert session.pins() == [] and session.sim.model.has_free_particles
    sim = session.sim
    dt = sim.dt
    x0 = sim.positions().mean(axis=0)
    v0 = (x0 - sim.previous_positions().mean(axis=0)) / dt  # the mean velocity over the last substep
    ticks(session, 30)
    t = 30 / 60
    expected = x0 + v0 * t + 0.5 * np.array([0.0, -9.81, 0.0]) * t * (t + dt)  # Verlet's exact sum over steps
    np.testing.assert_allclose(sim.positions().mean(axis=0), expected, atol=2e-4)


def test_pause_stops_at_a_frame_boundary_and_step_runs_one_frame():
    session = LiveSession(make_scene({"substeps": 4}, **HANGING), "cpu")
    session.tick(1.5 / 240)
    session.pause()
    assert not session.paused  # mid-frame: it finishes the frame first
    session.tick(3 / 240)
    assert session.paused and session.sim.at_frame_boundary and session.frame == 1
    ticks(session, 10)
    assert session.frame == 1
    session.step_frame()
    assert session.frame == 2 and session.sim.steps == 8
    session.play()
    ticks(session, 1)
    assert session.frame == 3


def test_tearing_switched_on_live_tears_and_is_recorded(tmp_path):
    scene = make_scene({"substeps": 4, "damping": 0.5}, **HANGING)
    session = LiveSession(scene, "cpu")
    ticks(session, 5)
    session.set_wind((0, 0, 1), 40.0)
    session.set_tear_threshold(1.02)
    ticks(session, 60)
    torn = session.readout().torn
    assert torn > 0
    assert any("tore" in line for line in session.events)
    drawn_holes = session.hidden_faces()[0]  # what the page draws without
    np.testing.assert_array_equal(drawn_holes, session.sim.model.hidden_faces(session.sim.torn_sticks())[0])
    assert len(drawn_holes) > 0
    path = tmp_path / "torn.usda"
    count = session.save(path)
    assert count == session.frame + 1 and validate_cache(path) == []
    cache = open_cache(path)
    last = read_cloths(cache, cache.frames[-1])[0]
    assert len(last.hidden) > 0  # torn faces removed from the saved topology, read back as hidden
    np.testing.assert_allclose(last.points, session.current_points()[0], atol=1e-6)
    assert len(read_cloths(cache, 0)[0].hidden) == 0


def test_tear_threshold_refusals_are_clear():
    session = LiveSession(make_scene(**HANGING), "cpu")
    with pytest.raises(WarpVerletError, match="> 1"):
        session.set_tear_threshold(0.9)
    multilevel = LiveSession(make_scene({"multilevel": True}, resolution=[9, 9], pins=["top-left"]), "cpu")
    multilevel.set_tear_threshold(1.5)  # refused by the scene's own check, into the log
    ticks(multilevel, 1)
    assert any("refused" in line and "multilevel" in line for line in multilevel.events)
    assert not multilevel.sim.model.tears


def test_dragged_sphere_pushes_the_cloth_out():
    scene = parse_scene({
        "simulation": {"substeps": 4},
        "cloth": [{"resolution": [10, 10], "size": [1.0, 1.0], "orientation": "horizontal",
                   "origin": [-0.5, 0.0, -0.5], "pins": ["top-left", "top-right", "bottom-left", "bottom-right"]}],
        "collider": [{"type": "sphere", "name": "ball", "centre": [0.0, -1.0, 0.0], "radius": 0.25}],
    }, file="<test>")
    session = LiveSession(scene, "cpu")
    ticks(session, 5)
    for y in np.linspace(-1.0, 0.1, 45):  # dragged up into the cloth, a little every frame
        session.move_sphere(0, (0.0, y, 0.0))
        ticks(session, 1)
    np.testing.assert_allclose(session.sphere_centres()[0], (0.0, 0.1, 0.0), atol=1e-7)
    distance = np.linalg.norm(session.sim.positions() - np.array([0.0, 0.1, 0.0]), axis=1)
    # The sphere now cuts the cloth's rest plane (centre 0.1 m above it, radius 0.25 m), where a 4 x 4 block of
    # the flat cloth's particles would lie inside it; the dragged sphere pushed them all out.
    rest = session.sim.model.rest_positions
    assert (np.linalg.norm(rest - np.array([0.0, 0.1, 0.0]), axis=1) < 0.25).sum() >= 4
    assert distance.min() >= 0.25 - 1e-4


def test_a_keyframed_sphere_cannot_be_dragged():
    scene = parse_scene({
        "cloth": [{"resolution": [4, 4], "size": [1.0, 1.0]}],
        "collider": [{"type": "sphere", "name": "ball", "radius": 0.2,
                      "path": [[0.0, 0.0, -1.0, 0.0], [1.0, 1.0, -1.0, 0.0]]}],
    }, file="<test>")
    with pytest.raises(WarpVerletError, match="keyframed"):
        LiveSession(scene, "cpu").move_sphere(0, (0, 0, 0))


def test_a_dragged_sphere_stays_where_it_is_put_beside_a_keyframed_one():
    # Once any sphere moves, the spheres are placed from their keyframes every substep: a still sphere was put
    # back at its start there, undoing every drag.
    scene = parse_scene({
        "cloth": [{"resolution": [4, 4], "size": [1.0, 1.0], "origin": [5.0, 5.0, 0.0]}],
        "collider": [{"type": "sphere", "name": "still", "radius": 0.2, "centre": [0.0, -3.0, 0.0]},
                     {"type": "sphere", "name": "moving", "radius": 0.2,
                      "path": [[0.0, 0.0, -1.0, 0.0], [1.0, 1.0, -1.0, 0.0]]}],
    }, file="<test>")
    session = LiveSession(scene, "cpu")
    session.move_sphere(0, (1.0, 2.0, 3.0))
    ticks(session, 3)
    np.testing.assert_array_equal(session.sphere_centres()[0], [1.0, 2.0, 3.0])
    assert session.sphere_centres()[1][0] == pytest.approx(3 / 60, abs=1e-6)  # the other keeps to its path
    session.reset()
    np.testing.assert_array_equal(session.sphere_centres()[0], [0.0, -3.0, 0.0])  # Reset puts it back


def test_tearing_switched_off_keeps_the_torn_sticks_torn(tmp_path):
    session = LiveSession(make_scene({"substeps": 4, "damping": 0.5}, **HANGING), "cpu")
    session.set_wind((0, 0, 1), 40.0)
    session.set_tear_threshold(1.02)
    ticks(session, 40)
    torn, holes = session.readout().torn, session.hidden_faces()[0].copy()
    assert torn > 0
    session.set_tear_threshold(None)
    ticks(session, 30)
    assert session.readout().torn == torn  # none healed, none more
    np.testing.assert_array_equal(session.hidden_faces()[0], holes)
    assert session.readout().stretch_max < 0.5  # the torn sticks are not pulling their ends back together
    session.save(tmp_path / "torn.usdc")
    cache = open_cache(tmp_path / "torn.usdc")
    np.testing.assert_array_equal(read_cloths(cache, cache.frames[-1])[0].hidden, holes)


def test_a_released_pin_after_tears_records_the_same_holes(tmp_path):
    session = LiveSession(make_scene({"substeps": 4, "damping": 0.5}, **HANGING), "cpu")
    session.set_wind((0, 0, 1), 40.0)
    session.set_tear_threshold(1.02)
    ticks(session, 40)
    session.set_wind((0, 0, 1), 0.0)
    session.release_pin(session.pins()[0])
    ticks(session, 2)
    holes = session.hidden_faces()[0]
    session.save(tmp_path / "released.usdc")
    cache = open_cache(tmp_path / "released.usdc")
    np.testing.assert_array_equal(read_cloths(cache, cache.frames[-1])[0].hidden, holes)


def test_pause_mid_frame_then_step_stops_at_that_frame():
    session = LiveSession(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu")
    session.tick(2 / 240)  # half a frame
    session.pause()
    assert not session.paused  # it waits for the frame boundary
    session.step_frame()  # the boundary: the pause holds there
    assert session.paused and session.frame == 1
    ticks(session, 3)
    assert session.frame == 1 and session.readout().paused


def test_a_stall_is_clamped_and_logged():
    session = LiveSession(make_scene({"fps": 60, "substeps": 4, "max_frame_time": 0.1}, **HANGING), "cpu")
    session.tick(3.0)
    assert session.sim.steps == 8  # two frames of 1/240 s steps: slow motion, not 3 s of catching up
    assert any("stall" in line and "2967 ms" in line for line in session.events)
    tight = LiveSession(make_scene({"fps": 60, "substeps": 4, "max_frame_time": 0.02}, **HANGING), "cpu")
    tight.tick(3.0)
    assert tight.sim.steps == 4  # the scene's max_frame_time, when shorter


def test_divergence_pauses_and_reset_recovers():
    session = LiveSession(make_scene({"position_bound": 1.2}, resolution=[4, 4]), "cpu")  # nothing pinned: falls
    ticks(session, 60)
    assert session.diverged and any("diverged" in line for line in session.events)
    assert session.readout().paused  # the page's button and frame readout say so
    frame = session.frame
    session.set_iterations(3)  # an edit while diverged applies, and steps nothing
    ticks(session, 5)
    assert session.frame == frame and session.sim.settings.iterations == 3
    assert sum("diverged" in line for line in session.events) == 1
    session.reset()
    assert not session.diverged and session.frame == 0 and session.sim.time == 0.0


def test_each_saved_frame_is_that_frame(device, tmp_path):
    """The recording keeps a copy of every frame on the simulation's device: each saved frame is bit for bit
    what a batch simulator of the same scene has at that frame (not a later frame's positions, not a view)."""
    scene = make_scene({"substeps": 4, "damping": 0.5}, **HANGING)
    session = LiveSession(scene, device)
    ticks(session, 6, per_frame=2)  # half frames: each frame is recorded at its boundary, not at a tick
    assert session.save(tmp_path / "frames.usdc") == 7
    cache = open_cache(tmp_path / "frames.usdc")
    batch = Simulator(scene, device)
    for frame in range(7):
        if frame:
            batch.step_frame()
        saved = read_cloths(cache, frame)[0].points
        np.testing.assert_array_equal(saved, batch.positions(), err_msg=f"frame {frame}")
    assert not np.array_equal(read_cloths(cache, 1)[0].points, read_cloths(cache, 6)[0].points)


def test_reset_empties_the_recording_and_keeps_the_edits(device, tmp_path):
    session = LiveSession(make_scene(**HANGING), device)
    ticks(session, 10)
    session.set_iterations(3)
    session.reset()
    ticks(session, 4)
    assert session.sim.settings.iterations == 3
    assert session.save(tmp_path / "after_reset.usdc") == 5
    assert open_cache(tmp_path / "after_reset.usdc").frames == (0, 1, 2, 3, 4)


def test_recording_stops_at_its_limit(device):
    frame_bytes = 12 * 12 * 3 * 4
    session = LiveSession(make_scene(**HANGING), device, record_limit=5 * frame_bytes)
    ticks(session, 10)
    r = session.readout()
    assert r.recorded == 5 and r.recording_full
    assert any("recording full" in line for line in session.events)


def test_a_waiting_session_holds_still_until_started(tmp_path):
    """``live`` makes its session waiting: nothing is simulated or recorded before start() (the first page), and
    the wall time spent waiting is not caught up afterwards."""
    session = LiveSession(make_scene({"fps": 60, "substeps": 4}, **HANGING), "cpu", waiting=True)
    rest = session.current_points()[0].copy()
    ticks(session, 30)  # half a second of wall time before any page connects
    session.step_frame()  # nothing steps before the start
    assert session.readout().waiting and session.frame == 0 and session.sim.steps == 0
    np.testing.assert_array_equal(session.current_points()[0], rest)
    session.set_iterations(3)  # an edit made while waiting applies at once, as while paused
    assert session.sim.settings.iterations == 3
    session.start()
    assert not session.readout().waiting and session.frame == 0
    ticks(session, 3)
    assert session.frame == 3 and session.sim.steps == 12  # three frames of wall time, three frames
    session.start()  # another page connecting changes nothing
    assert session.frame == 3 and session.readout().recorded == 4
    assert session.save(tmp_path / "started.usdc") == 4
    cache = open_cache(tmp_path / "started.usdc")
    assert cache.frames == (0, 1, 2, 3)
    np.testing.assert_array_equal(read_cloths(cache, 0)[0].points, rest)
    assert [line.split(" s  ", 1)[1] for line in session.event_lines()][1:4] == [
        "waiting for a page to connect: the simulation and its recording start then", "iterations 3",
        "started: simulating and recording from frame 0"]


class FakeClock:
    """The session's clock, moved by the test."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_stalls_are_one_line_at_most_once_a_second_and_edits_stay_in_the_log():
    clock = FakeClock()
    session = LiveSession(make_scene({"fps": 60, "substeps": 2}, **HANGING), "cpu", clock=clock)
    session.set_wind((0.0, 0.0, 1.0), 1.0)
    session.set_iterations(3)
    session.tick(1 / 60)  # the edits apply at the frame boundary
    session.pause()
    session.play()
    edits = [line for line in session.event_lines() if "wind 1" in line or "iterations 3" in line
             or "paused at frame 1" in line or "playing from frame 1" in line]
    assert len(edits) == 4
    stall_lines = set()
    for _ in range(240):  # 30 s of ticks of 1/8 s: each banks 2 frames (1/30 s) and drops the rest
        clock.now += 0.125
        session.tick(0.125)
        stall_lines.update(line for line in session.event_lines() if "stall" in line)
        assert sum("stall" in line for line in session.event_lines()) == 1
    # The first stall at once, then one line a second, each replacing the last: the log still holds the edits.
    assert len(stall_lines) == 1 + 29
    lines = session.event_lines()
    assert all(edit in lines for edit in edits)
    assert lines[-1].endswith("stalled 8 times in the last 1.0 s, worst 92 ms, 733 ms of wall time dropped in all "
                              "(a tick banks at most 33 ms of wall time); the simulation runs slower than real time")
