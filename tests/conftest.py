"""Shared fixtures. Physics tests run on every available device: the CPU always, CUDA when present
(CUDA cases are skipped, with a reason, where there is no GPU, as in CI)."""

from __future__ import annotations

import pytest
import warp as wp

from warp_verlet.scene import Scene, parse_scene

wp.config.quiet = True

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=[pytest.mark.cuda, pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")]),
]


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    return request.param


def make_scene(simulation: dict | None = None, **cloth) -> Scene:
    """A one-cloth scene from keyword overrides of a small default cloth."""
    spec = {"resolution": [4, 4], "size": [1.0, 1.0]}
    spec.update(cloth)
    return parse_scene({"simulation": simulation or {}, "cloth": [spec]}, file="<test>")
