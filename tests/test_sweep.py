"""warp-verlet sweep on the local backend: caches and a summary that match them, failures recorded while the rest go
on, resuming, a worker that dies, Ctrl-C, and the command line."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sweep_helpers import (DIVERGING_SWEEP, GRID_SWEEP, read_cache, read_rows, square_or_die, square_unless_killed,
                           structural_stretch, write_sweep)
from warp_verlet.apps.cli import main
from warp_verlet.errors import OutputBusyError, OutputError
from warp_verlet.output.output_file import OutputNameError
from warp_verlet.apps.sweep import cache_problems, load_sweep, run_sweep
from warp_verlet.apps.sweep_backends import InlineBackend, LocalBackend, Slot, device_slots


def local(workers: int = 2) -> LocalBackend:
    return LocalBackend(device_slots("cpu", workers))


def check_rows_match_caches(out: Path, expect: int) -> list[dict]:
    """Every ok row of sweep.csv against its cache read back with pxr: frames, point count (from the row's
    resolution), and the stretch recomputed from the cache's points."""
    rows = read_rows(out / "sweep.csv")
    assert [int(r["index"]) for r in rows] == list(range(expect))
    for r in rows:
        if r["status"] != "ok":
            continue
        cache = Path(r["output"])
        assert cache.parent == out and cache.name == f"{r['name']}.usdc"
        assert cache_problems(cache, int(r["frames"])) == []
        data = read_cache(cache)
        rows_, cols = json.loads(r["cloth.0.resolution"]) if "cloth.0.resolution" in r else (4, 4)
        assert (data["start"], data["end"]) == (0, int(r["frames"]))
        assert data["points"].shape == (int(r["frames"]) + 1, rows_ * cols, 3)
        rms, mx = structural_stretch(data["points"], rows_, cols)
        # abs: the float32 rounding of a stick's length (a converged pinned 4 x 4 cloth's stretch is about that)
        assert float(r["stretch_rms"]) == pytest.approx(rms, rel=1e-4, abs=2e-7), r["name"]
        assert float(r["stretch_max"]) == pytest.approx(mx, rel=1e-4, abs=2e-7), r["name"]
        sidecar = json.loads((out / f"{r['name']}.json").read_text())
        assert sidecar["hash"] == r["hash"] and sidecar["status"] == "ok"
    return rows


@pytest.mark.slow
def test_grid_sweep_gives_valid_caches_and_a_matching_summary(tmp_path):
    sweep = load_sweep(write_sweep(tmp_path))
    result = run_sweep(sweep, local(), progress=False)
    assert result.ran == [0, 1, 2, 3] and result.resumed == [] and not result.failed
    out = tmp_path / "out"
    rows = check_rows_match_caches(out, 4)
    assert [(json.loads(r["cloth.0.resolution"]), int(r["simulation.substeps"])) for r in rows] == [
        ([4, 4], 1), ([4, 4], 2), ([5, 3], 1), ([5, 3], 2)]
    assert all(r["status"] == "ok" and int(r["frames"]) == 3 and float(r["wall_s"]) > 0 for r in rows)
    # The substeps change the cloth (so the rows are not all one result): more substeps, less stretch.
    assert float(rows[1]["stretch_rms"]) < float(rows[0]["stretch_rms"])
    assert sorted(p.name for p in out.glob("*.usdc")) == [f"{r['name']}.usdc" for r in rows]
    assert rows[3]["name"] == "003_resolution=5_3_substeps=2"
    md = (out / "sweep.md").read_text()
    assert "4 variants: 4 ok" in md and "in parallel: up to 2 variants at once" in md
    assert all(r["name"] in md for r in rows)


