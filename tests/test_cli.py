"""The command line end to end, as a user runs it: scene file in, valid USD point cache out."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warp_verlet.apps.cli import main
from warp_verlet.output.usd_writer import validate_cache

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
orientation = "horizontal"
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


def interrupt_runs_after(monkeypatch, last: int) -> None:
    """Make run_scene raise KeyboardInterrupt after frame ``last``, as Ctrl-C from the terminal would arrive
    between frames."""
    from warp_verlet.apps import runner

    real = runner.run_scene

    def interrupted(*args, **kwargs):
        def progress(frame):
            if frame == last:
                raise KeyboardInterrupt

        return real(*args, **dict(kwargs, progress=progress))

    monkeypatch.setattr(runner, "run_scene", interrupted)


def test_ctrl_c_leaves_a_valid_cache_of_the_frames_done(scene_file, monkeypatch, capsys):
    interrupt_runs_after(monkeypatch, 3)
    assert main(["run", str(scene_file), "--device", "cpu", "-q"]) == 130
    assert "interrupted: frames 0 to 3 are in small.partial.usdc; small.usdc was not written" in capsys.readouterr().err
    cache = scene_file.parent / "small.partial.usdc"
    assert validate_cache(cache) == []
    _, samples = read_points(cache, "/World/sheet")
    assert sorted(samples) == [0, 1, 2, 3]


def test_validate_imports_no_heavy_module(scene_file):
    probe = (
        "import sys; from warp_verlet.apps.cli import main; rc = main(['validate', 'small.toml']); "
        "print(rc, *(m in sys.modules for m in ('warp', 'pxr', 'trimesh')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=scene_file.parent, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-4:] == ["0", "False", "False", "False"]


def test_preview_without_its_renderer_says_what_to_install(tmp_path):
    # Mitsuba is in the base install, but an install with --no-deps lacks it: the command then fails with one
    # clear line, not a traceback. sys.modules[name] = None makes the import fail as a missing package does.
    probe = ("import sys; sys.modules['mitsuba'] = None; from warp_verlet.apps.cli import main; "
             "print('rc', main(['preview', 'missing.usdc', '-o', 'x.png']))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["rc", "1"]
    assert "the preview needs mitsuba" in out.stderr and "pip install warp-verlet" in out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "x.png").exists()


# ---------------------------------------------------------------------------------- clean errors


def test_threads_are_bounded_with_a_message_about_threads(scene_file, capsys):
    from warp_verlet.core.cpu_team import MAX_THREADS

    for bad in ("0", "-3", str(MAX_THREADS + 1), "100000", "two"):
        with pytest.raises(SystemExit) as caught:
            main(["run", str(scene_file), "--threads", bad])
        assert caught.value.code == 2
        err = capsys.readouterr().err
        message = err.split("argument --threads:")[1]
        assert message.startswith(" expected a") and "threads" in message and "frame" not in message
    assert not (scene_file.parent / "small.usdc").exists()


def test_the_api_bounds_threads_too(scene_file):
    from warp_verlet import Simulator
    from warp_verlet.errors import ArgumentError
    from warp_verlet.input.scene import load_scene

    with pytest.raises(ArgumentError, match=r"threads must be a whole number in 1 \.\. 1024, got 100000"):
        Simulator(load_scene(scene_file), "cpu", threads=100000)


def test_more_threads_than_cores_warns(scene_file, monkeypatch, capsys):
    from warp_verlet.apps import cli

    monkeypatch.setattr(cli, "usable_cores", lambda: 2)
    assert main(["run", str(scene_file), "--device", "cpu", "-q", "--threads", "2"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["run", str(scene_file), "--device", "cpu", "-q", "--threads", "3"]) == 0
    err = capsys.readouterr().err
    assert "warning: --threads 3 is more than the 2 core(s)" in err and "slower, not faster" in err


@pytest.mark.slow
def test_a_cpu_run_does_not_print_warps_cuda_driver_warning(scene_file):
    done = subprocess.run([sys.executable, "-m", "warp_verlet", "run", "small.toml", "--device", "cpu", "-q"],
                          cwd=scene_file.parent, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "CUDA" not in done.stderr and "Traceback" not in done.stderr


def test_the_native_stderr_filter_drops_only_the_cuda_warning(capfd):
    import os

    from warp_verlet.core.warp_setup import CUDA_DRIVER_WARNING, _native_stderr_without

    with _native_stderr_without(CUDA_DRIVER_WARNING):
        os.write(2, f"Warp CUDA warning: {CUDA_DRIVER_WARNING}. GPU execution will not be available.\n".encode())
        os.write(2, b"something else native code said\n")
    err = capfd.readouterr().err
    assert CUDA_DRIVER_WARNING not in err and "something else native code said" in err


@pytest.mark.slow
def test_an_unwritable_warp_cache_chosen_by_the_user_is_one_clear_error(scene_file):
    env = dict(__import__("os").environ, WARP_CACHE_PATH=str(scene_file))  # a file, not a directory
    done = subprocess.run([sys.executable, "-m", "warp_verlet", "run", "small.toml", "--device", "cpu", "-q"],
                          cwd=scene_file.parent, capture_output=True, text=True, env=env)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert "error: Warp's kernel cache directory" in done.stderr and "set WARP_CACHE_PATH" in done.stderr


def test_an_unwritable_default_warp_cache_falls_back_with_a_note(tmp_path, monkeypatch):
    import warp as wp

    from warp_verlet.core import warp_setup

    blocked = tmp_path / "file"
    blocked.write_text("HOME's .cache is a file here")
    monkeypatch.setattr(wp.config, "kernel_cache_dir", None)
    monkeypatch.delenv("WARP_CACHE_PATH", raising=False)
    monkeypatch.setattr(warp_setup, "_default_cache_dir", lambda version: blocked / "warp" / version)
    monkeypatch.setattr(warp_setup, "fallback_cache_dir", lambda: tmp_path / "fallback")
    notes = []
    warp_setup.ensure_kernel_cache(notes.append)
    assert wp.config.kernel_cache_dir == str(tmp_path / "fallback") and (tmp_path / "fallback").is_dir()
    assert len(notes) == 1 and "is not writable" in notes[0] and "set WARP_CACHE_PATH" in notes[0]
    monkeypatch.setattr(wp.config, "kernel_cache_dir", None)
    monkeypatch.setattr(warp_setup, "fallback_cache_dir", lambda: blocked / "fallback")
    from warp_verlet.errors import WarpVerletError

    with pytest.raises(WarpVerletError, match="nor is .*: set WARP_CACHE_PATH"):
        warp_setup.ensure_kernel_cache(notes.append)


def test_public_api_errors_derive_from_warp_verlet_error(scene_file):
    from warp_verlet import Simulator
    from warp_verlet.errors import ArgumentError, StateError, WarpVerletError
    from warp_verlet.geometry.faces import Faces
    from warp_verlet.input.scene import load_scene
    from warp_verlet.output.usd_writer import CachedPlane, CachedShape, PointCacheWriter

    sim = Simulator(load_scene(scene_file), "cpu")
    rope = CachedShape("rope", np.zeros((0, 4), np.int32), np.zeros((4, 2), np.float32), 4)
    calls = [
        lambda: sim.advance(-1.0),
        lambda: sim.step(float("nan")),
        lambda: sim.state.set_velocity([float("nan"), 0.0, 0.0]),
        lambda: Faces(np.array([2]), np.array([0, 1])).validate(3, "mesh"),
        lambda: PointCacheWriter(scene_file.parent / "x.usdc", [rope], fps=-1.0),
        lambda: PointCacheWriter(scene_file.parent / "x.usdc", [replace(rope, name="Colliders")], fps=30.0,
                                 colliders=[CachedPlane("ground", (0, 0, 0), (0, 1, 0), 1.0)]),
    ]
    for call in calls:
        with pytest.raises(WarpVerletError) as caught:
            call()
        assert isinstance(caught.value, ValueError) and isinstance(caught.value, ArgumentError)
    writer = PointCacheWriter(scene_file.parent / "y.usdc", [rope], fps=30.0)
    writer.close()
    with pytest.raises(StateError) as caught:
        writer.write_frame(0, [np.zeros((4, 3), np.float32)])
    assert isinstance(caught.value, RuntimeError) and isinstance(caught.value, WarpVerletError)


@pytest.mark.slow
def test_no_builtin_exception_is_raised_on_purpose_anywhere_in_the_package():
    # Every error the package raises on purpose derives from WarpVerletError (README). AttributeError keeps
    # Python's meaning (a missing or read-only attribute), AssertionError marks a bug in the package itself.
    import ast
    from pathlib import Path

    import warp_verlet

    builtin = {n for n in dir(__import__("builtins")) if n.endswith(("Error", "Exception"))}
    allowed = {"AttributeError", "AssertionError"}  # a missing attribute; an internal invariant broken (a bug)
    root = Path(warp_verlet.__file__).parent
    found = []
    for path in sorted(list(root.rglob("*.py")) + list((root.parent / "kernels").glob("*.py"))):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None:
                target = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                name = target.id if isinstance(target, ast.Name) else None
                if name in builtin and name not in allowed:
                    found.append(f"{path.name}:{node.lineno} raises {name}")
    assert not found, found


@pytest.mark.parametrize("budget", [False, True])
def test_kernel_loading_is_timed_apart_from_the_frames(scene_file, monkeypatch, budget):
    # Warp loads a module at its first launch, compiling it when its kernel cache lacks it (seconds). The run
    # loads them all before its clock starts: none may load while frames are stepped, and the summary reports
    # the start-up on its own line.
    import warp as wp

    from warp_verlet.apps import runner
    from warp_verlet.input.scene import load_scene

    import warp_verlet.kernels.readback  # noqa: F401  (imported by the first step otherwise, unloaded here)
    import warp_verlet.kernels.relax  # noqa: F401
    import warp_verlet.core.simulator  # noqa: F401

    if budget:  # a target_stretch budget reduces the stretch on the device every frame
        scene_file.write_text(SCENE.replace("substeps = 2\niterations = 4\n", "target_stretch = 0.01\n"))

    kernels = [name for name in sys.modules if name.startswith("warp_verlet.kernels.")]
    for name in kernels:
        wp.get_module(name).unload()  # as in a fresh process: the run must load each module again
    module_type = type(wp.get_module(kernels[0]))
    loads, stepping = [], []
    real_load, real_loop = module_type.load, runner._step_loop

    def load(self, device, *args, **kwargs):
        if not self.execs:  # Warp's loaded executables of this module: none until it is loaded
            loads.append((self.name, bool(stepping)))
        return real_load(self, device, *args, **kwargs)

    def step_loop(*args, **kwargs):
        stepping.append(True)
        return real_loop(*args, **kwargs)

    monkeypatch.setattr(module_type, "load", load)
    monkeypatch.setattr(runner, "_step_loop", step_loop)
    summary = runner.run_scene(load_scene(scene_file), device="cpu")
    assert (summary.budget is not None) == budget
    assert stepping and {"warp_verlet.kernels.relax", "warp_verlet.kernels.integrate"} <= {n for n, _ in loads}
    assert [name for name, during in loads if during] == []
    assert 0.0 < summary.kernel_seconds <= summary.startup_seconds
    startup = next(line for line in summary.format().splitlines() if line.startswith("startup"))
    assert f"{summary.startup_seconds:.3f} s" in startup and "not in the wall time" in startup
