"""Output formats register by file suffix (warp_verlet/writer_registry.py): a format registered from outside the
library (here a numpy .npz writer defined in this file) is written by run_scene, accepted by every output check,
and named by the error for an unknown suffix; the real writers have every member of the declared interface."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from warp_verlet.errors import OutputError, SceneError
from warp_verlet.output.output_file import CacheOutput, OutputNameError
from warp_verlet.apps.runner import run_scene
from warp_verlet.input.scene import parse_scene
from warp_verlet.apps.sweep import formats
from warp_verlet.writer_registry import (USD_SUFFIXES, CacheRequest, CacheWriter, format_for, output_suffixes,
                                         register_format, unregister_format)


class NpzWriter:
    """Keeps every frame and writes them all to an .npz file every ``save_every`` frames and on close."""

    def __init__(self, path: Path, request: CacheRequest):
        self.path, self.request = Path(path), request
        self.start_frame, self.save_every = request.start_frame, request.save_every
        self.frames_written, self.saved_frames, self.saved_frame = 0, 0, None
        self.frames: list[int] = []
        self.points: list[list[np.ndarray]] = []
        self.closed = False
        self._save()  # like the USD writer: a file exists (and before_save has run) before the first frame

    def write_frame(self, frame, points, moving_centres=None, hidden_faces=None) -> None:
        self.frames.append(int(frame))
        self.points.append([np.array(p, dtype=np.float32) for p in points])
        self.frames_written += 1
        if self.frames_written % self.save_every == 0:
            self._save()

    def _save(self) -> None:
        if self.request.before_save is not None:
            self.request.before_save(self)
        arrays = {f"{shape.name}": np.array([frame[k] for frame in self.points], np.float32).reshape(
            len(self.points), shape.point_count, 3) for k, shape in enumerate(self.request.shapes)}
        with open(self.path, "wb") as f:
            np.savez(f, frames=np.array(self.frames, np.int64), **arrays)
        self.saved_frames = self.frames_written
        self.saved_frame = self.frames[-1] if self.frames else None

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._save()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


class NpzFormat:
    name = "numpy frames"
    overrides = False

    def open(self, path, request):
        return NpzWriter(path, request)

    def estimate(self, request, path):
        return None  # no estimate: the run goes without the free-space checks

    def problems(self, path, frames):
        with np.load(path) as data:
            return [] if list(data["frames"]) == list(range(frames + 1)) else [f"{path}: frames missing"]


@pytest.fixture
def npz_format():
    register_format(".npz", NpzFormat())
    try:
        yield
    finally:
        unregister_format(".npz")


def scene(frames: int = 5, **output):
    return parse_scene({"simulation": {"frames": frames}, "output": {"save_every": 2, **output},
                        "cloth": [{"resolution": [5, 4], "size": [1.0, 0.8], "pins": ["top-left", "top-right"]}]}, file="<test>")


def test_a_registered_format_is_written_by_run_scene_with_the_simulators_positions(tmp_path, npz_format):
    from warp_verlet.core.simulator import Simulator

    frames = 5
    out = tmp_path / "cloth.npz"
    summary = run_scene(scene(frames), output=out, device="cpu", threads=1)
    assert summary.output == out and out.is_file()
    assert not (tmp_path / "cloth.partial.npz").exists()  # written to the partial file, renamed on success

    sim = Simulator(scene(frames), "cpu", threads=1)
    expected = [np.asarray(sim.positions(), np.float32)]
    for _ in range(frames):
        sim.step_frame()
        expected.append(np.asarray(sim.positions(), np.float32))
    with np.load(out) as data:
        assert list(data["frames"]) == list(range(frames + 1))
        got = data["cloth0"]
    # Bit for bit: the writer gets the float32 positions the step loop read, whatever the format.
    assert got.shape == (frames + 1, 20, 3)
    np.testing.assert_array_equal(got, np.stack(expected))
    assert not np.array_equal(got[0], got[-1])  # the pinned cloth fell: the frames are not one repeated

    # The sweep's resume check asks the format of the cache's suffix.
    from warp_verlet.apps.sweep import cache_problems

    assert cache_problems(out, frames) == []
    assert cache_problems(out, frames + 1) != []


def test_every_output_check_accepts_a_registered_suffix(tmp_path, npz_format):
    assert ".npz" in output_suffixes() and "npz" in formats()
    CacheOutput(tmp_path / "x.npz")  # the run's path check
    assert scene(**{"path": "x.npz"}).output.path == Path("x.npz")  # the scene's output.path check


def test_a_suffix_not_registered_is_refused_everywhere_naming_every_registered_suffix(tmp_path, npz_format):
    registered = output_suffixes()
    assert set(registered) == {*USD_SUFFIXES, ".npz"}
    with pytest.raises(OutputNameError) as run_error:
        CacheOutput(tmp_path / "out.xyz")
    with pytest.raises(SceneError) as scene_error:
        scene(path="out.xyz")
    with pytest.raises(OutputError) as format_error:
        format_for(tmp_path / "out.xyz")
    for error in (run_error, scene_error, format_error):
        for suffix in registered:
            assert suffix in str(error.value), (suffix, str(error.value))
    assert "output.path" in str(scene_error.value)

    unregister_format(".npz")
    with pytest.raises(OutputNameError, match="must end in") as after:
        CacheOutput(tmp_path / "out.npz")
    assert str(after.value).endswith("must end in .usd, .usda, .usdc") and "npz" not in formats()


def test_an_override_layer_to_a_format_without_one_is_refused(tmp_path, npz_format):
    with pytest.raises(OutputError, match=r"override layer.*\.usd, \.usda, \.usdc"):
        format_for(tmp_path / "out.npz", override=True)
    assert format_for(tmp_path / "out.usdc", override=True).overrides


@pytest.mark.parametrize("suffix", ["npz", ".a.b", ".a/b", "."])
def test_a_malformed_suffix_is_refused(suffix):
    with pytest.raises(ValueError, match="one dot and a name"):
        register_format(suffix, NpzFormat())


def test_a_taken_suffix_is_refused_unless_replaced():
    with pytest.raises(ValueError, match=r"\.usdc is already registered"):
        register_format(".usdc", NpzFormat())


def test_the_real_writers_have_every_member_of_the_interface(tmp_path, npz_format):
    from warp_verlet.output.usd_writer import USD_POINT_CACHE, CachedShape

    members = set(CacheWriter.__annotations__) | {"write_frame", "close", "__enter__", "__exit__"}
    assert members >= {"path", "start_frame", "save_every", "frames_written", "saved_frames", "saved_frame"}
    request = CacheRequest([CachedShape("sheet", np.array([[0, 1, 2, 3]]), None, 4)], fps=24.0)
    for suffix in (*USD_SUFFIXES, ".npz"):
        cache_format = format_for(tmp_path / f"a{suffix}")
        for name in ("name", "overrides", "open", "estimate", "problems"):
            assert hasattr(cache_format, name), (suffix, name)
        with cache_format.open(tmp_path / f"a{suffix}", request) as writer:
            missing = {m for m in members if not hasattr(writer, m)}
            assert not missing, (suffix, missing)
            assert isinstance(writer, CacheWriter)
            writer.write_frame(0, [np.zeros((4, 3), np.float32)])
        assert writer.saved_frames == 1 and writer.saved_frame == 0
    assert format_for(tmp_path / "a.usdc") is USD_POINT_CACHE
