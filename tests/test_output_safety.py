"""Never lose a good cache: atomic output, one writer per output, full disks, paths that are inputs,
and what the command line says about each.

A run writes NAME.partial.EXT and renames it over NAME.EXT only when it succeeds; these tests re-run into an
existing good cache and check it byte for byte after a divergence, Ctrl-C, SIGTERM and SIGKILL, refuse a
second run while one holds the output, fake the free space (so the logic is tested everywhere) and, where the
test runs as root and may mount one, fill a real small tmpfs.
"""

from __future__ import annotations

import gc
import os
import shutil
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock
from pxr import Usd, UsdGeom

from warp_verlet.output import output_file
from warp_verlet.apps.cli import main
from warp_verlet.errors import DiskFullError, OutputBusyError, OutputError, WarpVerletError
from warp_verlet.output.output_file import CacheOutput, estimate_cache, output_report
from test_cli import SCENE as CLI_SCENE, interrupt_runs_after
from warp_verlet.apps.runner import run_scene
from warp_verlet.input.scene import load_scene
from warp_verlet.output.usd_writer import CachedShape, PointCacheWriter, validate_cache

# test_cli's small scene, its first cloth only (one cloth keeps the frame sizes simple to reason about).
SCENE = CLI_SCENE[:CLI_SCENE.index("[[cloth]]", CLI_SCENE.index("[[cloth]]") + 1)]
# The same scene gone wrong: 1000 m/s^2 and no pins take the cloth past a 3 m bound during frame 3.
DIVERGING = SCENE.replace("damping = 0.6", "damping = 0.0\ngravity = [0.0, -1000.0, 0.0]\nposition_bound = 3.0") \
    .replace('pins = ["top-left", "top-right"]', "pins = []")
# A run long enough to be caught while it writes (100 000 frames, saved every 500; a crate file rewrites its
# time-sample tables at every save, so saving every 2 frames would make this cache thousands of GB).
ENDLESS = SCENE.replace("frames = 6", "frames = 100000").replace("save_every = 2", "save_every = 500")


@pytest.fixture(autouse=True)
def lock_directory(tmp_path_factory, monkeypatch) -> Path:
    """This test's own runtime directory, where the output locks go (output_file.lock_directory); the runs
    these tests start in subprocesses inherit it."""
    runtime = tmp_path_factory.mktemp("runtime")
    runtime.chmod(0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    return runtime / "warp-verlet"


@pytest.fixture
def work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "small.toml").write_text(SCENE)
    return tmp_path


def run(*args: str) -> int:
    return main(["run", *args, "--device", "cpu", "-q"])


def sheet_frames(path: Path) -> list[float]:
    stage = Usd.Stage.Open(str(path))
    return list(UsdGeom.Mesh(stage.GetPrimAtPath("/World/sheet")).GetPointsAttr().GetTimeSamples())


@pytest.fixture
def good_cache(work) -> bytes:
    """A finished cache of the small scene in work/small.usdc; its bytes."""
    assert run("small.toml") == 0
    assert not (work / "small.partial.usdc").exists()  # a successful run leaves only its output
    return (work / "small.usdc").read_bytes()


# ------------------------------------------------------------------------------- atomic output (defect 2)


def test_a_rerun_that_diverges_keeps_the_previous_cache_byte_for_byte(work, good_cache, capsys):
    (work / "bad.toml").write_text(DIVERGING)
    capsys.readouterr()
    assert run("bad.toml", "-o", "small.usdc") == 1
    err = capsys.readouterr().err
    assert "diverged at frame 3" in err
    assert "frames 0 to 2 are in small.partial.usdc; small.usdc is as it was before this run" in err
    assert (work / "small.usdc").read_bytes() == good_cache
    partial = work / "small.partial.usdc"
    assert validate_cache(partial) == [] and sheet_frames(partial) == [0, 1, 2]


