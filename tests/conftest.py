"""Shared fixtures. Physics tests run on every available device: the CPU always, CUDA when present
(CUDA cases are skipped, with a reason, where there is no GPU, as in CI)."""

from __future__ import annotations

import pytest
import warp as wp

from warp_verlet.input.scene import Scene, parse_scene

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


class LaunchLog:
    """The device work actually issued while recording: kernel keys, "copy" for ``wp.copy`` and "zero" for
    ``wp.array.zero_``. Launches only recorded (``wp.launch(..., record_cmd=True)``) are not work and are
    left out; replaying a recorded launch (``wp.Launch.launch``) is logged under its kernel's key."""

    def __init__(self):
        self.names: list[str] = []
        self.recording = False

    def note(self, name: str) -> None:
        if self.recording:
            self.names.append(name)

    def of(self, work) -> list[str]:
        """Run ``work()`` and return what it issued, in order."""
        self.names, self.recording = [], True
        try:
            work()
        finally:
            self.recording = False
        return list(self.names)


@pytest.fixture
def launches(monkeypatch) -> LaunchLog:
    """Record the launches that are actually issued: ``launches.of(sim.step)`` is the list of kernel keys (and
    "copy" / "zero") that one step issued. Patched before the simulator under test binds its launches (a
    recorded launch's ``launch`` method is looked up when it is recorded), so create the simulator inside the
    test. A threaded CPU relaxation issues the same work from several threads, in no fixed order: use one
    thread (small grids get one automatically)."""
    log = LaunchLog()
    real_launch, real_replay, real_copy, real_zero = wp.launch, wp.Launch.launch, wp.copy, wp.array.zero_

    def launch(kernel, *args, **kwargs):
        if not kwargs.get("record_cmd", False):
            log.note(kernel.key)
        return real_launch(kernel, *args, **kwargs)

    def replay(self, *args, **kwargs):
        log.note(self.kernel.key)
        return real_replay(self, *args, **kwargs)

    def copy(*args, **kwargs):
        log.note("copy")
        return real_copy(*args, **kwargs)

    def zero(self, *args, **kwargs):
        log.note("zero")
        return real_zero(self, *args, **kwargs)

    monkeypatch.setattr(wp, "launch", launch)
    monkeypatch.setattr(wp.Launch, "launch", replay)
    monkeypatch.setattr(wp, "copy", copy)
    monkeypatch.setattr(wp.array, "zero_", zero)
    return log
