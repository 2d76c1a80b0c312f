"""A substep budget chosen from a target stretch: the controller's rules, a simulation that meets its target at
the least substeps it found, and the scene keys."""

import numpy as np
import pytest

from warp_verlet.core.budget import CALM_FRAMES, Budget
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import TARGET_ITERATIONS, parse_scene
from warp_verlet.core.simulator import Simulator

from test_multilevel import hanging  # tests/ is on sys.path (pytest, rootdir-relative imports)


def test_doubles_over_the_target_and_halves_only_after_calm_frames():
    b = Budget(target=0.01, substeps=4, max_substeps=32)
    b.observe(0.02)
    assert b.substeps == 8
    b.observe(0.009)  # under, but not under a quarter: keep
    assert b.substeps == 8
    for _ in range(CALM_FRAMES - 1):
        b.observe(0.001)
    assert b.substeps == 8  # one calm frame short
    b.observe(0.001)
    assert b.substeps == 4
    for _ in range(5):
        b.observe(1.0)
    assert b.substeps == 32 and b.over_at_max == 2  # 4 -> 8 -> 16 -> 32, then stuck at the cap twice
    assert b.frames_at == {4: 2, 8: CALM_FRAMES + 2, 16: 1, 32: 2}
    assert "raise max_substeps" in b.report() and "32 x 2" in b.report()


def scene(target: float, n: int = 48, **simulation):
    data = hanging(n, tethers=True, target_stretch=target, **simulation)
    del data["simulation"]["substeps"], data["simulation"]["iterations"]
    data["cloth"][0]["orientation"] = "horizontal"  # level, so that it swings down (hung, its tethers hold it still)
    return parse_scene(data, file="<budget>")


def run(target: float) -> Simulator:
    sim = Simulator(scene(target), "cpu", threads=1)
    for _ in range(40):
        sim.step_frame()
    return sim


def test_the_budget_keeps_a_hanging_cloth_under_its_target_and_spends_less_on_a_looser_one():
    tight, loose = run(0.002), run(0.1)
    assert tight.stretch().rms < 0.002 and loose.stretch().rms < 0.1
    assert tight.budget.last_rms == pytest.approx(tight.stretch().rms)
    assert tight.settings.iterations == TARGET_ITERATIONS
    # The tight target needed more substeps than the 4 it started from; the loose one fewer.
    assert max(tight.budget.frames_at) > 4 and min(loose.budget.frames_at) < 4
    assert tight.state.steps > 2 * loose.state.steps
    # It changed dt on the way, as the Verlet step's time-step-corrected form allows, and time stayed exact.
    assert tight.time == pytest.approx(40 / 60.0, rel=1e-12)


def test_the_budget_on_cpu_threads_gives_one_threads_frames_and_replays_them_on_one_set_of_threads():
    # Each substep count the budget picks is captured once (on threads, a graph a thread); one replayer, its
    # threads started once, replays every count's frame, and the positions are one thread's bit for bit.
    one = run(0.002)
    sim = Simulator(scene(0.002), "cpu", threads=2)
    replayers = set()
    for _ in range(40):
        sim.step_frame()
        replayers.add(id(sim._replayer))
    assert len([n for n, frame in sim._frame_graphs.items() if n in one.budget.frames_at]) >= 2
    assert len(replayers - {id(None)}) == 1
    assert sim.budget.frames_at == one.budget.frames_at
    assert np.array_equal(sim.positions(), one.positions())


def test_without_a_target_the_substeps_are_the_scene_s():
    sim = Simulator(parse_scene(hanging(16, substeps=3), file="<fixed>"), "cpu")
    assert sim.budget is None and sim.substeps == 3
    sim.step_frame()
    assert sim.state.steps == 3


@pytest.mark.parametrize("simulation, words", [
    ({"target_stretch": 0.01, "substeps": 8}, "remove one of the two"),
    ({"target_stretch": 0.01, "max_dt_ratio": 1.5}, "max_dt_ratio >= 2"),
    ({"target_stretch": 0.0}, "target_stretch"),
    ({"target_stretch": 1.0}, "target_stretch"),
    ({"max_substeps": 0}, "max_substeps"),
    ({"min_substeps": 8}, "no target_stretch: set substeps instead"),
    ({"target_stretch": 0.01, "min_substeps": 64, "max_substeps": 32}, "at most max_substeps (32), got 64"),
    ({"target_stretch": 0.01, "min_substeps": 0}, "min_substeps"),
])
def test_budget_keys_are_checked(simulation, words):
    data = hanging(8)
    del data["simulation"]["substeps"]
    data["simulation"].update(simulation)
    with pytest.raises(SceneError) as err:
        parse_scene(data, file="scene.toml")
    assert words in str(err.value) and "scene.toml" in str(err.value)


def test_the_run_summary_says_what_the_budget_chose(tmp_path):
    from warp_verlet.apps.runner import run_scene

    summary = run_scene(scene(0.001, n=16), tmp_path / "cache.usda", device="cpu", frames=5)
    line = next(l for l in summary.format().splitlines() if l.startswith("budget"))
    assert "target rms 0.100%" in line and "(substeps x frames)" in line


def test_reset_starts_the_budget_over():
    sim = run(0.002)
    assert sim.substeps > 4
    sim.reset()
    assert sim.substeps == 4 and not sim.budget.frames_at