def test_a_rerun_interrupted_by_ctrl_c_keeps_the_previous_cache(work, good_cache, monkeypatch, capsys):
    interrupt_runs_after(monkeypatch, 3)
    capsys.readouterr()
    assert run("small.toml") == 130
    assert "interrupted: frames 0 to 3 are in small.partial.usdc; small.usdc is as it was" in capsys.readouterr().err
    assert (work / "small.usdc").read_bytes() == good_cache
    assert sheet_frames(work / "small.partial.usdc") == [0, 1, 2, 3]


def test_ctrl_c_before_the_output_is_opened_claims_no_cache(work, monkeypatch, capsys):
    import warp_verlet.core.simulator

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt  # as if Ctrl-C came while the kernels compiled

    monkeypatch.setattr(warp_verlet.core.simulator.Simulator, "__init__", interrupted)
    assert run("small.toml") == 130
    err = capsys.readouterr().err
    assert "interrupted: nothing was written; small.usdc was not written" in err
    assert "holds the frames" not in err and "are in" not in err
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]


def test_an_error_inside_the_run_keeps_its_frames_and_reports_them_to_the_api(work, good_cache):
    scene = load_scene("small.toml")

    def progress(frame):
        if frame == 4:
            raise RuntimeError("a bug in a progress callback")

    with pytest.raises(RuntimeError) as caught:
        run_scene(scene, device="cpu", progress=progress)
    report = output_report(caught.value)
    assert report is not None and report.previous and report.frames == (0, 4)
    assert report.partial == Path("small.partial.usdc") and report.output == Path("small.usdc")
    assert (work / "small.usdc").read_bytes() == good_cache
    assert sheet_frames(work / "small.partial.usdc") == [0, 1, 2, 3, 4]


def test_a_successful_run_replaces_the_cache_and_an_old_partial_with_a_note(work, good_cache, capsys):
    (work / "bad.toml").write_text(DIVERGING)
    assert run("bad.toml", "-o", "small.usdc") == 1
    assert (work / "small.partial.usdc").exists()
    capsys.readouterr()
    assert run("small.toml") == 0
    err = capsys.readouterr().err
    assert "note: small.partial.usdc holds the frames of an earlier run that did not finish; this run replaces it" in err
    assert not (work / "small.partial.usdc").exists()
    assert (work / "small.usdc").read_bytes() == good_cache  # the same scene again: bit-identical