@pytest.mark.slow
def test_a_diverging_variant_is_recorded_and_the_others_succeed(tmp_path):
    sweep = load_sweep(write_sweep(tmp_path, DIVERGING_SWEEP))
    result = run_sweep(sweep, local(), progress=False)
    rows = read_rows(tmp_path / "out" / "sweep.csv")
    assert [r["status"] for r in rows] == ["ok", "diverged", "ok"]
    assert result.failed == [1]
    bad = rows[1]
    assert "diverged at frame 1" in bad["error"] and "beyond position_bound" in bad["error"]
    assert bad["frames"] == "0" and bad["stretch_rms"] == ""
    # The diverged run's frames before the divergence (frame 0) are in its partial file (output_file.py), a
    # valid cache; the variant's own cache path stays free, so a re-run runs it again.
    assert bad["output"].endswith(".partial.usdc") and cache_problems(Path(bad["output"]), 0) == []
    for r in (rows[0], rows[2]):
        assert cache_problems(Path(r["output"]), 3) == [] and r["error"] == ""
    assert json.loads((tmp_path / "out" / f"{bad['name']}.json").read_text())["status"] == "diverged"


@pytest.mark.slow
def test_a_resumed_sweep_runs_only_what_is_missing(tmp_path):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    first = run_sweep(load_sweep(path), local(), progress=False)
    assert first.ran == [0, 1, 2, 3]
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.usdc")}
    (out / f"{first.rows[2]['name']}.usdc").unlink()
    second = run_sweep(load_sweep(path), local(), progress=False)
    assert second.ran == [2] and second.resumed == [0, 1, 3]
    after = {p.name: p.stat().st_mtime_ns for p in out.glob("*.usdc")}
    changed = sorted(n for n in after if after[n] != before.get(n))
    assert changed == [f"{first.rows[2]['name']}.usdc"]
    rows = check_rows_match_caches(out, 4)
    assert [r["resumed"] for r in rows] == ["yes", "yes", "no", "yes"]
    # The resumed rows keep the measurements of the run that made them.
    for i in (0, 1, 3):
        assert float(rows[i]["wall_s"]) == pytest.approx(first.rows[i]["wall_s"], rel=1e-5)


def test_resume_runs_again_a_short_cache_a_changed_parameter_and_a_failure(tmp_path):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    first = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    # Variant 0: a cache cut short (a run killed after 2 frames), its sidecar still saying ok.
    from warp_verlet.apps.runner import run_scene

    sweep = load_sweep(path)
    run_scene(sweep.variants[0].scene, output=out / f"{first.rows[0]['name']}.usdc", device="cpu", frames=2)
    # Variant 1: the sidecar of another parameter set.
    side = out / f"{first.rows[1]['name']}.json"
    side.write_text(json.dumps({**json.loads(side.read_text()), "hash": "0" * 20}))
    # Variant 3: recorded as failed.
    side = out / f"{first.rows[3]['name']}.json"
    side.write_text(json.dumps({**json.loads(side.read_text()), "status": "diverged"}))
    second = run_sweep(sweep, InlineBackend("cpu"), progress=False)
    assert second.ran == [0, 1, 3] and second.resumed == [2]
    check_rows_match_caches(out, 4)
    # A changed base scene changes every hash: nothing is resumed.
    (tmp_path / "base.toml").write_text((tmp_path / "base.toml").read_text().replace("iterations = 2", "iterations = 3"))
    third = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    assert third.ran == [0, 1, 2, 3] and third.resumed == []


@pytest.mark.slow
def test_a_worker_that_dies_is_recorded_as_killed_and_the_rest_go_on():
    backend = LocalBackend([Slot("cpu", 1)] * 2)
    outcomes = {o.key: o for o in backend.run(square_or_die, [(k, k) for k in (2, 13, 3, 7, 4, 5)])}
    assert sorted(outcomes) == [2, 3, 4, 5, 7, 13]
    assert outcomes[13].status == "killed" and "SIGKILL" in outcomes[13].error and "alone" in outcomes[13].error
    assert outcomes[7].status == "error" and "ValueError: seven is refused" in outcomes[7].error
    for k in (2, 3, 4, 5):
        assert outcomes[k].status == "done" and outcomes[k].value["value"] == k * k, outcomes[k]
        assert outcomes[k].value["device"] == "cpu"