def test_the_report_names_the_cap_that_bound_the_budget_and_what_lifts_it():
    from warp_verlet.core.budget import FLOAT32_FLOOR, MAX_SUBSTEPS

    for capped_by in (MAX_SUBSTEPS, FLOAT32_FLOOR):
        b = Budget(target=0.01, substeps=32, max_substeps=32, capped_by=capped_by)
        b.observe(0.02)
        report = b.report()
        assert "over the target on 1 frames at 32 substeps" in report
        if capped_by == MAX_SUBSTEPS:
            assert "the scene's max_substeps: raise max_substeps above 32" in report and "float64" not in report
        else:
            assert "the float32 floor on dt" in report and 'set precision = "float64"' in report
            assert "max_substeps" not in report


@pytest.mark.parametrize("simulation, capped_by", [
    ({}, "float32 floor"),  # max_substeps 1024; float32 at 60 fps allows about 75 (docs/scenes.md)
    ({"max_substeps": 16}, "max_substeps"),
    ({"precision": "float64"}, "max_substeps"),  # the floor lies 2^29 lower in |a| dt^2
])
def test_the_simulator_tells_the_budget_which_cap_binds(simulation, capped_by):
    sim = Simulator(scene(0.01, n=8, **simulation), "cpu")
    assert sim.budget.capped_by == capped_by
    floor = int(1.0 / (sim.settings.fps * sim.min_dt))
    assert sim.budget.max_substeps == min(sim.settings.max_substeps, floor)
    assert (floor < sim.settings.max_substeps) == (capped_by == "float32 floor")


def test_the_budget_starts_at_the_default_substeps_as_docs_say():
    # A scene with target_stretch may not give substeps, so its budget starts at the default: 4
    # (docs/scenes.md, "A budget from a target stretch"), the step a scene without a target takes.
    from warp_verlet.input.scene import SimulationSettings

    sim = Simulator(scene(0.5, n=8), "cpu")
    assert SimulationSettings().substeps == 4 and sim.substeps == 4
    sim.step_frame()
    assert sim.state.steps == 4 and dict(sim.budget.frames_at) == {4: 1}


def test_min_substeps_starts_the_budget_there_and_halving_stops_at_it():
    b = Budget(target=0.01, substeps=16, max_substeps=64, min_substeps=16)
    for _ in range(3 * CALM_FRAMES):
        b.observe(0.0)
    assert b.substeps == 16 and b.frames_at == {16: 3 * CALM_FRAMES}
    sim = Simulator(scene(0.01, n=8, min_substeps=16), "cpu")
    assert sim.substeps == 16 and sim.budget.min_substeps == 16
    sim.step_frame()
    assert sim.state.steps == 16
    assert Simulator(scene(0.01, n=8, min_substeps=2), "cpu").substeps == 4  # the default start, if more
    below = Budget(target=0.01, substeps=4, max_substeps=64, min_substeps=16)  # a live session's target, turned on
    for expected in (8, 16, 16):
        below.observe(0.0)
        assert below.substeps == expected  # it climbs to its floor, doubling a frame at most (max_dt_ratio)


def test_the_report_counts_the_frames_a_sudden_load_stretched_and_suggests_min_substeps():
    b = Budget(target=0.01, substeps=4, max_substeps=64)
    for rms in (0.001, 0.05, 0.03, 0.02, 0.005, 0.005):  # a landing in frame 2: 4 -> 8 -> 16 -> 32
        b.observe(rms)
    report = b.report()
    assert b.over_while_adding == 3 and b.worst_while_adding == (0.05, 2, 4)
    assert "3 frames ended over the target while it added substeps (worst rms 5.000%, frame 2 at 4 substeps)" in report
    assert "min_substeps = 32 starts where it ended up" in report


def drape_run(tmp_path, **simulation):
    """A 48 x 48 sheet with a line pass dropped onto a ball under a 0.5% budget, 40 frames: its budget line."""
    from warp_verlet.apps.runner import run_scene

    data = {"simulation": {"fps": 60, "frames": 40, "target_stretch": 0.005, "iterations": 1, **simulation},
            "cloth": [{"name": "sheet", "resolution": [48, 48], "size": [1.0, 1.0], "origin": [-0.5, 0.4, -0.5],
                       "orientation": "horizontal", "sticks": ["structural", "shear", "bend"],
                       "compliance": {"shear": 1.0, "bend": 1.0}, "line_passes": 1}],
            "collider": [{"type": "sphere", "radius": 0.25, "centre": [0.0, 0.0, 0.0]}]}
    summary = run_scene(parse_scene(data, file="<drape>"), tmp_path / "drape.usdc", device="cpu")
    return summary.budget


def test_a_landing_the_budget_let_through_is_reported_and_min_substeps_holds_it(tmp_path):
    """In free fall the stretch is nil, so the budget halves to 2 substeps; the landing then stretches the
    frames it takes to double back up, and the report says so and what min_substeps would start there. Run again
    with it, no frame ends over the target and the budget never goes below it."""
    import re

    first = drape_run(tmp_path)
    assert "frames ended over the target while it added substeps" in first
    floor = int(re.search(r"min_substeps = (\d+) starts where it ended up", first).group(1))
    assert floor >= 8
    again = drape_run(tmp_path, min_substeps=floor)
    assert "ended over the target" not in again
    assert min(int(s) for s in re.findall(r"(\d+) x \d+", again.split("(substeps x frames)")[0])) >= floor
