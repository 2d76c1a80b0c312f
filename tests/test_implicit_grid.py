"""Implicit grid sticks and tethers (kernels/grid_relax.py, stages.GridSticks / GridTethers): the same positions as
the explicit stick and tether arrays bit for bit, no stick arrays on the device, and the rule that picks them."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.errors import ArgumentError
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.core import stages
from warp_verlet.core.stages import MAX_GRID_TETHER_PINS, implicit_grid_obstacle

SCENES = Path(__file__).resolve().parent.parent / "scenes"
SMALL = 14  # rows and columns at most: the shipped configurations, small enough to step a few frames quickly


def shipped_grid_scenes() -> list[str]:
    """The shipped scene files whose cloths are all grids."""
    names = []
    for path in sorted(SCENES.glob("*.toml")):
        data = tomllib.loads(path.read_text())
        if all("resolution" in cloth for cloth in data.get("cloth", [])):
            names.append(path.stem)
    return names


def small_scene(name: str, precision: str):
    """A shipped scene at a small resolution (its pins named or indexed as in the file, which resolve against
    the smaller grid), in the given precision."""
    path = SCENES / f"{name}.toml"
    data = tomllib.loads(path.read_text())
    data["simulation"]["precision"] = precision
    for cloth in data["cloth"]:
        cloth["resolution"] = [min(n, SMALL) for n in cloth["resolution"]]
    return parse_scene(data, str(path), path)


def run_frames(scene, device: str, sticks: str, frames: int = 5) -> tuple[np.ndarray, Simulator]:
    sim = Simulator(scene, device, sticks=sticks)
    for _ in range(frames):
        sim.step_frame()
    return sim.positions(), sim


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("name", shipped_grid_scenes())
def test_implicit_and_explicit_sticks_agree_bit_for_bit_on_every_shipped_grid_scene(name, precision, device):
    scene = small_scene(name, precision)
    explicit, reference = run_frames(scene, device, "explicit")
    assert "sticks" in reference.constraint_sets
    if implicit_grid_obstacle(scene) is not None:  # a tearing cloth, or several cloths: the stick arrays serve
        assert scene.tears or len(scene.cloths) > 1
        assert Simulator(scene, device).constraint_sets == reference.constraint_sets
        return
    auto, sim = run_frames(scene, device, "implicit")
    assert "grid sticks" in sim.constraint_sets
    cloth = scene.cloths[0]
    if cloth.uses_tethers:
        grid_tethers = cloth.pin_count <= MAX_GRID_TETHER_PINS
        assert ("grid tethers" if grid_tethers else "tethers") in sim.constraint_sets
    assert np.abs(explicit - explicit[0]).max() > 0.0  # the cloth moved: the comparison below means something
    np.testing.assert_array_equal(auto, explicit)


@pytest.mark.parametrize("cloth", [
    {"pins": ["top-left", "top-right"], "tethers": True},  # two pins: every particle tied to both
    {"pins": [[0, 0], [0, 4], [0, 9], [5, 0]], "tethers": True, "tether_scale": 1.2},  # nearest two of four
    {"pins": ["top-edge"], "tethers": True},  # more pins than implicit tethers take: the table serves
    {"pins": ["top-left"], "orientation": "horizontal", "compliance": {"shear": 1e-4, "bend": 1e-2}},
    {"sticks": ["bend"], "pins": ["top-right"]},
    {"sticks": ["shear"], "resolution": [2, 9], "pins": ["top-left"]},
    {"sticks": ["structural", "bend"], "resolution": [1, 11], "pins": [0]},  # a rope: no rows to cross
    {"resolution": [12, 3], "origin": [0.3, 7.1, -2.0], "size": [0.77, 0.31], "pins": ["top-left"]},
    # particle masses: the kernels read every weight (elsewhere the free particles share one, and pins weigh 0)
    {"pins": ["top-left", "top-right"], "particle_masses": [[4, 6, 0.05], [9, 0, 0.001]], "tethers": True},
    {"pins": [], "compliance": {"bend": 1e-3}},  # no pins: every weight read too
])
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_grid_configurations_agree_bit_for_bit(cloth, precision, device):
    spec = {"resolution": [10, 13], "size": [1.0, 1.3], "origin": [-0.5, 1.0, 0.2], "mass": 0.2,
            "sticks": ["structural", "shear", "bend"], **cloth}
    # Wind across the sheet, so that even a cloth hanging at rest from a pinned edge moves.
    scene = make_scene({"substeps": 3, "iterations": 3, "precision": precision, "wind": [0.5, 0.0, 4.0]}, **spec)
    explicit, _ = run_frames(scene, device, "explicit", frames=8)
    implicit, sim = run_frames(scene, device, "implicit", frames=8)
    assert sim.model.sticks_form == "implicit"
    assert np.abs(explicit - sim.model.rest_positions).max() > 1e-3  # it moved
    np.testing.assert_array_equal(implicit, explicit)


def test_the_rule_picks_implicit_sticks_for_one_grid_cloth_that_cannot_tear(device):
    grid = make_scene(resolution=[6, 6], sticks=["structural", "shear"], pins=["top-left", "top-right"])
    # "auto": implicit sticks and the tether table on a GPU, stick arrays on the CPU (each measured faster there)
    auto = ("tethers", "grid sticks") if device == "cuda" else ("tethers", "sticks")
    assert Simulator(grid, device).constraint_sets == auto
    assert Simulator(grid, device, sticks="implicit").constraint_sets == ("grid tethers", "grid sticks")
    assert Simulator(grid, device, sticks="explicit").constraint_sets == ("tethers", "sticks")
    assert Simulator(grid, device, colouring="graph").constraint_sets == ("tethers", "sticks")
    edge = make_scene(resolution=[6, 12], pins=["top-edge"], tethers=True)  # 12 pins: the tether table
    assert Simulator(edge, device, sticks="implicit").constraint_sets == ("tethers", "grid sticks")
    for other, reason in [
        (make_scene(resolution=[6, 6], tear_threshold=1.5), "can tear"),
        (make_scene({"relaxation": "jacobi"}, resolution=[6, 6]), "Jacobi"),
        (parse_scene({"cloth": [{"name": "a", "resolution": [4, 4], "size": [1.0, 1.0]},
                                {"name": "b", "resolution": [4, 4], "size": [1.0, 1.0], "origin": [2.0, 0.0, 0.0]}]},
                     file="<test>"), "several cloths"),
    ]:
        assert Simulator(other, device).constraint_sets[-1] == "sticks"
        with pytest.raises(ArgumentError, match=reason):
            Simulator(other, device, sticks="implicit")
    with pytest.raises(ArgumentError, match="colouring='graph'"):
        Simulator(grid, device, colouring="graph", sticks="implicit")
    with pytest.raises(ArgumentError, match="sticks must be one of"):
        Simulator(grid, device, sticks="lazy")


@pytest.mark.parametrize("compliance, smallest_tiled, sets, same_as, precision", [
    ({}, 0, ("tethers", "grid tiles"), "tiled", "float32"),  # rigid sticks of a large grid: swept tile by tile
    ({}, 0, ("tethers", "grid tiles"), "tiled", "float64"),  # float64 positions: tiled too
    ({}, 64, ("tethers", "grid sticks"), "explicit", "float32"),  # a grid below the tiles' size: a launch per colour
    ({"bend": 1e-3}, 0, ("tethers", "grid tiles"), "tiled", "float32"),  # a soft family of a large grid: tiled too
    ({"bend": 1e-3}, 64, ("tethers", "grid sticks"), "explicit", "float32"),  # soft, small: a launch per colour
])
def test_auto_on_a_gpu_computes_the_sticks_and_keeps_the_tether_table(compliance, smallest_tiled, sets, same_as,
                                                                      precision, monkeypatch):
    """What "auto" does on a GPU, on the CPU: the rule's device test answered as a GPU would."""
    import warp_verlet.core.model as model_module

    real = model_module.stick_form
    monkeypatch.setattr(stages, "MIN_TILED_PARTICLES", smallest_tiled)
    monkeypatch.setattr(model_module, "stick_form", lambda sticks, colouring, device: real(
        sticks, colouring, type("GPU", (), {"is_cpu": False})()))
    scene = make_scene({"substeps": 2, "precision": precision}, resolution=[7, 9], pins=["top-left", "top-right"],
                       sticks=["structural", "shear", "bend"], compliance=compliance)
    sim = Simulator(scene, "cpu")
    assert sim.constraint_sets == sets
    assert hasattr(sim.model, "tether_pin") and not hasattr(sim.model, "stick_ends")
    for _ in range(3):
        sim.step_frame()
    reference, _ = run_frames(scene, "cpu", same_as, frames=3)
    np.testing.assert_array_equal(sim.positions(), reference)


