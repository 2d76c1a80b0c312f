"""The CPU relaxation spread over threads (warp_verlet/core/cpu_team.py) and the captured CPU frame.

Cutting a colour over threads must not change a single bit: every particle still sees its sticks in colour
order. The analytic cases below (stability suite) run with the relaxation forced onto three threads, and the
same runs are compared bit-for-bit with one thread and with uncaptured launches.
"""

from __future__ import annotations

import gc
import threading

import numpy as np
import pytest
import warp as wp

import warp_verlet.core.cpu_team as cpu_team
import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import stability_cases as cases
from conftest import make_scene
from test_stability import assert_all_pass
from warp_verlet.core.cpu_team import FrameTeam, PhaseTeam, auto_threads
from warp_verlet.launches import split
from warp_verlet.errors import WarpVerletError
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator


def test_split_cuts_a_range_into_contiguous_pieces_in_order():
    for first, count, parts in [(0, 10, 3), (7, 2, 4), (5, 0, 2), (3, 12, 1)]:
        pieces = split(first, count, parts)
        assert len(pieces) == parts
        covered = [i for f, n in pieces for i in range(f, f + n)]
        assert covered == list(range(first, first + count))
        assert max(n for _, n in pieces) - min(n for _, n in pieces) <= 1


def test_auto_threads_balances_work_per_thread_against_the_cost_per_thread():
    cost = cpu_team.LAUNCH_COST_S
    assert auto_threads(0.9 * cost, cores=8) == 1  # a 64^2-like colour: a barrier costs more than it saves
    assert auto_threads(16 * cost, cores=8) == 4  # sqrt(work / cost)
    assert auto_threads(15.9 * cost, cores=8) == 3  # rounded down
    assert auto_threads(16 * cost, cores=2) == 2  # never more than the cores
    assert auto_threads(10_000 * cost, cores=64) == cpu_team.MAX_AUTO_THREADS
    assert auto_threads(0.0, cores=8) == 1
    # Where frames are captured a phase costs each thread less (a barrier in C++), so smaller colours are cut
    captured = cpu_team.CAPTURED_PHASE_COST_S
    assert captured < cost
    assert auto_threads(16 * captured, cores=8, captured=True) == 4
    assert auto_threads(16 * captured, cores=8) == 2  # sqrt(16 x 4 us / 13 us), rounded down


