"""The command line end to end, as a user runs it: scene file in, valid USD point cache out."""

import subprocess
import sys

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warp_verlet.cli import main
from warp_verlet.usd_writer import validate_cache

SCENE = """
[simulation]
fps = 30
frames = 6
substeps = 2
iterations = 4
damping = 0.6

[output]
path = "small.usdc"
save_every = 2

[[cloth]]
name = "sheet"
resolution = [6, 7]
size = [0.5, 0.6]
origin = [0.0, 1.0, 0.0]
sticks = ["structural", "shear"]
pins = ["top-left", "top-right"]

[[cloth]]
name = "rope"
resolution = [1, 5]
size = [0.0, 0.4]
pins = [0]
"""


@pytest.fixture
def scene_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "small.toml"
    path.write_text(SCENE)
    return path


def read_points(path, prim):
    stage = Usd.Stage.Open(str(path))
    attr = UsdGeom.PointBased(stage.GetPrimAtPath(prim)).GetPointsAttr()
    return stage, {t: np.array(attr.Get(t)) for t in attr.GetTimeSamples()}


def test_run_writes_a_valid_cache_with_every_frame(scene_file, capsys):
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 0
    out = capsys.readouterr().out
    for word in ("frames", "simulated", "wall", "colours", "stretch"):
        assert word in out
    cache = scene_file.parent / "small.usdc"
    assert validate_cache(cache) == []
    stage, samples = read_points(cache, "/World/sheet")
    assert sorted(samples) == [0, 1, 2, 3, 4, 5, 6]  # the rest pose plus 6 frames
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert stage.GetEndTimeCode() == 6
    assert samples[6].shape == (42, 3) and np.isfinite(samples[6]).all()
    assert samples[6][:, 1].mean() < samples[0][:, 1].mean()  # it fell under gravity
    assert stage.GetPrimAtPath("/World/rope").IsA(UsdGeom.BasisCurves)


def test_output_override_and_frames(scene_file):
    out = scene_file.parent / "other.usda"
    assert main(["run", str(scene_file), "-o", str(out), "--frames", "2", "--device", "cpu", "-q"]) == 0
    _, samples = read_points(out, "/World/sheet")
    assert sorted(samples) == [0, 1, 2]


def test_same_scene_gives_bit_identical_caches(scene_file):
    a, b = scene_file.parent / "a.usdc", scene_file.parent / "b.usdc"
    for path in (a, b):
        assert main(["run", str(scene_file), "-o", str(path), "--device", "cpu", "-q"]) == 0
    _, pa = read_points(a, "/World/sheet")
    _, pb = read_points(b, "/World/sheet")
    assert all(np.array_equal(pa[t], pb[t]) for t in pa)


def test_threads_option_gives_the_same_cache_and_says_so(scene_file, capsys):
    one, three = scene_file.parent / "one.usdc", scene_file.parent / "three.usdc"
    assert main(["run", str(scene_file), "-o", str(one), "--device", "cpu", "-q", "--threads", "1"]) == 0
    assert "relaxation on" not in capsys.readouterr().out
    assert main(["run", str(scene_file), "-o", str(three), "--device", "cpu", "-q", "--threads", "3"]) == 0
    assert "relaxation on 3 threads" in capsys.readouterr().out
    for prim in ("/World/sheet", "/World/rope"):
        _, p1 = read_points(one, prim)
        _, p3 = read_points(three, prim)
        assert p1.keys() == p3.keys() and all(np.array_equal(p1[t], p3[t]) for t in p1)
    with pytest.raises(SystemExit):
        main(["run", str(scene_file), "--threads", "0"])
    assert "--threads" in capsys.readouterr().err


def test_invalid_scene_exits_nonzero_names_the_key_and_writes_nothing(scene_file, capsys):
    scene_file.write_text(SCENE.replace("damping = 0.6", "damping = -1.5"))
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 2
    err = capsys.readouterr().err
    assert "small.toml: simulation.damping: expected a number in [0.0, inf), got -1.5" in err
    assert not (scene_file.parent / "small.usdc").exists()
    # The old per-substep drag is refused with the damping that means the same at this budget:
    # -ln(0.99) x 30 fps x 2 substeps = 0.603 per second.
    scene_file.write_text(SCENE.replace("damping = 0.6", "drag = 0.99"))
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 2
    err = capsys.readouterr().err
    assert "small.toml: simulation.drag: " in err and "damping = 0.603" in err
    assert not (scene_file.parent / "small.usdc").exists()