def test_implicit_sticks_allocate_no_stick_arrays_and_issue_one_launch_per_colour(launches):
    k = 3
    scene = make_scene({"iterations": k}, resolution=[8, 9], sticks=["structural", "shear", "bend"],
                       pins=["top-left", "top-right"], compliance={"bend": 1e-3})
    sim = Simulator(scene, "cpu", use_graph=False, sticks="implicit")
    model = sim.model
    for name in ("stick_ends", "stick_rest", "stick_weight", "tether_pin", "tether_length"):
        assert not hasattr(model, name), name
    assert model.stick_compliance is None
    soft = [c.count for c in model.grid.colours if c.compliance > 0]
    assert len(soft) == 4 and model.grid.soft_sticks == sum(soft) == 8 * 7 + 6 * 9  # the bend sticks
    sim.step()
    assert sim.solver._scratch["grid_tension"].shape == (model.grid.soft_sticks,)
    colours = ["relax_grid_colour"] * 8 + ["relax_grid_colour_compliant"] * 4
    assert launches.of(sim.step) == ["verlet_step", "zero"] + (["pull_grid_tethers"] + colours) * k
    assert model.grid.pins.numpy().tolist() == [0, 8]  # the pins a projection checks: the free weigh alike


def test_implicit_colours_cover_every_stick_once_in_the_analytic_order():
    """The colour sizes match the explicit model's colour ranges (the Model checks that too), and together the
    colours project every stick: the number of projections equals the stick count."""
    for resolution in ([1, 5], [2, 2], [3, 7], [8, 5], [9, 9]):
        scene = make_scene(resolution=resolution, sticks=["structural", "shear", "bend"])
        explicit = Simulator(scene, "cpu", sticks="explicit").model
        implicit = Simulator(scene, "cpu", sticks="implicit").model
        sizes = [c.count for c in implicit.grid.colours]
        assert sizes == [n for _, n in explicit.colour_ranges]
        assert sum(sizes) == explicit.stick_count


def test_retune_keeps_the_sticks_form():
    scene = make_scene({"substeps": 2}, resolution=[6, 6], pins=["top-left"])
    explicit = Simulator(scene, "cpu", sticks="explicit")
    explicit.retune(iterations=3)
    assert explicit.constraint_sets == ("tethers", "sticks")
    implicit = Simulator(scene, "cpu", sticks="implicit")
    implicit.retune(iterations=3)
    assert implicit.constraint_sets == ("grid tethers", "grid sticks")
    for sim in (explicit, implicit):
        sim.step_frame()
    np.testing.assert_array_equal(implicit.positions(), explicit.positions())


def test_a_lattice_that_is_not_uniform_is_refused():
    from warp_verlet.core.model import grid_axes
    from warp_verlet.geometry.topology import build_cloth

    top = build_cloth(make_scene(resolution=[4, 5]).cloths[0])
    grid_axes(top)  # a built grid is a lattice
    bent = replace(top, positions=top.positions.copy())
    bent.positions[7, 1] += 1e-3
    with pytest.raises(AssertionError, match="not a uniform lattice"):
        grid_axes(bent)
