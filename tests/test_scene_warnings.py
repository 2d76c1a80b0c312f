"""Scenes that load but will not do what they say (warp_verlet/input/scene_warnings.py): each warning fires exactly where
it should, says why and what to change, agrees with what a run does, and reaches the user through validate and run."""

from __future__ import annotations

import numpy as np
import pytest

from warp_verlet.apps import runner

from warp_verlet.input import scene_warnings
from warp_verlet.apps.cli import main
from warp_verlet.input.scene import parse_scene
from warp_verlet.input.scene_warnings import (free_fall, start_inside_warnings, stretch_warnings, tether_warnings,
                                              thickness_warnings)


def scene(cloth: dict, colliders=(), **simulation):
    data = {"simulation": {"fps": 60, "substeps": 4, "iterations": 2, **simulation}, "cloth": [cloth]}
    if colliders:
        data["collider"] = list(colliders)
    return parse_scene(data, "<warnings>")


def hanging_sheet(**cloth) -> dict:
    return {"name": "sheet", "resolution": [8, 8], "size": [0.7, 0.7], "origin": [0.0, 1.0, 0.0],
            "pins": ["top-edge"], **cloth}


# ------------------------------------------------------------------------------------------------ tethers


@pytest.mark.parametrize("scale, threshold, warned", [(1.0, 1.5, True), (1.5, 1.5, True), (1.6, 1.5, False)])
def test_tethers_that_hold_a_tearing_cloth_short_of_its_tear_length_are_named(scale, threshold, warned):
    found = tether_warnings(scene(hanging_sheet(tear_threshold=threshold, tethers=True, tether_scale=scale)))
    if not warned:
        assert found == []
        return
    (text,) = found
    assert text.startswith(f"cloth 'sheet': tethers with tether_scale = {scale:g} <= tear_threshold = {threshold:g}")
    assert f"raise tether_scale above {threshold:g} or set tethers = false" in text


def test_no_tether_warning_without_tethers_or_without_tearing():
    assert tether_warnings(scene(hanging_sheet(tear_threshold=1.5))) == []  # tethers are off by default here
    assert tether_warnings(scene(hanging_sheet(tethers=True))) == []  # it cannot tear anyway


def test_the_tether_warning_is_what_a_run_shows():
    # A hanging sheet under 200 g: without tethers its sticks tear; with tethers at their rest distances
    # (tether_scale 1 <= tear_threshold 1.3) none does; with the fix the warning gives, it tears again.
    from warp_verlet.core.simulator import Simulator

    def torn(**cloth) -> int:
        sim = Simulator(scene(hanging_sheet(tear_threshold=1.3, **cloth), gravity=[0.0, -2000.0, 0.0]), "cpu")
        for _ in range(30):
            sim.step_frame()
        return sim.torn_count()

    assert torn(tethers=False) > 0
    assert torn(tethers=True, tether_scale=1.0) == 0
    assert torn(tethers=True, tether_scale=2.0) > 0
    # Not a sharp bound: the sweeps after the tethers pull sticks past them, so just under the threshold tears too
    # (the warning says what the tethers do, not that nothing can tear).
    assert torn(tethers=True, tether_scale=1.29) > 0


# ------------------------------------------------------------------------------------- inside a collider

# 5 x 5 particles 0.25 m apart on the plane y = 0, centred on the origin.
FLAT = {"name": "sheet", "resolution": [5, 5], "size": [1.0, 1.0], "origin": [-0.5, 0.0, -0.5],
        "orientation": "horizontal"}
# Within 0.3 + 0.05 m of the origin: the centre and its four neighbours (0.25 m); the diagonal ones are 0.354 m off.
BALL = {"type": "sphere", "name": "ball", "radius": 0.3, "thickness": 0.05, "centre": [0.0, 0.0, 0.0]}
# Rows at y = 0.5, 0 and -0.5, two particles each.
HANGING = {"name": "sheet", "resolution": [3, 2], "size": [1.0, 0.5], "origin": [0.0, 0.5, 0.0]}


def moved_by_the_first_substep(s) -> int:
    """Particles the collider clamp moves in one substep with nothing else acting (no gravity, no sweeps)."""
    from warp_verlet.core.simulator import Simulator

    sim = Simulator(s, "cpu")
    before = sim.positions().copy()
    sim.step(sim.dt)
    return int((np.linalg.norm(sim.positions() - before, axis=1) > 0).sum())


