"""The Ray backend on a real local Ray instance (``ray.init(num_cpus=2)``): the same summary as the local pool,
bit-identical caches, the same failure handling, and a resumed sweep. Skipped when Ray is not installed (it is an
optional extra: pip install 'warp-verlet[ray]'; CI installs it)."""

from __future__ import annotations

import filecmp
import json
import subprocess
import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="Ray is an optional extra (pip install 'warp-verlet[ray]')")
pytestmark = pytest.mark.slow  # each test starts or uses a local Ray instance

from sweep_helpers import (DIVERGING_SWEEP, GRID_SWEEP, read_rows, square_or_die, square_unless_killed,  # noqa: E402
                           write_sweep)
from warp_verlet.apps.sweep import cache_problems, load_sweep, run_sweep  # noqa: E402
from warp_verlet.apps.sweep_backends import LocalBackend, RayBackend, Slot, device_slots  # noqa: E402

# What may differ between two runs of one variant: the timings, and where and when it ran.
MEASURED = {"wall_s", "task_s", "host", "resumed"}


@pytest.fixture(scope="module")
def ray_instance():
    import logging

    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False)
    yield
    ray.shutdown()


def same_rows(a: list[dict], b: list[dict], root_a: Path, root_b: Path) -> None:
    assert len(a) == len(b)
    for ra, rb in zip(a, b):
        for key in ra:
            if key in MEASURED:
                continue
            va, vb = ra[key], rb[key]
            if key in ("output", "error"):  # the same apart from the directory
                va, vb = va.replace(str(root_a), "<out>"), vb.replace(str(root_b), "<out>")
            assert va == vb, (key, ra, rb)


@pytest.mark.parametrize("text", [GRID_SWEEP, DIVERGING_SWEEP], ids=["grid", "diverging"])
def test_ray_gives_the_local_summary_and_bit_identical_caches(tmp_path, ray_instance, text):
    path = write_sweep(tmp_path, text)
    local = run_sweep(load_sweep(path, tmp_path / "local"), LocalBackend(device_slots("cpu", 2)), progress=False)
    backend = RayBackend(device="cpu")
    assert not backend.started  # it used the test's instance
    assert "one task per variant with num_cpus = 1, up to 2 at once" in backend.description
    remote = run_sweep(load_sweep(path, tmp_path / "ray"), backend, progress=False)
    assert sorted(remote.ran) == sorted(local.ran) == list(range(len(local.rows)))
    rows_local, rows_ray = read_rows(tmp_path / "local" / "sweep.csv"), read_rows(tmp_path / "ray" / "sweep.csv")
    same_rows(rows_local, rows_ray, tmp_path / "local", tmp_path / "ray")
    for r in rows_ray:  # the caches, or a failed variant's partial file, where each row says it is
        a, b = tmp_path / "local" / Path(r["output"]).name, tmp_path / "ray" / Path(r["output"]).name
        assert Path(r["output"]) == b and filecmp.cmp(a, b, shallow=False), r["name"]  # byte for byte
    statuses = [r["status"] for r in rows_ray]
    if text is DIVERGING_SWEEP:
        assert statuses == ["ok", "diverged", "ok"] and "diverged at frame 1" in rows_ray[1]["error"]
    else:
        assert statuses == ["ok"] * 4
    assert "in parallel: up to 2 variants at once across the cluster's 1 node(s)" in (tmp_path / "ray" / "sweep.md").read_text()


def test_ray_resumes_only_what_is_missing(tmp_path, ray_instance):
    path = write_sweep(tmp_path)
    first = run_sweep(load_sweep(path), RayBackend(device="cpu"), progress=False)
    (tmp_path / "out" / f"{first.rows[1]['name']}.usdc").unlink()
    second = run_sweep(load_sweep(path), RayBackend(device="cpu"), progress=False)
    assert second.ran == [1] and second.resumed == [0, 2, 3]
    assert [r["status"] for r in second.rows] == ["ok"] * 4
    assert cache_problems(tmp_path / "out" / f"{first.rows[1]['name']}.usdc", 3) == []


def test_ray_records_a_task_error_and_a_killed_worker(ray_instance):
    backend = RayBackend(device="cpu")
    outcomes = {o.key: o for o in backend.run(square_or_die, [(k, k) for k in (2, 13, 7, 3)])}
    assert outcomes[13].status == "killed" and "retried" in outcomes[13].error
    assert outcomes[7].status == "error" and "ValueError: seven is refused" in outcomes[7].error
    for k in (2, 3):
        assert outcomes[k].status == "done" and outcomes[k].value["value"] == k * k