def test_unwritable_output_fails_before_simulating(scene_file, capsys):
    assert main(["run", str(scene_file), "-o", str(scene_file.parent / "no" / "dir" / "x.usdc"), "--device", "cpu", "-q"]) == 1
    assert "x.usdc" in capsys.readouterr().err


def test_divergence_stops_names_the_frame_and_keeps_frames_done(scene_file, capsys):
    # 1000 m/s^2 for a rope with one pin: the free end leaves a 3 m bound during frame 3.
    # x(t) = a t^2 / 2 = 3 m at t = 0.077 s, i.e. frame 3 at 30 fps.
    text = SCENE.replace("damping = 0.6", "damping = 0.0\ngravity = [0.0, -1000.0, 0.0]\nposition_bound = 3.0")
    scene_file.write_text(text.replace('pins = ["top-left", "top-right"]', "pins = []"))
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 1
    err = capsys.readouterr().err
    assert "diverged at frame 3: cloth 'sheet'" in err and "position_bound = 3.0 m" in err
    # The frames done go to the partial file, never to the output, and the message says where they are.
    assert "frames 0 to 2 are in small.partial.usdc; small.usdc was not written" in err
    assert not (scene_file.parent / "small.usdc").exists()
    cache = scene_file.parent / "small.partial.usdc"
    assert validate_cache(cache) == []
    stage, samples = read_points(cache, "/World/sheet")
    assert sorted(samples) == [0, 1, 2] and stage.GetEndTimeCode() == 2


def test_validate_command(scene_file, capsys):
    assert main(["validate", str(scene_file)]) == 0
    out = capsys.readouterr().out
    assert "valid scene, 2 cloth(s), 47 particles" in out
    assert "memory: about 0.00 GiB of device arrays" in out
    assert "positions: float32\n" in out
    assert main(["validate", str(scene_file.parent / "missing.toml")]) == 2


def test_module_and_console_script_behave_the_same(scene_file):
    # python -m warp_verlet and the installed warp-verlet script print the same and exit the same.
    bad = scene_file.parent / "bad.toml"
    bad.write_text("[[cloth]]\nresolution = [4, 4]\nsize = [1.0, 1.0]\nmass = -1.0\n")
    module = subprocess.run([sys.executable, "-m", "warp_verlet", "validate", str(bad)], capture_output=True, text=True)
    script = subprocess.run(["warp-verlet", "validate", str(bad)], capture_output=True, text=True)
    assert module.returncode == script.returncode == 2
    assert module.stderr == script.stderr
    assert "cloth[0].mass" in module.stderr and "Traceback" not in module.stderr


def test_ctrl_c_leaves_a_valid_cache_of_the_frames_done(scene_file, monkeypatch, capsys):
    # Interrupt after frame 3, as a KeyboardInterrupt from the terminal would arrive between frames.
    from warp_verlet import runner

    real = runner.run_scene

    def interrupted(*args, **kwargs):
        def progress(frame):
            if frame == 3:
                raise KeyboardInterrupt

        return real(*args, **dict(kwargs, progress=progress))

    monkeypatch.setattr(runner, "run_scene", interrupted)
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 130
    assert "interrupted: frames 0 to 3 are in small.partial.usdc; small.usdc was not written" in capsys.readouterr().err
    cache = scene_file.parent / "small.partial.usdc"
    assert validate_cache(cache) == []
    _, samples = read_points(cache, "/World/sheet")
    assert sorted(samples) == [0, 1, 2, 3]


def test_validate_imports_no_heavy_module(scene_file):
    probe = (
        "import sys; from warp_verlet.cli import main; rc = main(['validate', 'small.toml']); "
        "print(rc, *(m in sys.modules for m in ('warp', 'pxr', 'trimesh')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=scene_file.parent, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-4:] == ["0", "False", "False", "False"]


def test_preview_without_matplotlib_says_which_extra_to_install(tmp_path):
    # matplotlib is an optional extra ("preview"): without it the command fails with one clear line, not a
    # traceback. sys.modules[name] = None makes the import fail as a missing package does.
    probe = ("import sys; sys.modules['matplotlib'] = None; from warp_verlet.cli import main; "
             "print('rc', main(['preview', 'missing.usdc', '-o', 'x.png']))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["rc", "1"]
    assert "pip install 'warp-verlet[preview]'" in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "x.png").exists()
