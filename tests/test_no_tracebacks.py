"""What a user can type never ends in a traceback: each input below once did, and now gives one clear error (exit
2 for bad input) or the documented result.

- an output file name longer than its file system allows, from the scene (validate and run) or from -o;
- a sweep range of more values than a float can count;
- a mesh of a million vertices in coincident triangles, and a dense cluster of distinct vertices, for the welding;
- `view` of a cache that opens but holds no readable points.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from browser import REPO, free_port
from sweep_helpers import BASE_SCENE
from test_cli import SCENE
from test_mesh_cloth import brute_force_weld
from warp_verlet.apps.cli import main
from warp_verlet.geometry.faces import Faces
from warp_verlet.geometry.mesh_cloth import MeshError, SourceMesh, prepare, weld

LONG_NAME = "a" * 300 + ".usdc"  # 305 bytes: every common file system stops at 255


@pytest.fixture
def work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "small.toml").write_text(SCENE)
    return tmp_path


# -- output names -------------------------------------------------------------------------------------------------

def test_an_output_name_too_long_in_the_scene_is_refused_by_validate_and_run(work, capsys):
    (work / "long.toml").write_text(SCENE.replace('path = "small.usdc"', f'path = "{LONG_NAME}"'))
    for command in (["validate", "long.toml"], ["run", "long.toml", "--device", "cpu", "-q"]):
        rc = main(command)
        err = capsys.readouterr().err
        assert rc == 2, err
        assert f"error: cannot write {LONG_NAME[:40]}" in err and "the file name is too long" in err, err
        assert "more than the 255" in err and len(err) < 500, err
        assert command[0] != "validate" or "(output.path in long.toml)" in err, err
    assert sorted(p.name for p in work.iterdir()) == ["long.toml", "small.toml"]  # nothing written


@pytest.mark.parametrize("output, problem", [
    ("d" * 300 + "/x.usdc", "the directory name dddddddddddddddddddddddd... is 300 bytes, more than the 255"),
    ("/".join(["d" * 200] * 25) + "/x.usdc", "the path is too long: "),  # over 5000 bytes: PATH_MAX is 4096
])
def test_an_output_path_too_long_on_the_way_is_one_error(work, capsys, output, problem):
    for command in (["run", "small.toml", "-o", output, "--device", "cpu", "-q"],
                    ["live", "small.toml", "--record", output, "--port", str(free_port()), "--seconds", "1"],
                    ["preview", "any.usdc", "-o", output.replace(".usdc", ".png")]):
        if command[0] == "preview":
            pytest.importorskip("mitsuba", reason="preview needs Mitsuba, part of the base install")
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "error: " in err and "cannot write ddd" in err and problem in err, err
        assert len(err) < 500, err  # the path shown shortened, not 5000 bytes of it
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]


@pytest.mark.parametrize("stem_bytes, refused", [(240, False), (241, True), (251, True)])
def test_every_name_a_run_writes_through_counts(work, capsys, stem_bytes, refused):
    # NAME.usdc is saved as USD's temporary NAME.partial.XXXXXX, renamed to NAME.partial.usdc: 15 bytes more than
    # the stem. A 240-byte stem makes a 255-byte temporary name (taken); 241 one of 256 bytes (refused, though
    # the output's own name, 246 bytes, and the partial's, 254, would fit).
    output = "b" * stem_bytes + ".usdc"
    rc = main(["run", "small.toml", "-o", output, "--device", "cpu", "-q", "--frames", "1"])
    err = capsys.readouterr().err
    if refused:
        assert rc == 2 and "more than the 255 its file system allows" in err, err
        assert sorted(p.name for p in work.iterdir()) == ["small.toml"]
    else:
        assert rc == 0 and (work / output).is_file(), err


def test_view_and_preview_of_names_too_long_are_one_error(work, capsys):
    pytest.importorskip("viser", reason="view needs viser: pip install 'warp-verlet[live]'")
    pytest.importorskip("mitsuba", reason="preview needs Mitsuba, part of the base install")
    assert main(["view", LONG_NAME, "--port", str(free_port())]) == 2
    assert f"error: {LONG_NAME}: cannot look at it (File name too long)" in capsys.readouterr().err
    # The image is written as .NAME.PID.partial.png: a 245-byte stem fits as NAME.png (249 bytes), not so.
    for image in ("c" * 300 + ".png", "c" * 245 + ".png"):
        assert main(["preview", "any.usdc", "-o", image]) == 2
        err = capsys.readouterr().err
        assert f"error: cannot write {image[:40]}" in err and "the file name is too long" in err, err
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]


# -- sweep ranges -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("axis_range, made", [
    ("{ start = 0.1, stop = 1e300, step = 1e-300 }", "more than a float can count"),  # (stop - start) / step = inf
    ("{ start = -1e308, stop = 1e308, step = 1.0 }", "more than a float can count"),  # stop - start = inf
    ("{ start = 0.1, stop = 1e9, step = 0.5 }", "got 2000000000"),  # finite: counted
])
def test_a_sweep_range_of_too_many_values_is_one_error(work, capsys, axis_range, made):
    (work / "base.toml").write_text(BASE_SCENE)
    (work / "sweep.toml").write_text(f'[sweep]\nscene = "base.toml"\n[axes]\n"simulation.damping" = {axis_range}\n')
    rc = main(["sweep", "sweep.toml"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "error: sweep.toml: axes.simulation.damping: expected at most 100000 values in a range" in err, err
    assert made in err, err


# -- welding ------------------------------------------------------------------------------------------------------

def stacked_triangles(count: int) -> SourceMesh:
    """``count`` copies of one triangle, each with its own three vertices."""
    corner = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    faces = Faces(np.full(count, 3, np.int32), np.arange(3 * count, dtype=np.int32))
    return SourceMesh("stack.obj", Path("stack.obj"), np.tile(corner, (count, 1)), faces)


def test_a_million_coincident_vertices_weld_into_three_particles_in_little_memory(monkeypatch):
    # Coincident vertices collapse before the close-pair search, so even a 64 MiB allowance takes them (the
    # search over all pairs would have asked for 103 GiB).
    monkeypatch.setattr("warp_verlet.machine.available_host_bytes", lambda: 64 * 2**20)
    with pytest.warns(UserWarning, match="shared by more than two faces"):  # 333,334 faces on each edge
        mesh = prepare(stacked_triangles(333_334))
    assert mesh.vertex_count == 1_000_002 and mesh.particle_count == 3
    np.testing.assert_array_equal(mesh.particle_points, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


def test_a_dense_cluster_of_distinct_vertices_is_refused_before_the_search_allocates(monkeypatch):
    # 1000 distinct vertices within 1e-6 m, welded at 1e-3 m: 8 grids x 499,500 candidate pairs x 128 bytes is
    # about 0.48 GiB, over the 32 MiB that a 64 MiB machine allows.
    monkeypatch.setattr("warp_verlet.machine.available_host_bytes", lambda: 64 * 2**20)
    rng = np.random.default_rng(1)
    points = rng.uniform(0.0, 1e-6, (1000, 3))
    with pytest.raises(MeshError, match=r"cluster\.obj: 1000 distinct vertices lie in one cell .* 3996000 pairs"):
        weld(points, 1e-3, "cluster.obj")
    monkeypatch.setattr("warp_verlet.machine.available_host_bytes", lambda: 64 * 2**30)  # 32 GiB allowed: welded
    np.testing.assert_array_equal(weld(points, 1e-3), np.zeros(1000))


@pytest.mark.parametrize("seed", range(3))
def test_welding_with_exact_duplicates_matches_brute_force(seed):
    # Duplicates collapse first: the particles and their numbering (first occurrence) are as before.
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1, 1, (30, 3))
    near = np.repeat(centres, rng.integers(1, 4, 30), axis=0)
    near = near + rng.normal(0, 3e-3, near.shape)  # some within 1e-2 of each other, some chained
    points = np.concatenate([near, near[rng.integers(0, len(near), 40)]])  # 40 exact copies, anywhere
    rng.shuffle(points)
    for distance in (1e-2, 0.0):
        np.testing.assert_array_equal(weld(points, distance), brute_force_weld(points, distance))


# -- view ---------------------------------------------------------------------------------------------------------

def one_triangle_cache(path, heights: dict[int, float]):
    """A cache of frames 1 .. 3 holding one triangle, whose points are at height z = heights[frame] at the frames
    given (none at the others)."""
    from pxr import Gf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    mesh = UsdGeom.Mesh.Define(stage, "/World/sheet")
    mesh.GetFaceVertexCountsAttr().Set([3])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2])
    for frame, z in heights.items():
        mesh.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, z), Gf.Vec3f(1, 0, z), Gf.Vec3f(0, 1, z)]), frame)
    stage.GetRootLayer().Save()
    return path


def test_view_of_a_cache_with_no_readable_points_is_one_error(tmp_path):
    pytest.importorskip("viser", reason="view needs viser: pip install 'warp-verlet[live]'")
    # Faces but no points at any time: what 40 flipped bytes left of a real cache (it opens; no sample reads).
    path = one_triangle_cache(tmp_path / "empty.usdc", {})
    result = subprocess.run([sys.executable, "-m", "warp_verlet", "view", str(path), "--port", str(free_port()),
                             "--seconds", "0.5"], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 2, result.stderr
    assert f"error: {path}: frame 1, the first, holds no readable points for any cloth or rope" in result.stderr
    assert "Traceback" not in result.stderr and "open http" not in result.stdout


# -- live's Save ----------------------------------------------------------------------------------------------------

def test_a_save_path_typed_in_the_live_page_is_refused_in_its_log_not_with_a_traceback(tmp_path, monkeypatch):
    pytest.importorskip("viser", reason="live needs viser: pip install 'warp-verlet[live]'")
    from conftest import make_scene
    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    app = LiveApp(LiveSession(make_scene(resolution=[4, 4]), "cpu", waiting=False), port=free_port(),
                  record_path=tmp_path / "live.usdc")
    errors = []
    monkeypatch.setattr("threading.excepthook", lambda hook: errors.append(hook.exc_value))

    def save(path) -> str:
        app.record_path.value = str(path)
        app._save()
        for thread in app._saves:
            thread.join()
        return app.session.event_lines()[-1]

    try:
        app.session.tick(1 / 60)
        assert "refused: cannot write" in save(tmp_path / LONG_NAME) and "the file name is too long" in \
            app.session.event_lines()[-1]
        # Whatever else the system refuses is said in the log too (a name the checks let through, here faked).
        monkeypatch.setattr(app.session, "save", lambda path: open(tmp_path / "missing" / "x", "w"))
        line = save(tmp_path / "other.usdc")
        assert f"refused: cannot write {tmp_path / 'missing' / 'x'}: No such file or directory" in line, line
        assert not errors, errors  # no thread ended in an exception
        assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written
    finally:
        app.server.stop()
        app.session.close()


def test_view_says_a_damaged_frame_on_the_page_and_plays_on(tmp_path):
    pytest.importorskip("viser", reason="view needs viser: pip install 'warp-verlet[live]'")
    from warp_verlet.apps.cache_player import CachePlayer

    # Frame 2 holds NaN: it cannot be drawn.
    path = one_triangle_cache(tmp_path / "holed.usda", {1: 0.0, 2: float("nan"), 3: 0.5})
    player = CachePlayer(path, port=free_port())
    try:
        player.show(2)
        assert player.frame == 2 and "cannot draw it" in player.time_text.value
        assert "frame 2 is damaged" in player.time_text.value, player.time_text.value
        player.show(3)  # the next good frame draws as ever
        assert player.frame == 3 and player.time_text.value == f"{3 / player.cache.fps:.3f} s"
    finally:
        player.server.stop()


def test_view_keeps_usds_cpp_locations_from_stderr(tmp_path, capfd):
    # A cache whose layer names a sublayer that is missing: USD warns at open, with its C++ source file and line.
    from warp_verlet.output.cache_reader import open_cache, read_frame
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.input.scene import parse_scene

    run_scene(parse_scene({"simulation": {"frames": 2}, "cloth": [{"resolution": [3, 3], "size": [1.0, 1.0]}]},
                          file="<test>"), tmp_path / "cloth.usdc", device="cpu", frames=2)
    wrapper = tmp_path / "wrapper.usda"
    wrapper.write_text('#usda 1.0\n(\n    subLayers = [@./cloth.usdc@, @./missing.usda@]\n)\n')
    capfd.readouterr()
    cache = open_cache(wrapper)
    geometry = read_frame(cache, cache.frames[-1])
    assert len(geometry.cloth_frames) == 1  # the cloth reads as ever
    err = capfd.readouterr().err
    assert ".cpp" not in err and "line" not in err, err


def test_validate_cache_says_a_missing_layer_plainly_and_prints_nothing(tmp_path, capfd):
    # The same wrapper as above: validate_cache (and a sweep's resume, through it) names the missing layer as a
    # problem, without USD's C++ source file and line on stderr.
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.input.scene import parse_scene
    from warp_verlet.output.usd_writer import validate_cache

    run_scene(parse_scene({"simulation": {"frames": 2}, "cloth": [{"resolution": [3, 3], "size": [1.0, 1.0]}]},
                          file="<test>"), tmp_path / "cloth.usdc", device="cpu", frames=2)
    assert validate_cache(tmp_path / "cloth.usdc") == []
    wrapper = tmp_path / "wrapper.usda"
    wrapper.write_text('#usda 1.0\n(\n    subLayers = [@./cloth.usdc@, @./missing.usda@]\n)\n')
    capfd.readouterr()
    problems = validate_cache(wrapper)
    assert len(problems) == 1 and "missing.usda" in problems[0], problems
    assert ".cpp" not in problems[0] and " line " not in problems[0], problems
    err = capfd.readouterr().err
    assert ".cpp" not in err and "line" not in err, err


def test_run_scene_from_python_refuses_a_name_too_long_as_the_command_line_does(tmp_path):
    from warp_verlet.output.output_file import OutputNameError
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.input.scene import parse_scene

    scene = parse_scene({"simulation": {"frames": 1}, "cloth": [{"resolution": [3, 3], "size": [1.0, 1.0]}]},
                        file="<test>")
    with pytest.raises(OutputNameError, match="the file name is too long"):
        run_scene(scene, tmp_path / LONG_NAME, device="cpu")
    assert list(tmp_path.iterdir()) == []