def start_endless(work: Path, output: str = "small.usdc") -> subprocess.Popen:
    """A run of a million frames in a subprocess, returned once its partial file holds saved frames."""
    (work / "endless.toml").write_text(ENDLESS)
    proc = subprocess.Popen([sys.executable, "-m", "warp_verlet", "run", "endless.toml", "-o", output,
                             "--device", "cpu", "-q"], cwd=work, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    partial = work / output.replace(".usdc", ".partial.usdc")
    sizes = set()  # the empty layer, the topology, then frames: the third size means frames are on disk
    deadline = time.monotonic() + 300  # a guard against a hang, not a timing: it normally takes seconds
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            sizes.add(partial.stat().st_size)
        except FileNotFoundError:
            pass
        if len(sizes) >= 3:
            return proc
        time.sleep(0.02)
    proc.kill()
    out, err = proc.communicate()
    pytest.fail(f"the endless run never saved frames: rc {proc.returncode}\n{err}")


@pytest.mark.slow
def test_a_rerun_killed_with_sigkill_keeps_the_previous_cache_byte_for_byte(work, good_cache, capsys):
    proc = start_endless(work)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    assert (work / "small.usdc").read_bytes() == good_cache
    # The killed run's frames up to its last save; not checked further: a crate file is appended to in place,
    # and a kill during a save can leave it unreadable (measured: 8 of 40 kills of a run that saves often).
    assert (work / "small.partial.usdc").is_file()
    # The next run finds what the killed one left, says so, and leaves nothing behind when it succeeds.
    stale_temp = work / "small.partial.Ab12Cd"  # what USD leaves when a run is killed during a save
    stale_temp.write_bytes(b"PXR-USDC half a save")
    (work / "small.partial.backup").write_text("a file of the user's, named alike but no USD: left alone")
    capsys.readouterr()
    assert run("small.toml") == 0
    err = capsys.readouterr().err
    assert f"note: removed {stale_temp}, a temporary file left by an earlier run that was killed during a save" in err
    assert "small.partial.usdc holds the frames of an earlier run" in err
    assert sorted(p.name for p in work.iterdir()) == ["endless.toml", "small.partial.backup", "small.toml",
                                                      "small.usdc"]


@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c_and_says_where_the_frames_are(work, good_cache):
    proc = start_endless(work)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate()
    assert proc.returncode == 143, err
    assert "terminated: frames 0 to " in err and "are in small.partial.usdc; small.usdc is as it was" in err
    assert "Traceback" not in err
    assert (work / "small.usdc").read_bytes() == good_cache
    assert validate_cache(work / "small.partial.usdc") == []


# ------------------------------------------------------------------------------ one writer (defect 3)


def test_a_second_run_to_the_same_output_is_refused_at_once(work, good_cache, capsys):
    proc = start_endless(work)
    try:
        capsys.readouterr()
        assert run("small.toml") == 1
        err = capsys.readouterr().err
        assert "error: cannot write small.usdc: another run is writing it now" in err
        assert proc.poll() is None  # the first run goes on
        assert (work / "small.usdc").read_bytes() == good_cache
    finally:
        proc.kill()
        proc.communicate()


def test_the_lock_is_refused_without_waiting_and_released_after_any_run(work):
    with FileLock(str(output_file.lock_path(work / "small.usdc"))):  # another process's run, as flock sees it
        with pytest.raises(OutputBusyError, match="another run is writing it now"):
            run_scene(load_scene("small.toml"), device="cpu")
        assert not (work / "small.usdc").exists() and not (work / "small.partial.usdc").exists()
    (work / "bad.toml").write_text(DIVERGING)
    with pytest.raises(WarpVerletError):
        run_scene(load_scene("bad.toml"), output="small.usdc", device="cpu")
    run_scene(load_scene("small.toml"), device="cpu")  # the failed run released the lock


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc, where no file can be created")
def test_a_lock_that_cannot_be_created_is_not_called_busy(work, monkeypatch):
    # filelock times out on a directory where the lock file cannot be created at all, as it does on a held lock;
    # the message says which of the two happened (the live page's Save to such a place showed "busy").
    monkeypatch.setenv("XDG_RUNTIME_DIR", "/proc")
    with pytest.raises(OutputError, match=r"cannot create the output lock directory /proc/warp-verlet") as refused:
        run_scene(load_scene("small.toml"), device="cpu")
    assert not isinstance(refused.value, OutputBusyError)
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]


def test_the_lock_lives_in_the_private_lock_directory_and_every_path_to_the_output_finds_it(work, lock_directory):
    assert run("small.toml") == 0
    assert sorted(p.name for p in work.iterdir()) == ["small.toml", "small.usdc"]  # nothing beside the output
    (lock,) = lock_directory.iterdir()
    assert lock.name.startswith("small.usdc.") and lock.name.endswith(".lock") and lock.stat().st_size == 0
    assert lock_directory.stat().st_mode & 0o777 == 0o700
    (work / "sub").mkdir()
    (work / "alias").symlink_to(work)
    assert output_file.lock_path(work / "small.usdc") == lock
    assert output_file.lock_path(work / "alias" / "small.usdc") == lock  # the same directory, by another path
    assert output_file.lock_path(work / "sub" / "small.usdc") != lock  # the same name elsewhere: another lock
    assert output_file.lock_path(work / "other.usdc") != lock


def test_a_lock_directory_open_to_others_is_refused(work, lock_directory):
    lock_directory.mkdir(mode=0o777)
    lock_directory.chmod(0o777)
    with pytest.raises(OutputError, match="is not a private directory of this user's"):
        run_scene(load_scene("small.toml"), device="cpu")
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]