@pytest.mark.slow
def test_every_item_beside_a_dead_worker_is_run_again_and_says_so(tmp_path):
    # "killer" kills its worker. The pool notices a dead worker when it next hears from one ("quick" finishing
    # after the death), and then fails everything still running: "slow", which runs on for 3 s after "quick"
    # finished, is run again alone, as is the killer. "once" kills its worker on
    # its first run only, so its second run succeeds.
    backend = LocalBackend([Slot("cpu", 1)] * 3)
    started, quick_done = str(tmp_path / "killer_started"), str(tmp_path / "quick_finished")
    items = [("slow", {"value": 3, "wait_for": [started, quick_done], "sleep": 3.0,
                       "first": str(tmp_path / "slow_ran")}),
             ("killer", {"value": 13, "die": "always", "started": started}),
             ("quick", {"value": 2, "wait_for": [started], "sleep": 0.2, "finished": quick_done}),
             ("later", {"value": 4}), ("once", {"value": 5, "die": str(tmp_path / "died_once")})]
    outcomes = {o.key: o for o in backend.run(square_unless_killed, items)}
    died = "a worker process died (killed by SIGKILL (out of memory?)) while it ran"
    assert outcomes["slow"].status == "done" and outcomes["slow"].value["value"] == 9
    assert outcomes["slow"].retries == 1 and outcomes["slow"].retry_reason.startswith(died)
    assert outcomes["killer"].status == "killed" and outcomes["killer"].retries == 1
    assert outcomes["killer"].retry_reason.startswith(died)
    # "quick" finished either before the pool broke (once) or was running when it did (then run again), and "later"
    # either ran after the pool was replaced or had taken quick's worker before the pool noticed the death (then
    # it was running, and is run again): either way each outcome says which.
    for key, square in (("quick", 4), ("later", 16)):
        outcome = outcomes[key]
        assert outcome.status == "done" and outcome.value["value"] == square
        assert (outcome.retries, outcome.retry_reason) == (0, None) or \
            (outcome.retries == 1 and outcome.retry_reason.startswith(died)), outcome
    assert outcomes["once"].status == "done" and outcomes["once"].value["value"] == 25
    assert outcomes["once"].retries == 1 and outcomes["once"].retry_reason.startswith(died)


@pytest.mark.slow
def test_a_variant_whose_worker_is_killed_is_run_again_and_recorded(tmp_path, capsys):
    """The out-of-memory killer's SIGKILL from outside, on the one worker of a real sweep: the variant runs again and
    succeeds, and the console, sweep.csv, sweep.md and the sidecar all say that it was run again and why."""
    import multiprocessing
    import threading

    path = write_sweep(tmp_path)
    codes = []
    sweep = threading.Thread(target=lambda: codes.append(main(["sweep", str(path), "--device", "cpu", "--workers",
                                                               "1", "-q"])))
    sweep.start()
    deadline = time.monotonic() + 60
    while not multiprocessing.active_children() and time.monotonic() < deadline:
        time.sleep(0.01)
    workers = multiprocessing.active_children()
    assert len(workers) == 1, workers
    os.kill(workers[0].pid, signal.SIGKILL)
    sweep.join(timeout=300)
    assert codes == [0]  # every variant ok in the end
    out = tmp_path / "out"
    rows = check_rows_match_caches(out, 4)
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert [r["retries"] for r in rows] == ["1", "0", "0", "0"]  # only the first was running when it died
    assert "killed by SIGKILL" in rows[0]["retry_reason"] and rows[1]["retry_reason"] == ""
    err = capsys.readouterr().err
    assert (f"variant {rows[0]['name']}: a worker process died (killed by SIGKILL (out of memory?)) while it ran, "
            "which stops the whole pool; retried: ok") in err
    assert sum("retried" in line for line in err.splitlines()) == 1
    assert f"run again after their worker died: 1 variant(s), {rows[0]['name']}" in (out / "sweep.md").read_text()
    assert json.loads((out / f"{rows[0]['name']}.json").read_text())["retries"] == 1
    # A resumed sweep keeps the record of the run that made the cache.
    assert main(["sweep", str(path), "--device", "cpu", "--workers", "1", "-q"]) == 0
    assert read_rows(out / "sweep.csv")[0]["retries"] == "1"


