"""Every scene and sweep file is read up to a cap (scene.MAX_TOML_BYTES): a file that never ends, or a huge one,
is one clear error naming the file, the cap and the size, and costs at most the cap in memory."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest

from warp_verlet.input import scene as scene_module
from warp_verlet.errors import SceneError
from warp_verlet.input.scene import MAX_TOML_BYTES, load_scene
from warp_verlet.apps.sweep import load_sweep

SCENE = """
[simulation]
frames = 2
[[cloth]]
resolution = [4, 4]
size = [1.0, 1.0]
"""
CAP_TEXT = f"at most {MAX_TOML_BYTES:,} bytes (16 MiB)"
MEMORY_LIMIT = 2 * 2**30  # address space of the checking process: far above the cap, far below "everything"


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero on this system")
@pytest.mark.parametrize("command", ["validate", "run"])
def test_a_scene_file_that_never_ends_is_refused_within_bounded_memory(command, tmp_path):
    # Under a 2 GiB address-space limit: reading the whole of /dev/zero would end in a MemoryError traceback.
    done = subprocess.run([sys.executable, "-m", "warp_verlet", command, "/dev/zero"], capture_output=True,
                          text=True, timeout=120, preexec_fn=_limit_memory, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert lines == [f"error: /dev/zero: the file is too large for a scene file: more than {MAX_TOML_BYTES:,} "
                     f"bytes, and a scene file may hold {CAP_TEXT}"], done.stderr
    assert "Traceback" not in done.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero on this system")
def test_a_sweep_file_that_never_ends_is_refused_within_bounded_memory(tmp_path):
    done = subprocess.run([sys.executable, "-m", "warp_verlet", "sweep", "/dev/zero", "--dry-run"],
                          capture_output=True, text=True, timeout=120, preexec_fn=_limit_memory, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"error: /dev/zero: the file is too large for a sweep file: more than {MAX_TOML_BYTES:,} bytes, and a "
        f"sweep file may hold {CAP_TEXT}"], done.stderr


def test_a_regular_file_over_the_cap_names_its_size_and_one_at_the_cap_is_read(tmp_path, monkeypatch):
    cap = 4096
    monkeypatch.setattr(scene_module, "MAX_TOML_BYTES", cap)
    at_cap = tmp_path / "at_cap.toml"
    at_cap.write_bytes(SCENE.encode() + b"#" * (cap - len(SCENE.encode()) - 1) + b"\n")
    assert at_cap.stat().st_size == cap
    assert load_scene(at_cap).simulation.frames == 2  # exactly the cap: read whole, parsed
    over = tmp_path / "over.toml"
    over.write_bytes(at_cap.read_bytes() + b"\n")
    with pytest.raises(SceneError) as caught:
        load_scene(over)
    assert str(caught.value) == (f"{over}: the file is too large for a scene file: {cap + 1:,} bytes, and a scene "
                                 f"file may hold at most {cap:,} bytes")


def test_a_sweep_whose_base_scene_is_over_the_cap_names_the_scene(tmp_path, monkeypatch):
    cap = 4096
    monkeypatch.setattr(scene_module, "MAX_TOML_BYTES", cap)
    (tmp_path / "base.toml").write_bytes(SCENE.encode() + b"#" * cap + b"\n")
    (tmp_path / "s.toml").write_text('[sweep]\nscene = "base.toml"\n[axes]\n"simulation.frames" = [1, 2]\n')
    with pytest.raises(SceneError, match=r"base\.toml: the file is too large for a scene file"):
        load_sweep(tmp_path / "s.toml")


def test_a_byte_order_mark_is_named(tmp_path):
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + SCENE.encode())
    with pytest.raises(SceneError, match=r"starts with a UTF-8 byte order mark \(BOM, bytes EF BB BF\).*without a BOM"):
        load_scene(bom)
    plain = tmp_path / "plain.toml"
    plain.write_bytes(bom.read_bytes()[3:])
    assert load_scene(plain).simulation.frames == 2  # the same text without the mark is a valid scene