# ---------------------------------------------------------------------------------- paths (defect 4)


def test_the_output_may_not_be_the_scene_or_a_symlink_to_it(work, capsys):
    scene = work / "x.usda"  # a scene whose name is a USD name
    scene.write_text(SCENE)
    before = scene.read_bytes()
    assert run(str(scene), "-o", str(scene)) == 2  # a bad argument (tests/test_exit_codes.py)
    assert "the output would overwrite the input file" in capsys.readouterr().err
    link = work / "link.usda"
    link.symlink_to(scene)
    assert run(str(scene), "-o", str(link)) == 2
    err = capsys.readouterr().err
    assert "would overwrite the input file" in err and "link.usda is a symlink to it" in err
    # The default output named like the scene's own partial file is refused too.
    assert run(str(work / "small.toml"), "-o", str(work / "small.partial.usdc")) == 2
    assert "kept for the frames of runs that did not finish" in capsys.readouterr().err
    assert scene.read_bytes() == before and link.is_symlink()
    assert sorted(p.name for p in work.iterdir()) == ["link.usda", "small.toml", "x.usda"]


def test_a_symlinked_output_replaces_the_file_it_points_to_and_keeps_the_link(work, good_cache):
    (work / "real").mkdir()
    target = work / "real" / "cache.usdc"
    target.write_bytes(b"old")
    (work / "link.usdc").symlink_to(target)
    assert run("small.toml", "-o", "link.usdc") == 0
    assert (work / "link.usdc").is_symlink() and target.read_bytes() == good_cache


def test_a_directory_in_the_way_is_refused_and_leaves_no_temporary_file(work, capsys):
    (work / "small.usdc").mkdir()
    assert run("small.toml") == 1
    assert "small.usdc is a directory" in capsys.readouterr().err
    assert sorted(p.name for p in work.iterdir()) == ["small.toml", "small.usdc"]


def test_input_files_finds_the_scene_and_path_fields():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class MeshCloth:  # the shape of a cloth spec that reads a file
        name: str
        mesh: Path
        layers: tuple

    class Scene:
        source = __file__
        cloths = (MeshCloth("a", Path("a.obj"), (Path("over.usda"), "not a path")),)
        colliders = ()

    assert output_file.input_files(Scene()) == [Path(__file__), Path("a.obj"), Path("over.usda")]


# ------------------------------------------------------------------------------ disk space (defect 1)


def fake_free(monkeypatch, free):
    """shutil.disk_usage as the output module sees it, with ``free(call)`` bytes free at the call-th check."""
    calls = []

    def disk_usage(path):
        calls.append(str(path))
        real = shutil._ntuple_diskusage if hasattr(shutil, "_ntuple_diskusage") else None
        value = int(free(len(calls)))
        return real(10**12, 10**12 - value, value) if real else type("U", (), {"free": value})()

    monkeypatch.setattr(output_file.shutil, "disk_usage", disk_usage)
    return calls


def test_a_cache_that_cannot_fit_is_refused_before_anything_is_written(work, good_cache, monkeypatch, capsys):
    calls = fake_free(monkeypatch, lambda call: 20_000)  # the small cache needs about 70 kB
    capsys.readouterr()
    assert run("small.toml") == 1
    err = capsys.readouterr().err
    assert "error: cannot write small.usdc: the cache needs about" in err and "20 kB free" in err
    assert calls and (work / "small.usdc").read_bytes() == good_cache
    assert not (work / "small.partial.usdc").exists()