@pytest.mark.parametrize("cloth, collider, count, pinned, where", [
    (FLAT, BALL, 5, 0, "inside sphere 'ball' (closer than radius + thickness = 0.35 m to its centre"),
    (dict(FLAT, pins=[[2, 2]]), BALL, 5, 1, "inside sphere 'ball'"),
    (HANGING, {"type": "plane", "name": "ground", "thickness": 0.01}, 4, 0,
     "behind or within thickness = 0.01 m of plane 'ground'"),
    (HANGING, {"type": "plane", "name": "ground"}, 2, 0, "behind plane 'ground'"),  # on the surface is outside
])
def test_a_cloth_that_starts_inside_a_collider_is_named_with_the_particles_the_clamp_moves(cloth, collider, count,
                                                                                           pinned, where):
    s = scene(cloth, [collider], gravity=[0.0, 0.0, 0.0], iterations=0, substeps=1)
    (text,) = start_inside_warnings(s)
    total = cloth["resolution"][0] * cloth["resolution"][1]
    assert text.startswith(f"cloth 'sheet' starts with {count} of {total} particles {where}")
    assert ("1 of them pinned, which stay there" in text) == bool(pinned)
    assert "move the cloth's origin" in text
    assert moved_by_the_first_substep(s) == count - pinned  # the kernel's own answer: pins are never moved