def busy_scene(solver: str):
    """A 20 x 24 cloth with every stick family (soft shear and bend sticks where the solver has them: the
    coloured one), tethers, a moving ball, the ground and tearing: every stage and constraint set runs."""
    soft = {"compliance": {"shear": 0.02, "bend": 0.2}} if solver == "coloured" else {}
    return parse_scene({
        "simulation": {"fps": 60, "substeps": 3, "iterations": 6, "relaxation": solver, "wind": [8.0, 0.0, 3.0]},
        "cloth": [{"resolution": [20, 24], "size": [1.0, 1.2], "pins": ["top-left", "top-right"], "tear_threshold": 1.4,
                   "tethers": True, "tether_scale": 1.5, "sticks": ["structural", "shear", "bend"], **soft}],
        "collider": [{"type": "sphere", "radius": 0.2, "path": [[0.0, 0.0, 0.3, 1.0], [0.5, 0.0, 0.3, -1.0]]},
                     {"type": "plane", "point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]}],
    }, file="<busy>")


def run_frames(scene, frames: int, **options) -> tuple[np.ndarray, int]:
    sim = Simulator(scene, "cpu", **options)
    for _ in range(frames):
        sim.step_frame()
    return sim.positions(), sim.torn_count()


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_threaded_relaxation_is_bit_identical_to_one_thread(solver):
    scene = busy_scene(solver)
    one, torn_one = run_frames(scene, 30, threads=1)
    assert torn_one > 0  # the scene exercises tearing, so the comparison covers it
    for threads in (2, 3, 7):
        points, torn = run_frames(scene, 30, threads=threads)
        assert torn == torn_one
        assert np.array_equal(points, one), f"{threads} threads changed the result"


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_contact_projected_every_sweep_runs_threaded_and_bit_identical(solver):
    # The clamps that end every sweep are phases of the thread team too: each must have an entry per thread
    # (member 0 runs the clamp while the others wait), or binding the sweeps fails once the team has two threads.
    scene = parse_scene({
        "simulation": {"fps": 60, "substeps": 2, "iterations": 3, "relaxation": solver,
                       "contact_projection": "every_sweep"},
        "cloth": [{"resolution": [8, 6], "size": [1.0, 0.8], "orientation": "horizontal", "origin": [-0.5, 0.3, -0.4],
                   "sticks": ["structural", "shear", "bend"]}],
        "collider": [{"type": "sphere", "radius": 0.28, "centre": [0.0, 0.0, 0.0]},
                     {"type": "plane", "point": [0.0, -0.3, 0.0]}],
    }, file="<every sweep>")
    one, _ = run_frames(scene, 6, threads=1)
    assert np.isclose(np.linalg.norm(one, axis=1).min(), 0.28)  # the cloth lies on the ball: the clamps act
    for threads in (2, 3):
        points, _ = run_frames(scene, 6, threads=threads)
        assert np.array_equal(points, one), f"{threads} threads changed the result"


def test_colliders_clamp_on_every_thread_bit_for_bit(launches):
    # After the sweeps each thread of the team clamps its own run of particles, kind after kind (a mesh's clamp, a
    # BVH query a particle, can cost more than the sweeps): every thread count gives one thread's positions.
    from pathlib import Path

    from warp_verlet.input.scene import read_toml_file

    path = Path(__file__).resolve().parents[1] / "scenes" / "cloth_on_table.toml"
    table = read_toml_file(path)
    table["cloth"][0]["resolution"] = [24, 18]
    # Every kind touches the cloth within the run: a bump on the table top, and the ground raised to catch the
    # overhang as it folds down.
    table["collider"][1]["point"] = [0.0, 0.68, 0.0]
    table["collider"].append({"type": "sphere", "radius": 0.1, "centre": [0.0, 0.72, 0.0]})
    scene = parse_scene(table, str(path), path)
    kinds = ("collide_meshes", "collide_moving_meshes", "collide_spheres", "collide_planes")
    positions = []
    for threads in (1, 2, 3):
        sim = Simulator(scene, "cpu", threads=threads, use_graph=False)
        issued = launches.of(sim.step)
        assert sorted(name for name in issued if name in kinds) == sorted(
            ["collide_meshes"] * threads + ["collide_spheres"] * threads + ["collide_planes"] * threads)
        for _ in range(30):
            sim.step_frame()
        positions.append(sim.positions())
    low = positions[0][:, 1]
    assert low.max() > 0.8 and abs(low.min() - 0.685) < 1e-3  # over the bump, and the overhang on the ground
    for threads, points in zip((2, 3), positions[1:]):
        assert np.array_equal(points, positions[0]), f"{threads} threads changed the result"


def test_captured_cpu_frames_match_launch_by_launch():
    scene = busy_scene("coloured")
    captured, torn_captured = run_frames(scene, 20, threads=1)
    launched, torn_launched = run_frames(scene, 20, threads=1, use_graph=False)
    assert torn_captured == torn_launched > 0
    assert np.array_equal(captured, launched)


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_frames_captured_on_cpu_threads_give_one_threads_positions_bit_for_bit(solver, monkeypatch):
    # On threads a frame is captured as one graph a thread, meeting at barriers in C++ (cpu_team.FrameTeam): every
    # stage of the busy scene (soft sticks, tethers, a moving ball, the ground, tearing) then replays from the
    # graphs, and a replayed frame hands work to the threads once, not once a phase.
    scene = busy_scene(solver)
    one, torn_one = run_frames(scene, 20, threads=1)
    runs = []
    original = PhaseTeam.run
    monkeypatch.setattr(PhaseTeam, "run", lambda team: (runs.append(team), original(team))[1])
    for threads in (2, 3):
        sim = Simulator(scene, "cpu", threads=threads)
        assert sim.threads == threads and sim.replays_frames
        for _ in range(20):
            runs.clear()
            sim.step_frame()
        assert isinstance(sim._frame_graphs[sim.settings.substeps], FrameTeam)
        assert runs == [sim._replayer._team]  # the last frame: one hand-off to the threads
        assert sim.torn_count() == torn_one > 0
        assert np.array_equal(sim.positions(), one), f"{threads} threads changed the result"
        sim.close()


def test_the_native_barrier_lets_every_thread_go_once_the_abort_flag_is_set():
    from warp_verlet.core.cpu_team import yield_address
    from warp_verlet.kernels.team_barrier import team_barrier

    state = wp.zeros(3, dtype=int, device="cpu")
    state.numpy()[2] = 1  # aborted: a barrier of five threads returns to each one that arrives
    for _ in range(3):
        wp.launch(team_barrier, 1, inputs=[state, 5, wp.uint64(yield_address())], device="cpu")
    wp.synchronize_device("cpu")
    assert list(state.numpy()[:2]) == [3, 0]  # each arrival counted, the generation never advanced


def test_an_error_in_one_thread_of_a_captured_frame_reaches_the_caller_without_a_hang(monkeypatch):
    sim = Simulator(busy_scene("coloured"), "cpu", threads=2)
    for _ in range(2):
        sim.step_frame()  # the second frame is captured
    assert isinstance(sim._frame_graphs[sim.settings.substeps], FrameTeam)
    replay = wp.capture_launch

    def fail_in_workers(graph):
        if threading.current_thread().name.startswith("warp-verlet-relax"):
            raise RuntimeError("replay failed in a worker")
        replay(graph)

    monkeypatch.setattr(wp, "capture_launch", fail_in_workers)
    raised = []

    def step():
        try:
            sim.step_frame()
        except RuntimeError as exc:
            raised.append(exc)

    caller = threading.Thread(target=step, daemon=True)
    caller.start()
    caller.join(timeout=60)
    assert not caller.is_alive(), "the caller's thread still waits at a barrier for the failed one"
    assert raised and "replay failed in a worker" in str(raised[0])
    with pytest.raises(WarpVerletError, match="stopped after an earlier error"):
        sim.step_frame()


@pytest.fixture
def always_three_threads(monkeypatch):
    """Make auto_threads pick three threads for any grid, so the stability cases run threaded."""
    monkeypatch.setattr(cpu_team, "LAUNCH_COST_S", 1e-15)
    monkeypatch.setattr(cpu_team, "CAPTURED_PHASE_COST_S", 1e-15)
    monkeypatch.setattr(cpu_team, "usable_cores", lambda: 3)
    created = []
    original = Simulator.__init__

    def spy(self, *args, **kwargs):
        original(self, *args, **kwargs)
        created.append(self.threads)

    monkeypatch.setattr(Simulator, "__init__", spy)
    return created


@pytest.mark.slow
@pytest.mark.parametrize("case", ["heavy_chain", "stiff_iterations", "mass_ratio", "two_places"])
def test_stability_cases_pass_with_threaded_relaxation(always_three_threads, case):
    assert_all_pass(getattr(cases, case)("cpu"))
    assert always_three_threads and set(always_three_threads) == {3}


def test_auto_threads_picks_one_thread_for_small_grids_and_cuda_takes_none():
    small = make_scene({}, resolution=[16, 16])
    assert Simulator(small, "cpu").threads == 1
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(WarpVerletError, match="threads must be a whole number"):
            Simulator(small, "cpu", threads=bad)


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_threads_are_refused_on_cuda():
    small = make_scene({}, resolution=[8, 8])
    assert Simulator(small, "cuda").threads == 1
    with pytest.raises(WarpVerletError, match="CPU only"):
        Simulator(small, "cuda", threads=2)


def test_an_error_in_a_worker_reaches_the_caller_and_stops_the_team():
    done = []

    def fail():
        raise RuntimeError("boom in worker")

    team = PhaseTeam([[lambda: done.append(0), fail], [lambda: done.append(1), None]], repeats=2)
    raised = []

    def run():  # member 0 waits for the failed worker at the native barrier: its abort flag must release it
        try:
            team.run()
        except RuntimeError as exc:
            raised.append(exc)

    caller = threading.Thread(target=run, daemon=True)
    caller.start()
    caller.join(timeout=60)
    assert not caller.is_alive(), "the caller still waits at the barrier for the failed worker"
    assert len(raised) == 1 and "boom in worker" in str(raised[0])
    with pytest.raises(WarpVerletError, match="stopped after an earlier error"):
        team.run()
    assert all(not w.is_alive() for w in _joined(team))


def test_an_interrupt_in_the_caller_releases_the_workers():
    def interrupt():
        raise KeyboardInterrupt

    for phases in ([[interrupt, lambda: None, lambda: None]],
                   # in a later phase, where the workers wait for the caller at the native barrier
                   [[lambda: None] * 3, [interrupt, lambda: None, lambda: None]]):
        team = PhaseTeam(phases, repeats=1)
        with pytest.raises(KeyboardInterrupt):
            team.run()
        assert all(not w.is_alive() for w in _joined(team))


def test_phases_run_in_order_with_every_member_and_workers_stop_on_close():
    log, lock = [], threading.Lock()

    def note(phase, member):
        def task():
            with lock:
                log.append((phase, member))
        return task

    team = PhaseTeam([[note(p, t) for t in range(3)] for p in range(4)], repeats=2)
    team.run()
    phases = [p for p, _ in log]
    assert phases == sorted(phases[:12]) + sorted(phases[12:])  # each pass: phase 0 done before 1, ...
    assert sorted(log) == sorted((p, t) for p in range(4) for t in range(3) for _ in range(2))
    team.close()
    assert all(not w.is_alive() for w in _joined(team))


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
def test_dropping_a_threaded_simulator_stops_its_threads(solver):
    sim = Simulator(busy_scene(solver), "cpu", threads=3)
    for _ in range(3):
        sim.step_frame()  # the first frame's teams, and the frames captured after it
    workers = [w for team in sim.solver._teams for w in team._workers]
    workers += sim._replayer._team._workers
    assert len(workers) == 3 * 2  # the sweeps', the clamps' and the captured frame's, two workers each
    assert workers and all(w.is_alive() for w in workers)
    del sim
    gc.collect()
    for worker in workers:
        worker.join(timeout=5)
    assert not any(w.is_alive() for w in workers)


def test_dropping_a_state_stops_the_threads_that_relaxed_it():
    # A threaded solver starts teams of workers for every state it steps (its launches are bound to that state's
    # arrays): checkpoints must not leave threads behind once they are dropped.
    sim = Simulator(busy_scene("coloured"), "cpu", threads=3)
    sim.step()
    own = {w for team in sim.solver._teams for w in team._workers}
    teams_per_state = len(sim.solver._teams)  # the sweeps' and the colliders' clamps'
    assert teams_per_state == 2
    clones = [sim.state.clone() for _ in range(3)]
    for clone in clones:
        sim.solver.step(clone, sim.settings.dt)
    workers = {w for team in sim.solver._teams for w in team._workers} - own
    assert len(workers) == 3 * teams_per_state * 2 and all(w.is_alive() for w in workers)
    del clones, clone
    gc.collect()
    for worker in workers:
        worker.join(timeout=5)
    assert not any(w.is_alive() for w in workers)
    assert all(w.is_alive() for w in own)  # the simulator's own state still has its team
    sim.step()


def _joined(team: PhaseTeam) -> list[threading.Thread]:
    for worker in team._workers:
        worker.join(timeout=5)
    return team._workers