def test_the_disk_filling_up_mid_run_stops_cleanly_with_the_frames_saved(work, good_cache, monkeypatch, capsys):
    # Plenty of room up front and for the first saves, then none: the run stops before the save that would
    # not fit, USD is never asked to write it, and the saved frames stay a valid cache.
    from pxr import Sdf

    saves = []
    real_save = Sdf.Layer.Save

    def counting_save(self, *args):
        saves.append(self.identifier)
        return real_save(self, *args)

    monkeypatch.setattr(Sdf.Layer, "Save", counting_save)
    fake_free(monkeypatch, lambda call: 10**9 if call <= 3 else 1000)  # check_space, topology, frames 0-1
    capsys.readouterr()
    assert run("small.toml") == 1
    err = capsys.readouterr().err
    assert "error: not enough disk space for small.usdc: saving the next 2 frame(s) needs about" in err
    assert "stopped before USD could write into a full disk" in err
    assert "frames 0 to 1 are in small.partial.usdc; small.usdc is as it was before this run" in err
    assert (work / "small.usdc").read_bytes() == good_cache
    partial = work / "small.partial.usdc"
    assert validate_cache(partial) == [] and sheet_frames(partial) == [0, 1]
    assert len(saves) == 2  # the topology and frames 0-1: nothing after the refusal, not even at close


def test_the_refined_estimate_stops_a_run_whose_rest_will_not_fit(work, monkeypatch):
    # Each save fits, but two saves measure the frames, and the rest of a 200-frame run does not fit.
    (work / "long.toml").write_text(SCENE.replace("frames = 6", "frames = 200"))
    estimate = estimate_cache([CachedShape("sheet", np.zeros((0, 4), np.int32), np.zeros((42, 2), np.float32), 42)])
    room = 2 * output_file.RESERVE_BYTES + 60 * estimate.frame_bytes  # about 60 frames' worth, then

    def free(call):
        return 10**9 if call == 1 else room

    fake_free(monkeypatch, free)
    with pytest.raises(DiskFullError, match="the whole cache needs about .* more") as caught:
        run_scene(load_scene("long.toml"), device="cpu")
    report = output_report(caught.value)
    assert report.frames is not None and report.frames[1] < 60


def test_the_estimate_matches_the_file_within_a_few_percent(work, monkeypatch):
    seen = {}
    real = CacheOutput.check_space

    def spy(self, estimate, frames, save_every):
        seen["total"] = estimate.total(frames, save_every)
        return real(self, estimate, frames, save_every)

    monkeypatch.setattr(CacheOutput, "check_space", spy)
    for suffix in (".usdc", ".usda"):
        run_scene(load_scene("small.toml"), output=f"e{suffix}", device="cpu", frames=60)
        actual = (work / f"e{suffix}").stat().st_size
        # Crate files: within a few percent; text files: the estimate allows the longest spelling of a float.
        low, high = (0.9, 1.25) if suffix == ".usdc" else (0.9, 2.0)
        assert low * actual <= seen["total"] <= high * actual, (suffix, seen["total"], actual)


