"""A coloured stick launch on the CPU gives each thread its whole piece of a colour, projected in one loop inside
the kernel (kernels/relax.py, warp_verlet/launches.elements_per_thread); on a GPU each thread takes one stick.
The sticks of a colour share no particle, so the order cannot change a bit: the positions must equal those of
one stick a thread, with pins, tethers, soft sticks, colliders and both kinds of tearing, on one thread and cut
over a thread team; a Jacobi gather and the tethers take their piece's particles the same way. Implicit grid
sticks (kernels/grid_relax.py) take whole rows of anchors a thread on the CPU, and must give the stick arrays'
positions, as tests/test_implicit_grid.py asks of them in general."""

from __future__ import annotations

import numpy as np
import pytest

import warp_verlet.constraints.sticks as sticks_module
import warp_verlet.constraints.tethers as tethers_module
from warp_verlet.input.scene import parse_scene
from warp_verlet.launches import elements_per_thread
from warp_verlet.core.simulator import Simulator

RELAX_KERNELS = ("relax_colour", "relax_colour_compliant", "relax_colour_tension", "relax_jacobi", "pull_tethers")


def scene_with(name: str):
    """A 17 x 23 hanging cloth (several colours, uneven pieces over threads) with what ``name`` asks for."""
    cloth = {"resolution": [17, 23], "size": [1.0, 1.3], "pins": ["top-left", "top-right"],
             "sticks": ["structural", "shear", "bend"]}
    colliders = []
    if name == "rigid, tethers, masses":
        cloth.update(tethers=True, tether_scale=1.2, particle_masses=[[4, 6, 0.05], [9, 0, 0.001]])
    elif name == "soft, tethers, tearing, colliders":
        cloth.update(compliance={"shear": 0.02, "bend": 0.2}, tethers=True, tether_scale=1.5, tear_threshold=1.2)
        colliders = [{"type": "sphere", "radius": 0.2, "path": [[0.0, 0.0, 0.3, 1.0], [0.5, 0.0, 0.3, -1.0]]},
                     {"type": "plane", "point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]}]
    elif name == "rigid, tearing by tension":
        cloth.update(pins=["top-edge"], tear_tension=1.0)
    elif name == "soft, tearing by tension, float64":
        cloth.update(pins=["top-edge"], tear_tension=1.0, compliance={"bend": 1e-3})
    elif name == "jacobi, tethers, tearing, colliders":
        cloth.update(tethers=True, tether_scale=1.5, tear_threshold=1.2)
        colliders = [{"type": "sphere", "radius": 0.2, "path": [[0.0, 0.0, 0.3, 1.0], [0.5, 0.0, 0.3, -1.0]]}]
    simulation = {"fps": 60, "substeps": 3, "iterations": 5, "wind": [8.0, 0.0, 3.0]}
    if name.startswith("jacobi"):
        simulation["relaxation"] = "jacobi"
    if name.endswith("float64"):
        simulation["precision"] = "float64"
    return parse_scene({"simulation": simulation, "cloth": [cloth], "collider": colliders}, file=f"<{name}>")


SCENES = ["rigid, tethers, masses", "soft, tethers, tearing, colliders", "rigid, tearing by tension",
          "soft, tearing by tension, float64", "jacobi, tethers, tearing, colliders"]
KERNEL_OF = {"rigid, tethers, masses": "relax_colour", "soft, tethers, tearing, colliders": "relax_colour_compliant",
             "rigid, tearing by tension": "relax_colour_tension",
             "soft, tearing by tension, float64": "relax_colour_compliant",
             "jacobi, tethers, tearing, colliders": "relax_jacobi"}


@pytest.fixture
def stick_launches(monkeypatch):
    """The stick launches bound from now on, as (kernel, threads, first, sticks or particles per thread)."""
    seen = []
    real = sticks_module.recorded

    def spy(kernel, dim, inputs, outputs=None, **kwargs):
        if kernel.key in RELAX_KERNELS:
            if kernel.key == "pull_tethers":  # its piece is a slice of the tether table
                first, per_thread = None, inputs[-1]
            else:
                first, per_thread = inputs[-3:-1] if kernel.key == "relax_jacobi" else inputs[-2:]  # jacobi: x_out
            seen.append((kernel.key, dim, first, per_thread))
        return real(kernel, dim, inputs, outputs, **kwargs)

    monkeypatch.setattr(sticks_module, "recorded", spy)
    monkeypatch.setattr(tethers_module, "recorded", spy)
    return seen


def run(scene, frames: int, threads: int) -> tuple[np.ndarray, int]:
    sim = Simulator(scene, "cpu", threads=threads)
    for _ in range(frames):
        sim.step_frame()
    return sim.positions(), sim.torn_count()


def test_a_cpu_launch_gives_one_thread_a_whole_piece_and_a_gpu_launch_one_stick_a_thread(stick_launches):
    class Device:
        def __init__(self, cpu):
            self.is_cpu = cpu

    assert elements_per_thread(1234, Device(True)) == 1234
    assert elements_per_thread(1234, Device(False)) == 1
    scene = scene_with("rigid, tethers, masses")
    for threads in (1, 2):
        stick_launches.clear()
        sim = Simulator(scene, "cpu", threads=threads)
        sim.step()
        assert all(dim == 1 for _, dim, _, _ in stick_launches), "a CPU launch ran more than one thread"
        pieces = [(first, per_thread) for kernel, dim, first, per_thread in stick_launches if kernel == "relax_colour"]
        # The pieces tile every colour: threads pieces a colour, in order, covering its sticks exactly once.
        assert len(pieces) == threads * len(sim.model.colour_ranges)
        covered = [s for first, per_thread in pieces for s in range(first, first + per_thread)]
        assert covered == list(range(sim.model.stick_count))


@pytest.mark.parametrize("name", SCENES)
def test_whole_pieces_give_the_positions_of_one_element_a_thread_bit_for_bit(monkeypatch, stick_launches, name):
    scene = scene_with(name)
    whole = {threads: run(scene, 12, threads) for threads in (1, 2)}
    tethered = "tethers" in name
    assert {kernel for kernel, *_ in stick_launches} == {KERNEL_OF[name]} | ({"pull_tethers"} if tethered else set())
    assert all(dim == 1 for _, dim, _, _ in stick_launches)
    stick_launches.clear()
    for module in (sticks_module, tethers_module):
        monkeypatch.setattr(module, "elements_per_thread", lambda count, device: 1)
    one = {threads: run(scene, 12, threads) for threads in (1, 2)}
    assert stick_launches and all(per_thread == 1 for *_, per_thread in stick_launches)
    assert any(dim > 1 for _, dim, _, _ in stick_launches)
    if "tear" in name:
        assert one[1][1] > 0, "the scene should tear, so that the comparison covers tearing"
    for threads in (1, 2):
        (points, torn), (expected, expected_torn) = whole[threads], one[threads]
        assert torn == expected_torn
        assert points.dtype == (np.float64 if name.endswith("float64") else np.float32)
        differ = (points != expected).any(axis=1)
        assert not differ.any(), (f"{name}, {threads} threads: whole pieces moved {differ.sum()} particles off the "
                                  f"one-stick-a-thread positions (by up to {np.abs(points - expected).max():.2e} m)")


# ---------------------------------------------------------------------------------------------- implicit grid sticks
GRID_KERNELS = ("relax_grid_colour", "relax_grid_colour_compliant")
GRID_CLOTHS = {
    "rigid, two pins": {"pins": ["top-left", "top-right"]},
    "soft shear and bend, horizontal": {"pins": ["top-left"], "orientation": "horizontal",
                                        "compliance": {"shear": 1e-4, "bend": 1e-2}},
    "particle masses, tethers": {"pins": ["top-left", "top-right"], "particle_masses": [[4, 6, 0.05], [9, 0, 0.001]],
                                 "tethers": True},
    "soft bend, float64": {"pins": ["top-edge"], "compliance": {"bend": 1e-3}},
}


def grid_scene(name: str):
    cloth = {"resolution": [13, 19], "size": [1.0, 1.3], "sticks": ["structural", "shear", "bend"],
             **GRID_CLOTHS[name]}
    simulation = {"fps": 60, "substeps": 3, "iterations": 5, "wind": [8.0, 0.0, 3.0]}
    if name.endswith("float64"):
        simulation["precision"] = "float64"
    return parse_scene({"simulation": simulation, "cloth": [cloth]}, file=f"<{name}>")


@pytest.fixture
def grid_launches(monkeypatch):
    """The implicit grid stick launches bound from now on, as (kernel, threads, rows of anchors a thread)."""
    seen = []
    real = sticks_module.recorded

    def spy(kernel, dim, inputs, outputs=None, **kwargs):
        if kernel.key in GRID_KERNELS:
            seen.append((kernel.key, dim, inputs[-1]))
        return real(kernel, dim, inputs, outputs, **kwargs)

    monkeypatch.setattr(sticks_module, "recorded", spy)
    return seen


@pytest.mark.parametrize("name", list(GRID_CLOTHS))
def test_implicit_grid_rows_a_thread_give_the_stick_arrays_positions_bit_for_bit(monkeypatch, grid_launches, name):
    # On the CPU a thread takes its piece's whole rows of anchors; with one row a thread (elements_per_thread
    # made 1) the rows of a piece go to several threads of one launch. Both must give the stick arrays' positions.
    scene = grid_scene(name)
    expected = {}
    for threads in (1, 3):
        sim = Simulator(scene, "cpu", threads=threads, sticks="explicit")
        for _ in range(8):
            sim.step_frame()
        expected[threads] = sim.positions()
        assert np.abs(expected[threads] - sim.model.rest_positions).max() > 1e-3  # the cloth moved
    for rows_a_thread in ("whole piece", "one row"):
        if rows_a_thread == "one row":
            monkeypatch.setattr(sticks_module, "elements_per_thread", lambda count, device: 1)
        for threads in (1, 3):
            grid_launches.clear()
            sim = Simulator(scene, "cpu", threads=threads, sticks="implicit")
            for _ in range(8):
                sim.step_frame()
            assert "grid sticks" in sim.constraint_sets and grid_launches
            if rows_a_thread == "whole piece":
                assert all(dim == 1 and per_thread >= 1 for _, dim, per_thread in grid_launches)
            else:
                assert all(per_thread == 1 for *_, per_thread in grid_launches)
                assert any(dim > 1 for _, dim, _ in grid_launches)
            points = sim.positions()
            differ = (points != expected[threads]).any(axis=1)
            worst = np.abs(points - expected[threads]).max()
            assert not differ.any(), (f"{name}, {rows_a_thread}, {threads} threads: {differ.sum()} particles off the "
                                      f"stick arrays' positions (by up to {worst:.2e} m)")
