"""The memory estimate matches what the simulator allocates, and a scene too big for the device or the
host is refused before anything is allocated."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.errors import WarpVerletError
import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench.common import device_arrays as every_device_array
from warp_verlet.constraints.self_contact import hash_grid_bytes
from warp_verlet.core.memory import check_fits, estimate, stick_count
from warp_verlet.core.stages import Requirements
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.geometry.topology import build_cloth

FAMILIES = [["structural"], ["shear"], ["bend"], ["structural", "shear", "bend"]]


@pytest.mark.parametrize("sticks", FAMILIES)
@pytest.mark.parametrize("resolution", [[1, 2], [1, 40], [2, 2], [3, 1], [5, 7], [16, 3]])
def test_stick_count_without_building(resolution, sticks):
    spec = make_scene(resolution=resolution, size=[1.0, 1.0], sticks=sticks).cloths[0]
    assert stick_count(spec) == len(build_cloth(spec).sticks)


def mesh_native_bytes(sim: Simulator) -> int:
    """What Warp allocates for each wp.Mesh beyond the points and indices it is given, which no wp.array shows
    (warp/native mesh.cu and bvh.cu): each triangle's bounds (two vec3), 2T - 1 BVH nodes (two 16-byte halves,
    a parent and a count), T primitive indices, a root, and the descriptors the kind allows for. On CUDA,
    tests/test_mesh_collider.py measures the whole from the memory pool."""
    from warp_verlet.colliders.mesh import DESCRIPTOR_BYTES

    total = 0
    for mesh in getattr(sim.model.colliders, "mesh_bvhs", ()):
        triangles = len(mesh.indices) // 3
        total += triangles * 2 * 12 + (2 * triangles - 1) * (2 * 16 + 2 * 4) + triangles * 4 + 4 + DESCRIPTOR_BYTES
    return total


def device_arrays(obj) -> list[wp.array]:
    return [a for a in vars(obj).values() if isinstance(a, wp.array)]


def simulator_bytes(sim: Simulator) -> int:
    """Bytes of every device array the simulator holds (bench.common.device_arrays: the Model's, its levels',
    its colliders', the State's and the solver's scratch, each shared array once). Call after a step: scratch
    buffers are allocated when the solver binds its launches."""
    state = sim.state
    # clone() and assign() copy what arrays() lists: every array a State holds must be there.
    assert {a.ptr for a in device_arrays(state)} == {a.ptr for a in state.arrays().values()}
    return sum(a.capacity for a in every_device_array(sim).values())


# (simulation, cloth) overrides on a 24 x 31 cloth with every stick family: each solver with and without
# tearing, tethers (on by default for a pinned cloth that cannot tear; asked for on a tearing one), soft sticks
# (a compliance per stick, a tension of scratch), and colliders (planes; a still sphere; a moving one, which adds
# its keyframes, a clock and per-sphere key starts).
GROUND = {"type": "plane", "point": [0.0, -1.0, 0.0], "friction_coefficient": 0.3}
WALL = {"type": "plane", "point": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "thickness": 0.01}
BALL = {"type": "sphere", "radius": 0.2, "centre": [0.3, -0.5, 0.2]}
SWEEP = {"type": "sphere", "radius": 0.1, "path": [[0.0, 0.0, 0.0, 0.5], [0.5, 1.0, 0.0, 0.5], [1.0, 1.0, -1.0, 0.5]]}
TABLE = {"type": "mesh", "mesh": str(Path(__file__).resolve().parent.parent / "scenes" / "assets" / "table.obj"),
         "translate": [0.0, -2.0, 0.0]}
CASES = {
    "coloured": ({}, {}),
    "jacobi": ({"relaxation": "jacobi"}, {}),
    "coloured-tear": ({}, {"tear_threshold": 1.5}),
    "jacobi-tear": ({"relaxation": "jacobi"}, {"tear_threshold": 1.5}),
    "tethers": ({}, {"pins": ["top-left", "top-right"]}),
    "jacobi-tethers": ({"relaxation": "jacobi"}, {"pins": ["top-edge"]}),
    "tethers-tear": ({}, {"pins": ["top-left", "top-right"], "tear_threshold": 1.5, "tethers": True,
                          "tether_scale": 2.0}),
    "compliance": ({}, {"compliance": {"bend": 1e-3}}),
    "compliance-tear": ({}, {"compliance": {"shear": 1e-4, "bend": 1e-3}, "tear_threshold": 1.5}),
    "multilevel": ({"multilevel": True}, {"pins": ["top-left", "top-right"]}),
    "jacobi-multilevel": ({"relaxation": "jacobi", "multilevel": True}, {}),
    "planes": ({}, {}, [GROUND, WALL]),
    "still-sphere": ({}, {}, [BALL]),
    "moving-sphere": ({}, {}, [SWEEP, GROUND]),
    "everything": ({}, {"pins": ["top-edge"], "compliance": {"bend": 1e-3}, "tear_threshold": 1.5,
                        "tethers": True, "tether_scale": 2.0}, [SWEEP, BALL, GROUND, WALL]),
    "jacobi-everything": ({"relaxation": "jacobi"}, {"pins": ["top-edge"], "tear_threshold": 1.5, "tethers": True,
                                                 "tether_scale": 2.0}, [SWEEP, BALL, GROUND]),
    # float64 positions: 24 bytes for each of the State's three and the Jacobi scratch, the rest float32 as before
    "float64": ({"precision": "float64"}, {}),
    "float64-everything": ({"precision": "float64"}, {"pins": ["top-edge"], "compliance": {"bend": 1e-3},
                                                      "tear_threshold": 1.5, "tethers": True, "tether_scale": 2.0},
                           [SWEEP, BALL, GROUND, WALL]),
    "float64-jacobi-everything": ({"relaxation": "jacobi", "precision": "float64"}, {"pins": ["top-edge"],
                                  "tear_threshold": 1.5, "tethers": True, "tether_scale": 2.0}, [SWEEP, BALL, GROUND]),
    "auto-float64": ({"substeps": 1000, "relaxation": "jacobi"}, {}),  # "auto" below the float32 floor
    "angle-limit": ({}, {"max_bend_angle": 30.0}),  # joints along rows and columns, and their limits
    "angle-limit-float64": ({"precision": "float64"}, {"pins": ["top-edge"], "max_bend_angle": 30.0}),
    "rigid-patches": ({}, {"pins": ["top-left"], "rigid_patches": [[[0, 0], [0, 1], [1, 0], [1, 1]],
                                                                   [[5, 5], [5, 6], [6, 5]]]}),
    "self-contact": ({}, {"self_collision": True}),  # per particle: thickness, rest, cloth, a scratch position
    "jacobi-self-contact-float64": ({"relaxation": "jacobi", "precision": "float64"}, {"self_collision": True}),
    # every other row and column: per colliding particle its index, and the positions the search reads
    "self-contact-stride": ({}, {"self_collision": True, "self_collision_stride": 2}),
    # triangle meshes (points and indices, a wp.Mesh id, reach, thickness, friction, a translation in the Model
    # and the State, and a BVH of its own); a moving one adds its keyframes, a clock and per-mesh key starts
    "mesh": ({}, {}, [BALL, TABLE, dict(TABLE, translate=[0.0, -3.0, 0.0]), GROUND]),
    "moving-mesh": ({}, {}, [SWEEP, TABLE, dict(TABLE, translate=[[0.0, 0.0, -3.0, 0.0], [1.0, 1.0, -3.0, 0.0]])]),
    # the global correction: its own stick table and CSR, per-particle vectors and blocks, a position snapshot
    "global": ({"global_iterations": 3}, {}, [BALL, GROUND]),  # with its multigrid levels
    "global-jacobi": ({"global_iterations": 3, "global_preconditioner": "jacobi"}, {"pins": ["top-left"]}),
    "global-float64-tear": ({"global_iterations": 3, "precision": "float64"}, {"tear_threshold": 1.5}, [SWEEP]),
    # line solves: a vec4i per row and column and a rest length per gap; with colliders a position snapshot and a
    # contact normal per particle
    "line-solves": ({}, {"line_passes": 1, "compliance": {"bend": 1e-3}}, [SWEEP, GROUND]),
    "line-solves-float64": ({"precision": "float64"}, {"line_passes": 2}, [BALL]),
    "line-solves-alone": ({}, {"line_passes": 1}),
}


# The cases above that allow implicit grid sticks (one grid cloth that cannot tear, the coloured solver), again
# with them ("auto" keeps stick arrays on the CPU).
IMPLICIT = ["coloured", "tethers", "compliance", "multilevel", "float64", "moving-sphere", "planes", "angle-limit",
            "rigid-patches", "self-contact", "self-contact-stride", "global", "line-solves", "line-solves-alone"]


# The cases that allow tiled sweeps (kernels/grid_tiles.py).
TILED = ["coloured", "tethers", "compliance", "multilevel", "float64", "moving-sphere", "planes", "angle-limit",
         "rigid-patches", "self-contact", "global", "line-solves"]


# The float32 cases of the coloured solver that cannot tear, which allow clustered sweeps of stick arrays (soft
# sticks too, without the global correction).
CLUSTERED = ["coloured", "tethers", "compliance", "multilevel", "moving-sphere", "planes", "self-contact", "global"]


@pytest.mark.parametrize("case", list(CASES) + [f"{c}/implicit" for c in IMPLICIT] + [f"{c}/tiled" for c in TILED]
                         + [f"{c}/clustered" for c in CLUSTERED] + [f"{CLUSTERED[0]}/chained"])
def test_estimate_matches_the_arrays_allocated(case, monkeypatch):
    case, _, sticks = case.partition("/")
    chained = sticks == "chained"
    if chained:  # a clustered sweep chained (of any size here): its neighbour lists and chain counted
        from warp_verlet.constraints import stick_clusters

        monkeypatch.setattr(stick_clusters, "MIN_CHAINED_PARTICLES", 0)
        sticks = "clustered"
    simulation, cloth, *colliders = CASES[case]
    spec = {"resolution": [24, 31], "size": [1.0, 1.0], "sticks": FAMILIES[-1], **cloth}
    scene = parse_scene({"simulation": simulation, "cloth": [spec], "collider": colliders[0] if colliders else []},
                        file="<test>")
    sim = Simulator(scene, "cpu", use_graph=False, sticks=sticks or "auto")
    sim.step()
    assert sim.model.sticks_form == (sticks or "explicit")
    assert sim.precision == ("float64" if "float64" in case else "float32")
    # The only arrays not in the estimate are one-element counters: the tear counter (4 bytes), and the
    # Jacobi CSR's extra row start (4 bytes). A moving sphere's key starts are counted (spheres + 1 of them).
    counters = 4 * (scene.tears + (scene.simulation.relaxation == "jacobi"))
    # Warp's hash grid (self contact) and a mesh's BVH allocate outside any wp.array: counted from Warp's source.
    contact = Requirements.of(scene).count("self contact")
    native = hash_grid_bytes(contact[0], contact[1]) if contact else 0
    allocated = simulator_bytes(sim) + native + mesh_native_bytes(sim)
    # Clustered sticks are estimated before their layout is built, by a bound: every particle and one other end
    # per stick in the regions, MAX_COLOURS stick colours per cluster. What the layout left of it is exact.
    slack = 0
    if sticks == "clustered":
        from warp_verlet.geometry.colouring import MAX_COLOURS

        from warp_verlet.constraints.stick_clusters import MAX_CHAINED_NEIGHBOURS

        data = sim.model.constraints["stick clusters"]
        clusters = data.region_start.shape[0] - 1
        slack = 4 * (scene.particle_count + sim.model.stick_count - data.region.shape[0]
                     + clusters * (MAX_COLOURS - data.colours))
        assert (data.neighbour is not None) == chained
        if data.neighbour is not None:  # a chained sweep's lists, bounded by MAX_CHAINED_NEIGHBOURS a cluster
            slack += 4 * (clusters * MAX_CHAINED_NEIGHBOURS - data.neighbour.shape[0])
    assert allocated - estimate(scene, sim.model.sticks_form).device_bytes == counters - slack


def test_a_scene_too_big_for_the_machine_is_refused_before_allocating():
    huge = make_scene(resolution=[32768, 32768], sticks=FAMILIES[-1])  # 1 G particles, 6.4 G sticks
    start = time.perf_counter()
    with pytest.raises(WarpVerletError, match=r"1,073,741,824 particles .* need about .* GiB.*lower the resolution"):
        Simulator(huge, "cpu")
    assert time.perf_counter() - start < 5.0  # refused from the counts, not after trying to build it


def test_device_and_host_limits_are_named():
    scene = make_scene(resolution=[64, 64])
    req = estimate(scene)
    with pytest.raises(WarpVerletError, match="cuda:0 has only"):
        check_fits(scene, "cuda:0", device_free=req.device_bytes - 1, host_free=None)
    with pytest.raises(WarpVerletError, match="this machine has only"):
        check_fits(scene, "cpu", device_free=None, host_free=req.device_bytes + req.host_bytes - 1)
    assert check_fits(scene, "cpu", device_free=None, host_free=req.device_bytes + req.host_bytes) == req
    # Per particle three positions and an inverse mass; stick arrays keep ends, rest and weight per stick, where
    # implicit grid sticks keep rest lengths 1 and 2 columns and rows apart (float32) and squared steps 1 column
    # and 1 row apart (float64, for shear sticks).
    assert estimate(scene, "explicit").device_bytes == 64 * 64 * 40 + 2 * 64 * 63 * 16
    assert estimate(scene, "implicit").device_bytes == req.device_bytes == 64 * 64 * 40 + 250 * 4 + 126 * 8


def test_a_simulator_derives_the_scenes_requirements_once(monkeypatch):
    # The memory check, the model and the solver read one Requirements: counting every kind again (a mesh's
    # hinges, the multilevel hierarchy's sizes) for each of them would be wasted work and could disagree.
    from warp_verlet.core.stages import Requirements

    calls = []
    real_of = Requirements.of.__func__
    monkeypatch.setattr(Requirements, "of", classmethod(lambda cls, *a, **k: calls.append(1) or real_of(cls, *a, **k)))
    Simulator(make_scene(resolution=[6, 6], pins=["top-left"], max_bend_angle=30.0), "cpu")
    assert len(calls) == 1