def test_ray_runs_again_a_task_whose_worker_died_and_says_so(tmp_path, ray_instance):
    # "once" kills its worker on its first run only: its second run succeeds, and its outcome says it was retried.
    backend = RayBackend(device="cpu")
    items = [("once", {"value": 5, "die": str(tmp_path / "died_once")}), ("killer", {"value": 13, "die": "always"}),
             ("fine", {"value": 4})]
    outcomes = {o.key: o for o in backend.run(square_unless_killed, items)}
    assert outcomes["once"].status == "done" and outcomes["once"].value["value"] == 25
    assert outcomes["once"].retries == 1 and outcomes["once"].retry_reason.startswith("its Ray worker died (")
    assert outcomes["killer"].status == "killed" and outcomes["killer"].retries == 1
    assert "again when retried" in outcomes["killer"].error
    assert outcomes["fine"].status == "done" and outcomes["fine"].retries == 0 and outcomes["fine"].retry_reason is None


def test_rays_start_up_messages_only_with_verbose(tmp_path):
    """A sweep that starts its own local Ray instance: Ray's start-up lines and the workers' output only with -v."""
    path = write_sweep(tmp_path)

    def sweep(*extra) -> str:
        done = subprocess.run([sys.executable, "-m", "warp_verlet", "sweep", str(path), "--ray", "--device", "cpu",
                               "-q", "--restart", *extra], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        return done.stdout + done.stderr

    quiet = sweep()
    assert "4 variants: 4 ok" in quiet
    for noise in ("Started a local Ray instance", "(_ray_call", "INFO", "WARNING", "Warp"):
        assert noise not in quiet, quiet
    assert "Started a local Ray instance" in sweep("-v")


def test_ray_ships_the_cache_back_from_a_node_without_the_drivers_disk(tmp_path, ray_instance, monkeypatch):
    # One host here: pretend the task ran on another node (a different node id), so that it writes to a local
    # temporary file and sends the bytes back through the object store; the driver writes them.
    import warp_verlet.apps.sweep_backends as sb

    path = write_sweep(tmp_path)
    local = run_sweep(load_sweep(path, tmp_path / "local"), LocalBackend([Slot("cpu", 1)]), progress=False)
    monkeypatch.setattr(sb, "_driver_node", lambda: "not-this-node")
    remote = run_sweep(load_sweep(path, tmp_path / "shipped"), RayBackend(device="cpu"), progress=False)
    assert [r["status"] for r in remote.rows] == ["ok"] * 4
    for r in local.rows:
        a, b = tmp_path / "local" / f"{r['name']}.usdc", tmp_path / "shipped" / f"{r['name']}.usdc"
        assert filecmp.cmp(a, b, shallow=False), r["name"]
    assert json.loads((tmp_path / "shipped" / f"{local.rows[0]['name']}.json").read_text())["status"] == "ok"


def test_work_precision_grid_on_ray(tmp_path, ray_instance):
    # bench.work_precision's grid as Ray tasks (its package travels by value): the same points as in this process.
    import bench_package  # noqa: F401
    from bench import work_precision as wpb

    tiny = ["--resolution", "6", "--iterations", "1", "4", "--substeps", "1", "2", "--solvers", "coloured",
            "--seconds", "0.05", "--repeats", "1", "--ref-substeps", "8", "--ref-iterations", "8",
            "--newton-points", "--no-plot"]
    assert wpb.main([*tiny, "--out", str(tmp_path / "inline")]) == 0
    assert wpb.main([*tiny, "--ray", "--out", str(tmp_path / "ray")]) == 0
    timing = {"wall_per_sim_s", "wall_min", "wall_max", "Mproj_per_s", "pareto"}
    a, b = read_rows(tmp_path / "inline" / "work_precision.csv"), read_rows(tmp_path / "ray" / "work_precision.csv")
    assert len(a) == 4 and [{k: v for k, v in r.items() if k not in timing} for r in b] == \
        [{k: v for k, v in r.items() if k not in timing} for r in a]
    assert "Timings: in parallel: up to 2 variants at once across the cluster's 1 node(s)" in \
        (tmp_path / "ray" / "work_precision.md").read_text()