def test_a_moving_sphere_is_checked_where_it_starts():
    far = dict(BALL, path=[[0.0, 0.0, 5.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
    del far["centre"]
    assert start_inside_warnings(scene(FLAT, [far])) == []  # it reaches the cloth later: that is the scene
    assert start_inside_warnings(scene(FLAT)) == []


# ------------------------------------------------------------------------------------------ thickness


def test_a_collider_of_thickness_zero_gets_half_the_finest_spacing_as_advice():
    coarse = dict(FLAT, name="coarse")  # 0.25 m spacing
    fine = {"name": "fine", "resolution": [6, 11], "size": [1.0, 1.0], "origin": [3.0, 1.0, 0.0]}  # 0.2 and 0.1 m
    s = parse_scene({"cloth": [coarse, fine], "collider": [{"type": "plane", "name": "ground", "point": [0, -9, 0]},
                                                            dict(BALL, name="ball", centre=[0, 9, 0])]}, "<t>")
    (text,) = thickness_warnings(s)  # the ball has a thickness
    assert text.startswith("collider 'ground' has thickness 0: the cloth comes to rest on its visible surface")
    assert text.endswith("(cloth 'fine': thickness = 0.05)")


# --------------------------------------------------------------------------------------------- stretch


def test_free_fall_is_the_analytic_fall_without_damping_and_shorter_with_it():
    s = scene(HANGING, iterations=0, frames=30)
    t = 30 / 60
    # Verlet's x_n = a dt^2 n (n + 1) / 2 from rest: a t^2 / 2 plus half a step's worth.
    n = 30 * 4
    assert free_fall(s) == pytest.approx(9.81 * s.simulation.dt ** 2 * n * (n + 1) / 2, rel=1e-12)
    assert free_fall(s) == pytest.approx(9.81 * t * t / 2, rel=0.01)
    damped = scene(HANGING, iterations=0, frames=30, damping=5.0)
    keep, x, x_prev = np.exp(-5.0 * damped.simulation.dt), 0.0, 0.0
    for _ in range(n):  # the recurrence itself, step by step
        x, x_prev = x + keep * (x - x_prev) + 9.81 * damped.simulation.dt ** 2, x
    assert free_fall(damped) == pytest.approx(x, rel=1e-9) and x < free_fall(s)
    # A billion steps take no time: the closed form.
    long = scene(HANGING, iterations=0, frames=10**6, substeps=1000)
    assert free_fall(long) == pytest.approx(9.81 * (10**6 / 60) ** 2 / 2, rel=1e-6)


def test_no_sweeps_on_a_pinned_grid_is_predicted_and_the_run_agrees(tmp_path):
    cloth = {"name": "sheet", "resolution": [4, 4], "size": [0.3, 0.3], "pins": ["top-edge"]}
    s = scene(cloth, iterations=0, frames=30)  # falls 1.2 m; the sticks are 0.1 m
    (text,) = stretch_warnings(s)
    assert text.startswith("cloth 'sheet': iterations = 0 relaxes no stick")
    assert "give it iterations (at least 1)" in text
    summary = runner.run_scene(s, tmp_path / "c.usdc", device="cpu")
    assert summary.stretch_max > runner.UNCONVERGED_STRETCH and "has not converged" in summary.format()
    # Too short a fall to be sure (0.0055 m in 2 frames), or sweeps to hold it: no prediction.
    assert stretch_warnings(scene(cloth, iterations=0, frames=2)) == []
    assert stretch_warnings(scene(cloth, iterations=1, frames=30)) == []


def test_the_predicted_stretch_is_the_run_s_own_threshold():
    assert scene_warnings.UNCONVERGED_STRETCH == runner.UNCONVERGED_STRETCH


# -------------------------------------------------------------------------------------- validate and run

TRAP = """
[simulation]
frames = 3

[[cloth]]
name = "flag"
resolution = [5, 5]
size = [0.5, 0.5]
pins = ["top-edge"]
tear_threshold = 1.5
tethers = true
"""


def test_validate_and_run_print_the_warnings_and_still_succeed(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "trap.toml").write_text(TRAP)
    expected = "warning: cloth 'flag': tethers with tether_scale = 1 <= tear_threshold = 1.5"
    assert main(["validate", "trap.toml"]) == 0
    out, err = capsys.readouterr()
    assert "valid scene" in out and expected in err
    assert main(["run", "trap.toml", "--device", "cpu", "-q"]) == 0
    assert expected in capsys.readouterr().err
    (tmp_path / "fine.toml").write_text(TRAP.replace("tethers = true", "tethers = false"))
    assert main(["validate", "fine.toml"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_run_that_has_not_converged_names_the_cloth_and_what_helps_it(tmp_path):
    # Not predictable without running (how far a frame's sweeps carry a correction against the load), so the
    # run says it: one sweep of one substep a frame cannot hold a 32 x 32 grid from two corners under 3 g.
    s = parse_scene({"simulation": {"fps": 30, "frames": 15, "substeps": 1, "iterations": 1,
                                    "gravity": [0.0, -30.0, 0.0]},
                     "cloth": [{"name": "small", "resolution": [3, 3], "size": [0.2, 0.2], "origin": [2.0, 1.0, 0.0],
                                "pins": ["top-edge"]},
                               {"name": "big", "resolution": [32, 32], "size": [1.0, 1.0], "origin": [0.0, 1.0, 0.0],
                                "pins": ["top-left", "top-right"], "tethers": False}]}, "<unconverged>")
    summary = runner.run_scene(s, tmp_path / "c.usdc", device="cpu")
    assert summary.stretch_max > runner.UNCONVERGED_STRETCH
    (warning,) = [line for line in summary.format().splitlines() if line.startswith("warning")]
    assert "has not converged in cloth 'big' (a 32 x 32 grid) at 1 substeps x 1 iterations a frame" in warning
    for fix in ("more substeps", "target_stretch", "tethers = true", "line_passes = 1", "multilevel = true",
                "30 m/s^2"):
        assert fix in warning
    assert "sixth of its spacing" not in warning  # a landing's rule is for cloth that colliders hold up


def test_the_unconverged_warning_offers_a_cloth_held_up_by_contact_line_passes_and_no_multilevel_pass(tmp_path):
    """A cloth with no pins that lands on a ball and clings to it (friction): the multilevel pass, which ignores
    contact, would stretch it more, so the warning does not offer it; line passes need soft shear and bend sticks
    to drape, and converge a landing slower than a sixth of the spacing a substep, which the warning works out
    (1 m / 47 / 6 = 3.5 mm)."""
    s = parse_scene({"simulation": {"fps": 30, "frames": 20, "substeps": 1, "iterations": 1},
                     "cloth": [{"name": "sheet", "resolution": [48, 48], "size": [1.0, 1.0],
                                "origin": [-0.5, 0.4, -0.5], "orientation": "horizontal",
                                "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0}}],
                     "collider": [{"type": "sphere", "radius": 0.25, "centre": [0.0, 0.0, 0.0],
                                   "friction_coefficient": 1.0}]}, "<drape>")
    summary = runner.run_scene(s, tmp_path / "c.usdc", device="cpu")
    assert summary.stretch_max > runner.UNCONVERGED_STRETCH
    (warning,) = [line for line in summary.format().splitlines() if line.startswith("warning")]
    assert "line_passes = 1 and a compliance on its shear sticks (rigid, they make it a plate" in warning
    assert "sixth of its spacing, 3.5 mm, a substep" in warning
    assert "multilevel" not in warning and "tethers" not in warning


def test_the_unconverged_warning_offers_no_multilevel_pass_to_a_cloth_that_can_tear(tmp_path):
    """The multilevel pass refuses a cloth that can tear, by stretch or by tension, so the warning does not offer
    it to either."""
    for tear in ({"tear_threshold": 50.0}, {"tear_tension": 1.0e6}):
        s = parse_scene({"simulation": {"fps": 30, "frames": 15, "substeps": 1, "iterations": 1,
                                        "gravity": [0.0, -30.0, 0.0]},
                         "cloth": [{"name": "big", "resolution": [32, 32], "size": [1.0, 1.0],
                                    "origin": [0.0, 1.0, 0.0], "pins": ["top-left", "top-right"], "tethers": False,
                                    **tear}]}, "<unconverged, tearing>")
        summary = runner.run_scene(s, tmp_path / "c.usdc", device="cpu")
        (warning,) = [line for line in summary.format().splitlines() if line.startswith("warning")]
        assert "more substeps" in warning and "multilevel" not in warning


def _hung(substeps: int, iterations: int, **cloth) -> "Scene":
    """A small pinned cloth that converges and a 24 x 24 one hung by two corners without tethers, 15 frames."""
    big = {"name": "big", "resolution": [24, 24], "size": [1.0, 1.0], "origin": [0.0, 1.0, 0.0],
           "pins": ["top-left", "top-right"], "tethers": False, **cloth}
    return parse_scene({"simulation": {"fps": 30, "frames": 15, "substeps": substeps, "iterations": iterations},
                        "cloth": [{"name": "small", "resolution": [3, 3], "size": [0.2, 0.2],
                                   "origin": [2.0, 1.0, 0.0], "pins": ["top-edge"]}, big]}, "<rubber>")


def test_a_run_that_leaves_a_cloth_rubbery_notes_it_with_what_helps(tmp_path):
    """Short of the warning (no stick at twice its length), a cloth left several percent long on average reads
    as rubber: at 8 x 2 the big cloth ends about 4% long (RMS) with its longest stick about 28% long; the note
    names it (not the small cloth, which converges) and what helps."""
    summary = runner.run_scene(_hung(8, 2), tmp_path / "c.usdc", device="cpu")
    assert summary.stretch_max < runner.UNCONVERGED_STRETCH and summary.stretch_rms > runner.RUBBERY_RMS
    text = summary.format()
    assert "warning" not in text
    (note,) = [line for line in text.splitlines() if line.startswith("note")]
    assert "cloth 'big' (a 24 x 24 grid) ends " in note and "longer than at rest (RMS over its structural" in note
    assert "has not converged at 8 substeps x 2 iterations a frame" in note
    for fix in ("more substeps", "tethers = true", "line_passes = 1"):
        assert fix in note


def test_a_converged_run_and_a_cloth_with_soft_structural_sticks_have_no_rubbery_note(tmp_path):
    """At 16 x 8 the same cloth ends under 1% long (RMS): no note. A cloth whose structural sticks have a
    compliance stretches by its own stiffness, so however long it ends, the note does not count it."""
    converged = runner.run_scene(_hung(16, 8), tmp_path / "a.usdc", device="cpu")
    assert converged.stretch_rms < runner.RUBBERY_RMS and converged.rubbery is None
    soft = runner.run_scene(_hung(8, 2, compliance={"structural": 1.0e-3}), tmp_path / "b.usdc", device="cpu")
    assert runner.RUBBERY_RMS < soft.stretch_rms and soft.stretch_max < runner.UNCONVERGED_STRETCH
    assert soft.rubbery is None and "note" not in soft.format()
