"""The memory estimate matches what the simulator allocates, and a scene too big for the device or the
host is refused before anything is allocated."""

from __future__ import annotations

import time

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.errors import WarpVerletError
from warp_verlet.memory import check_fits, estimate, stick_count
from warp_verlet.simulator import Simulator
from warp_verlet.topology import build_cloth

FAMILIES = [{"structural": 1.0}, {"shear": 1.0}, {"bend": 0.5}, {"structural": 1.0, "shear": 1.0, "bend": 0.5}]


@pytest.mark.parametrize("sticks", FAMILIES)
@pytest.mark.parametrize("resolution", [[1, 2], [1, 40], [2, 2], [3, 1], [5, 7], [16, 3]])
def test_stick_count_without_building(resolution, sticks):
    spec = make_scene(resolution=resolution, size=[1.0, 1.0], sticks=sticks).cloths[0]
    assert stick_count(spec) == len(build_cloth(spec).sticks)


def simulator_bytes(sim: Simulator) -> int:
    arrays = {a.ptr: a for a in list(vars(sim).values()) + list(vars(sim.model).values()) if isinstance(a, wp.array)}
    return sum(a.capacity for a in arrays.values())


@pytest.mark.parametrize("solver", ["coloured", "jacobi"])
@pytest.mark.parametrize("tear", [None, 1.5])
def test_estimate_matches_the_arrays_allocated(solver, tear):
    extra = {} if tear is None else {"tear_threshold": tear}
    scene = make_scene({"solver": solver}, resolution=[24, 31], sticks=FAMILIES[-1], **extra)
    sim = Simulator(scene, "cpu")
    # The only arrays not in the estimate are one-element counters (the tear counter) and the CSR's extra
    # row start: a few bytes.
    assert 0 <= simulator_bytes(sim) - estimate(scene).device_bytes <= 16


def test_a_scene_too_big_for_the_machine_is_refused_before_allocating():
    huge = make_scene(resolution=[32768, 32768], sticks=FAMILIES[-1])  # 1 G particles, 6.4 G sticks
    start = time.perf_counter()
    with pytest.raises(WarpVerletError, match=r"1,073,741,824 particles .* need about .* GiB.*lower the resolution"):
        Simulator(huge, "cpu")
    assert time.perf_counter() - start < 5.0  # refused from the counts, not after trying to build it


def test_device_and_host_limits_are_named():
    scene = make_scene(resolution=[64, 64])
    need = estimate(scene)
    with pytest.raises(WarpVerletError, match="cuda:0 has only"):
        check_fits(scene, "cuda:0", device_free=need.device_bytes - 1, host_free=None)
    with pytest.raises(WarpVerletError, match="this machine has only"):
        check_fits(scene, "cpu", device_free=None, host_free=need.device_bytes + need.host_bytes - 1)
    assert check_fits(scene, "cpu", device_free=None, host_free=need.device_bytes + need.host_bytes) == need
    assert np.isclose(need.device_bytes, 64 * 64 * 40 + 2 * 64 * 63 * 16)
