"""The background writer keeps frame order, bounds its queue, and hands errors back to the step loop."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from conftest import make_scene
from warp_verlet.output.background_writer import BackgroundWriter
from warp_verlet.apps.runner import run_scene


def test_frames_are_written_in_order_and_all_flushed_on_close():
    written = []
    w = BackgroundWriter(lambda frame, value: written.append((frame, value)), depth=2)
    for f in range(50):
        w.submit(f, f * f)
    w.close()
    assert written == [(f, f * f) for f in range(50)]


def test_the_queue_is_bounded():
    release, calls = threading.Event(), []

    def slow(frame):
        calls.append(frame)
        release.wait()

    w = BackgroundWriter(slow, depth=2)
    for f in range(3):  # one being written, two queued: all three fit
        w.submit(f)
    blocked = threading.Thread(target=w.submit, args=(3,))
    blocked.start()
    blocked.join(timeout=0.3)
    assert blocked.is_alive()  # the fourth waits for room
    release.set()
    blocked.join(timeout=5)
    w.close()
    assert calls == [0, 1, 2, 3]


def test_a_writer_error_reaches_the_step_loop_once():
    def fail_on_two(frame):
        if frame == 2:
            raise OSError("disk full")

    w = BackgroundWriter(fail_on_two, depth=1)
    with pytest.raises(OSError, match="disk full"):
        for f in range(100):
            w.submit(f)
    w.close()  # already reported: close does not raise it again


def test_overlapped_and_sequential_runs_write_identical_caches(tmp_path):
    from pxr import Usd, UsdGeom

    scene = make_scene({"frames": 12}, resolution=[12, 12], pins=["top-left", "top-right"])
    run_scene(scene, tmp_path / "a.usdc", device="cpu", overlap=True)
    run_scene(scene, tmp_path / "b.usdc", device="cpu", overlap=False)
    stages = [Usd.Stage.Open(str(tmp_path / n)) for n in ("a.usdc", "b.usdc")]  # kept alive while read
    a, b = (UsdGeom.Mesh.Get(stage, "/World/cloth0").GetPointsAttr() for stage in stages)
    assert a.GetTimeSamples() == b.GetTimeSamples() == list(map(float, range(13)))
    for t in a.GetTimeSamples():
        assert np.array_equal(np.asarray(a.Get(t)), np.asarray(b.Get(t)))