@pytest.mark.slow
def test_local_pool_pins_one_variant_per_slot():
    backend = LocalBackend([Slot("cpu", 1), Slot("cpu", 1)])
    outcomes = list(backend.run(square_or_die, [(k, k) for k in range(6)]))
    assert sorted(o.value["value"] for o in outcomes) == [k * k for k in range(6)]
    assert len({o.value["pid"] for o in outcomes}) <= 2 and os.getpid() not in {o.value["pid"] for o in outcomes}
    assert backend.timing_note.startswith("in parallel")
    assert LocalBackend([Slot("cpu", 1)]).timing_note.startswith("isolated")
    assert LocalBackend([Slot("cuda:0"), Slot("cuda:1")]).timing_note.startswith("one variant per GPU")


def test_device_slots():
    assert device_slots("cpu", 2, None) == [Slot("cpu", max(1, os.cpu_count() // 2))] * 2 or os.cpu_count() is None
    assert device_slots("cpu", 3, 4) == [Slot("cpu", 4)] * 3
    with pytest.raises(Exception, match="at least 1 worker"):
        device_slots("cpu", 0)
    with pytest.raises(Exception, match="expected a device"):
        device_slots("tpu", 1)


# ---------------------------------------------------------------------------------------------- Ctrl-C

SLOW_SWEEP = """\
[sweep]
scene = "base.toml"
output = "{out}"
frames = 400

[axes]
"cloth.0.resolution" = [[24, 24]]
simulation.substeps = [8, 9, 10, 11, 12, 13]
"""


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_and_the_sweep_resumes(tmp_path):
    path = write_sweep(tmp_path, SLOW_SWEEP)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "warp_verlet", "sweep", str(path), "--device", "cpu", "--workers", "1", "-q"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:  # wait for the first finished variant
        sidecars = list(out.glob("*.json"))
        if sidecars:
            break
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole process group
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "run the same command again to resume" in stderr
    rows = read_rows(out / "sweep.csv")
    statuses = [r["status"] for r in rows]
    assert set(statuses) <= {"ok", "interrupted"} and "ok" in statuses and "interrupted" in statuses, statuses
    for r in rows:  # consistent: an ok row has its complete cache and sidecar; an interrupted one no sidecar
        sidecar = out / f"{r['name']}.json"
        if r["status"] == "ok":
            assert cache_problems(Path(r["output"]), 400) == [] and json.loads(sidecar.read_text())["status"] == "ok"
        else:
            assert not sidecar.exists() and "interrupted" in r["error"]
            # It names where its frames are (the partial file), or nothing: never a cache that does not exist.
            assert r["output"] == "" or (r["output"].endswith(".partial.usdc") and Path(r["output"]).is_file()), r
    done = [int(r["index"]) for r in rows if r["status"] == "ok"]
    again = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    assert again.resumed == done and sorted(again.ran) == [i for i in range(6) if i not in done]
    assert [r["status"] for r in again.rows] == ["ok"] * 6


# ---------------------------------------------------------------------------------------------- the output directory

class PausedBackend(InlineBackend):
    """Runs inline once ``release`` is set; sets ``started`` when the sweep hands it its variants."""

    def __init__(self):
        super().__init__("cpu")
        self.started, self.release = threading.Event(), threading.Event()

    def run(self, fn, items):
        self.started.set()
        assert self.release.wait(120)
        yield from super().run(fn, items)


def test_a_second_sweep_into_the_same_output_directory_is_refused_at_once(tmp_path):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    first_backend, first = PausedBackend(), {}
    thread = threading.Thread(target=lambda: first.update(result=run_sweep(load_sweep(path), first_backend,
                                                                           progress=False)))
    thread.start()
    try:
        assert first_backend.started.wait(120)
        before = (out / "sweep.csv").read_bytes()
        (tmp_path / "alias").symlink_to(out)  # the same directory by another path
        for where in (None, tmp_path / "alias"):
            with pytest.raises(OutputBusyError, match=r"another sweep is writing that directory now"):
                run_sweep(load_sweep(path), InlineBackend("cpu"), out=where, progress=False)
        done = subprocess.run([sys.executable, "-m", "warp_verlet", "sweep", str(path), "--device", "cpu", "-q"],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 1 and done.stderr.count("error:") == 1, done.stderr
        assert "another sweep is writing that directory now" in done.stderr
        assert (out / "sweep.csv").read_bytes() == before and list(out.glob("*.usdc")) == []  # nothing ran
    finally:
        first_backend.release.set()
        thread.join(300)
    assert first["result"].ran == [0, 1, 2, 3] and not first["result"].failed
    check_rows_match_caches(out, 4)
    assert run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False).resumed == [0, 1, 2, 3]  # released


def test_an_output_directory_holding_the_sweep_file_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the output directory "." is the working directory's
    path = write_sweep(tmp_path, GRID_SWEEP.replace('output = "{out}"', 'output = "."'))
    text = path.read_text()
    with pytest.raises(OutputNameError, match=r"the output directory \S+ is the sweep file's own directory"):
        run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    assert main(["sweep", str(path), "--device", "cpu", "-q"]) == 2
    assert "is the sweep file's own directory" in capsys.readouterr().err
    assert path.read_text() == text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["base.toml", "falling.toml", "sweep.toml"]


@pytest.mark.parametrize("name", ["sweep.csv", "sweep.md"])
def test_a_summary_file_this_sweep_did_not_write_is_never_overwritten(tmp_path, name):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    theirs = out / name
    theirs.write_text("index,name\nmy own table\n")
    with pytest.raises(OutputError, match=f"{theirs} is not a summary of {path}"):
        run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    assert theirs.read_text() == "index,name\nmy own table\n" and sorted(p.name for p in out.iterdir()) == [name]
    theirs.unlink()
    run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    again = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False, resume=False)  # its own: replaced
    assert again.ran == [0, 1, 2, 3] and len(read_rows(out / "sweep.csv")) == 4


def test_a_cache_swapped_in_from_another_variant_is_run_again(tmp_path):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    first = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    rows = first.rows
    # Variants 0 and 1 differ in substeps only: the other's cache is a valid cache of as many points and frames.
    mine, other = Path(rows[0]["output"]), Path(rows[1]["output"])
    assert cache_problems(other, 3) == [] and not np.array_equal(read_cache(mine)["points"], read_cache(other)["points"])
    kept = mine.read_bytes()
    mine.write_bytes(other.read_bytes())
    again = run_sweep(load_sweep(path), InlineBackend("cpu"), progress=False)
    assert again.ran == [0] and again.resumed == [1, 2, 3]
    assert np.array_equal(read_cache(mine)["points"], read_cache_bytes(kept, tmp_path)["points"])


def read_cache_bytes(data: bytes, tmp_path: Path) -> dict:
    copy = tmp_path / "copy.usdc"
    copy.write_bytes(data)
    return read_cache(copy)


# ---------------------------------------------------------------------------------------------- command line

@pytest.mark.slow
def test_cli_sweep_runs_resumes_and_reports(tmp_path, capsys):
    path = write_sweep(tmp_path, DIVERGING_SWEEP)
    assert main(["sweep", str(path), "--device", "cpu", "--workers", "2", "-q"]) == 1  # one variant diverged
    text = capsys.readouterr().out
    assert "3 variants: 2 ok, 1 diverged (3 run now, 0 done before)" in text
    assert "001_gravity=0_-1e+30_0: diverged: simulation diverged at frame 1" in text
    assert main(["sweep", str(path), "--device", "cpu", "--workers", "1", "-q"]) == 1
    assert "(1 run now, 2 done before)" in capsys.readouterr().out
    assert main(["sweep", str(path), "--dry-run"]) == 0
    listing = capsys.readouterr().out
    assert "000_gravity=0_-9.81_0" in listing and "valid sweep, 3 variants" in listing


@pytest.mark.slow
def test_warps_start_up_messages_come_from_the_workers_only_with_verbose(tmp_path):
    """Each worker starts Warp as `run` does: no banner, no module-load lines, and no CUDA-driver warning on the CPU,
    unless -v. The warning is expected with -v where Warp, started bare, prints it on this machine (no driver)."""
    from warp_verlet.core.warp_setup import CUDA_DRIVER_WARNING

    bare = subprocess.run([sys.executable, "-c", "import warp; warp.init()"], capture_output=True, text=True)
    no_driver = CUDA_DRIVER_WARNING in bare.stderr
    path = write_sweep(tmp_path)

    def sweep(*extra) -> str:
        done = subprocess.run([sys.executable, "-m", "warp_verlet", "sweep", str(path), "--device", "cpu", "--workers",
                               "2", "-q", "--restart", *extra], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        return done.stdout + done.stderr

    quiet, loud = sweep(), sweep("-v")
    for noise in (CUDA_DRIVER_WARNING, "initialized", "took"):  # warning, banner, "Module ... load ... took"
        assert noise not in quiet, quiet
    assert "Warp" not in quiet and "4 variants: 4 ok" in quiet
    assert loud.count("initialized") >= 1 and "took" in loud  # at least one worker's banner and module loads
    assert (loud.count(CUDA_DRIVER_WARNING) >= 1) == no_driver, loud


@pytest.mark.slow
def test_sweep_frames_overrides_every_variant_and_is_part_of_resume(tmp_path, capsys):
    path = write_sweep(tmp_path)
    out = tmp_path / "out"
    command = ["sweep", str(path), "--device", "cpu", "--workers", "2", "-q"]

    def run(*extra) -> str:
        assert main([*command, *extra]) == 0
        return capsys.readouterr().out

    assert "(4 run now, 0 done before)" in run("--frames", "2")
    check_rows_match_caches(out, 4)
    assert [r["frames"] for r in read_rows(out / "sweep.csv")] == ["2"] * 4
    # Another count is another run of every variant: a 2-frame cache is never resumed as a 4-frame result.
    assert "(4 run now, 0 done before)" in run("--frames", "4")
    rows = check_rows_match_caches(out, 4)
    assert [r["frames"] for r in rows] == ["4"] * 4
    assert "(0 run now, 4 done before)" in run("--frames", "4")
    assert "(4 run now, 0 done before)" in run()  # the base scene's 3 frames
    assert [r["frames"] for r in check_rows_match_caches(out, 4)] == ["3"] * 4
    # A sweep that varies the frame count itself cannot also take --frames.
    varied = tmp_path / "varied.toml"
    varied.write_text('[sweep]\nscene = "base.toml"\n[axes]\n"simulation.frames" = [2, 3]\n')
    assert main(["sweep", str(varied), "--frames", "5", "--dry-run"]) == 2
    assert ("axes.simulation.frames: simulation.frames is already set for every variant by --frames"
            in capsys.readouterr().err)
    with pytest.raises(SystemExit):
        main(["sweep", str(path), "--frames", "0"])
    assert "expected at least 1 frame, got 0" in capsys.readouterr().err


def test_cli_sweep_errors(tmp_path, capsys, monkeypatch):
    path = write_sweep(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text('[sweep]\nscene = "base.toml"\n[axes]\n"cloth.0.mass" = [0.2, -1.0]\n')
    assert main(["sweep", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"error: {bad}: axes.cloth.0.mass: the value -1 gives an invalid scene" in err
    assert "cloth[0].mass: expected a number in (0.0, inf), got -1.0" in err
    assert main(["sweep", str(path), "--workers", "2", "--cpus-per-variant", "1"]) == 1
    assert "Ray's" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    assert main(["sweep", str(path), "--device", "cpu", "--ray"]) == 1
    assert "pip install 'warp-verlet[ray]'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing ran


def test_example_sweep_file_is_valid():
    example = Path(__file__).resolve().parent.parent / "scenes" / "sweeps" / "wind_stiffness.toml"
    sweep = load_sweep(example)
    assert len(sweep.variants) >= 4 and sweep.base.name == "wind_sheet.toml"
    assert all(math.isfinite(v.scene.simulation.wind[2]) for v in sweep.variants)