def _mount_tmpfs(path: Path, size: str) -> str | None:
    """Mount a tmpfs of ``size`` at ``path``; None when done, else why not."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "mounting a tmpfs needs root"
    if shutil.which("mount") is None or shutil.which("umount") is None:
        return "no mount/umount command"
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True)
    return None if done.returncode == 0 else f"cannot mount a tmpfs here: {done.stderr.strip()}"


@pytest.fixture
def small_disk(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    why = _mount_tmpfs(disk, "3m")
    if why is not None:
        pytest.skip(why)
    try:
        yield disk
    finally:
        gc.collect()  # USD maps crate files into memory: release the stages first
        if subprocess.run(["umount", str(disk)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(disk)], check=False)  # detached now, gone when unused


def test_a_real_full_disk_refuses_up_front_and_stops_mid_run(small_disk, work, capsys):
    # The case: hanging_cloth (about 6 MB) onto a 3 MB tmpfs segfaulted inside USD (exit 139).
    scenes = Path(__file__).resolve().parent.parent / "scenes"
    out = small_disk / "c.usdc"
    assert run(str(scenes / "hanging_cloth.toml"), "-o", str(out)) == 1
    assert "the cache needs about 6" in capsys.readouterr().err
    assert sorted(p.name for p in small_disk.iterdir()) == []

    # 40 frames fit (about 2 MB); at frame 15 another program fills the disk but for 400 kB.
    def fill(frame):
        if frame == 15:
            fd = os.open(small_disk / "filler", os.O_WRONLY | os.O_CREAT)
            try:
                while True:
                    os.write(fd, bytes(65536))
            except OSError:
                pass
            finally:
                os.close(fd)
            os.truncate(small_disk / "filler", os.path.getsize(small_disk / "filler") - 400_000)

    with pytest.raises(DiskFullError, match="stopped before USD could write into a full disk") as caught:
        run_scene(load_scene(scenes / "hanging_cloth.toml"), output=out, device="cpu", frames=40, progress=fill)
    report = output_report(caught.value)
    assert report.frames is not None and report.frames[1] >= 9
    assert validate_cache(small_disk / "c.partial.usdc") == []
    stage = Usd.Stage.Open(str(small_disk / "c.partial.usdc"))
    assert stage.GetEndTimeCode() == report.frames[1]


# ----------------------------------------------------------------------------------- one-line errors


def test_usd_errors_become_one_line_without_cpp_source_locations(tmp_path):
    from pxr import Sdf, Tf

    from warp_verlet.errors import usd_cause

    (tmp_path / "file.txt").write_text("a file, not a directory")
    with pytest.raises(Tf.ErrorException) as caught:
        Sdf.Layer.CreateAnonymous().Export(str(tmp_path / "file.txt" / "x.usda"))
    cause = usd_cause(caught.value)
    assert cause and "\n" not in cause and ".cpp" not in cause and "pxrInternal" not in cause
    garbage = tmp_path / "garbage.usdc"
    garbage.write_bytes(b"PXR-USDC" + bytes(200))
    (problem,) = validate_cache(garbage)
    assert "cannot be opened as USD" in problem and ".cpp" not in problem and "\n" not in problem.strip()


def test_a_writer_that_usd_cannot_save_raises_one_line(tmp_path, monkeypatch):
    from pxr import Sdf

    (tmp_path / "file.txt").write_text("a file, not a directory")

    def refuse(self, *args, **kwargs):
        return Sdf.Layer.CreateAnonymous().Export(str(tmp_path / "file.txt" / "x.usda"))  # a real Tf error

    shape = CachedShape("rope", np.zeros((0, 4), np.int32), np.zeros((4, 2), np.float32), 4)
    monkeypatch.setattr(Sdf.Layer, "Save", refuse)
    with pytest.raises(OutputError) as caught:
        PointCacheWriter(tmp_path / "c.usdc", [shape], fps=30)
    assert str(caught.value).startswith(f"cannot save USD cache {tmp_path / 'c.usdc'}: ")
    assert ".cpp" not in str(caught.value) and "\n" not in str(caught.value)


def test_a_run_refused_at_its_first_save_can_be_run_again_in_the_same_process(work, monkeypatch):
    # The refused writer must not keep its layer open: the retry would be told the file is open in this process.
    full = [True]
    fake_free(monkeypatch, lambda call: 1000 if call == 2 and full[0] else 10**9)  # no room at the first save
    with pytest.raises(DiskFullError, match="the cache's first save needs about") as caught:
        run_scene(load_scene("small.toml"), device="cpu")
    assert not (work / "small.partial.usdc").exists() and not (work / "small.usdc").exists()
    full[0] = False  # the disk was cleared; the caller still holds the exception (and its traceback)
    run_scene(load_scene("small.toml"), device="cpu")
    # What made the retry a test: the traceback still held the refused writer while the retry ran.
    assert any(isinstance(frame.f_locals.get("self"), PointCacheWriter)
               for frame, _ in traceback.walk_tb(caught.value.__traceback__))
    assert sheet_frames(work / "small.usdc") == list(range(7))
