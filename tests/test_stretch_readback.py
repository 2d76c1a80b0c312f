"""The target_stretch budget's stretch, reduced on the device (simulator.StretchReadback, kernels/readback.py):
the host's RMS over the same sticks, the same number on every run, one frame late on CUDA without the budget
over-reacting, and one captured frame per substep count."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from conftest import make_scene
from warp_verlet.core.budget import Budget
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator, StretchReadback

from test_multilevel import hanging  # tests/ is on sys.path (pytest, rootdir-relative imports)


def budget_scene(target: float, n: int = 24, **cloth):
    """A cloth that starts level and swings down from two corners, with a target stretch (hung where it hangs, its
    tethers would hold it still, and the budget would have nothing to do)."""
    data = hanging(n, tethers=True, target_stretch=target)
    del data["simulation"]["substeps"], data["simulation"]["iterations"]
    data["cloth"][0].update({"orientation": "horizontal", **cloth})
    return parse_scene(data, file="<budget>")


@pytest.mark.parametrize("case", ["implicit", "explicit", "torn", "mesh-free two cloths"])
def test_the_device_rms_is_the_host_rms_and_repeats_exactly(case, device):
    if case == "torn":
        scene = make_scene({"substeps": 2, "iterations": 2}, resolution=[20, 23], pins=["top-left", "top-right"],
                           tear_threshold=1.02, sticks=["structural", "shear"])
    elif case == "mesh-free two cloths":
        scene = parse_scene({"simulation": {"substeps": 2}, "cloth": [
            {"name": "a", "resolution": [9, 7], "size": [1.0, 1.0], "pins": ["top-left"]},
            {"name": "b", "resolution": [5, 11], "size": [1.0, 1.0], "origin": [2.0, 0.0, 0.0], "pins": ["top-edge"]}]},
            file="<test>")
    else:
        scene = make_scene({"substeps": 2}, resolution=[17, 300], pins=["top-left"], sticks=["structural", "bend"])
    sim = Simulator(scene, device, sticks="implicit" if case == "implicit" else "auto")
    for _ in range(12):
        sim.step_frame()
    if case == "torn":
        assert sim.torn_count() > 0  # torn sticks must be left out of the sum, as on the host
    readback = StretchReadback(sim.model, sim.device)
    readback.launch(sim.state)
    rms = readback.read()
    host = sim.stretch().rms
    assert host > 1e-6
    assert rms == pytest.approx(host, rel=1e-12)  # float64 sums of the same terms, in another order
    readback.launch(sim.state)
    assert readback.read() == rms  # a fixed order: the same bits every time


def test_a_late_observation_of_a_frame_at_other_substeps_decides_nothing():
    b = Budget(target=0.01, substeps=4, max_substeps=64)
    b.observe(0.02, 4)
    assert b.substeps == 8
    b.observe(0.03, 4)  # the next frame, also run at 4, read a frame late: the budget already doubled for it
    assert b.substeps == 8 and b.frames_at == {4: 2}
    b.observe(0.02, 8)
    assert b.substeps == 16


def test_each_substep_count_is_captured_once(monkeypatch):
    captures = []
    real = wp.ScopedCapture.__enter__

    def enter(self):
        captures.append(1)
        return real(self)

    monkeypatch.setattr(wp.ScopedCapture, "__enter__", enter)
    sim = Simulator(budget_scene(0.002), "cpu", threads=1, sticks="implicit")
    for _ in range(40):
        sim.step_frame()
    chosen = set(sim.budget.frames_at)
    assert len(chosen) >= 2  # the budget moved
    assert len(captures) == len(sim._frame_graphs) <= len(chosen)


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_on_cuda_the_budget_reads_the_stretch_a_frame_late_and_meets_its_target():
    sim = Simulator(budget_scene(0.002), "cuda")
    for frame in range(1, 41):
        sim.step_frame()
        assert sum(sim.budget.frames_at.values()) == frame - 1  # the last frame's stretch is still on its way
    sim.settle_budget()
    assert sum(sim.budget.frames_at.values()) == 40
    assert sim.budget.last_rms == pytest.approx(sim.stretch().rms, rel=1e-12)
    assert sim.stretch().rms < 0.002 and max(sim.budget.frames_at) > 4


@pytest.mark.cuda
@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_the_run_summary_counts_every_frame_in_the_budget_on_cuda(tmp_path):
    """On CUDA the last frame's stretch is still on its way when the frames end: the summary's budget line
    must count it (run_scene settles the budget before reporting)."""
    from warp_verlet.apps.runner import run_scene

    frames = 12
    summary = run_scene(budget_scene(0.002), tmp_path / "budget.usdc", device="cuda", frames=frames)
    counted = [part.split(" x ") for part in summary.budget.split("substeps ")[1].split(" (")[0].split(", ")]
    assert sum(int(n) for _, n in counted) == frames
