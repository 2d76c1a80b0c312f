"""bench.work_precision, bench.numpy_baseline, bench.cpu_reference (and bench.newton_peer): smoke
tests at tiny sizes, plus the physics checks that make their numbers meaningful.

Bounds are set from measured values (in each comment) with a margin.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import cpu_reference as cref
from bench import newton_peer
from bench import numpy_baseline as npb
from bench import work_precision as wpb
from bench.common import hanging_cloth
from warp_verlet.core.simulator import Simulator

TINY = ["--resolution", "8", "--iterations", "1", "4", "32", "--substeps", "1", "2", "--seconds", "0.05",
        "--repeats", "2", "--ref-substeps", "16", "--ref-iterations", "32"]


def _rows(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


# ---------------------------------------------------------------- work_precision.py

@pytest.fixture(scope="module")
def wp_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("work_precision")
    assert wpb.main([*TINY, "--newton-points", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_work_precision_outputs(wp_run):
    for name in ("work_precision.csv", "reference.csv", "work_precision.md", "work_precision.png"):
        assert (wp_run / name).stat().st_size > 0, name
    rows = _rows(wp_run / "work_precision.csv")
    assert list(rows[0]) == wpb.COLUMNS
    assert len(rows) == 3 * 2 * 2  # K x S x solver
    assert {(r["solver"], int(r["substeps"]), int(r["iterations"])) for r in rows} == {
        (s, S, K) for s in ("coloured", "jacobi") for S in (1, 2) for K in (1, 4, 32)}
    for r in rows:
        assert int(r["frames"]) == 3 and int(r["sticks"]) > 0
        for key in ("wall_per_sim_s", "wall_min", "wall_max", "Mproj_per_s", "stretch_rms", "stretch_max",
                    "pos_error_traj", "pos_error"):
            v = float(r[key])
            assert math.isfinite(v) and v > 0, (key, r)
        assert float(r["wall_min"]) <= float(r["wall_per_sim_s"]) <= float(r["wall_max"])
    md = (wp_run / "work_precision.md").read_text()
    for text in ("Pareto front", "Reference: S = 16, K = 32", "vs K = 16", "vs S = 8", "command:", "CPU:", "Warp ",
                 "soft sticks made rigid (scene compliance: cloth: bend = 0.7 m/N)"):
        assert text in md, text


@pytest.mark.slow
def test_work_precision_physics(wp_run):
    rows = _rows(wp_run / "work_precision.csv")
    err = {(r["solver"], int(r["substeps"]), int(r["iterations"])): float(r["pos_error"]) for r in rows}
    traj = {(r["solver"], int(r["substeps"]), int(r["iterations"])): float(r["pos_error_traj"]) for r in rows}
    stretch = {(r["solver"], int(r["substeps"]), int(r["iterations"])): float(r["stretch_rms"]) for r in rows}
    # The shipped quick start at 8 x 8, swinging down under its tethers (on by default for its pins), with rigid
    # sticks (the sweep includes Jacobi). Its two tethers hold each particle on a circle about the pinned edge, so
    # against a reference of S = 16 the error is mostly the step's: more sweeps help a little, more substeps more.
    for S in (1, 2):
        # Over the trajectory: coloured 8.3e-4 -> 7.5e-4 at S = 1, 7.3e-4 -> 6.1e-4 at S = 2.
        assert traj["coloured", S, 32] < 0.95 * traj["coloured", S, 1], S
        # Final frame: coloured 1.39e-3 -> 1.24e-3 at S = 1, 1.25e-3 -> 1.03e-3 at S = 2; stretch 4.8e-4 -> 3.0e-4
        # and 4.3e-4 -> 2.6e-4. Jacobi: 1.40e-3 -> 1.36e-3 and 1.26e-3 -> 1.22e-3.
        assert err["coloured", S, 32] < 0.95 * err["coloured", S, 1], S
        assert stretch["coloured", S, 32] < 0.8 * stretch["coloured", S, 1], S
        assert err["jacobi", S, 32] < err["jacobi", S, 1], S
    # More substeps help at equal K (coloured, K = 32: 1.24e-3 at S = 1, 1.03e-3 at S = 2).
    assert err["coloured", 2, 32] < 0.9 * err["coloured", 1, 32]


@pytest.mark.slow
def test_work_precision_reference_resolves_the_errors(wp_run):
    # The reference (S = 16, K = 32) differs from its half-K and half-S runs by under half the smallest error in
    # the sweep, so the sweep's errors are not reference noise.
    rows = _rows(wp_run / "work_precision.csv")
    ref = {r["run"]: r for r in _rows(wp_run / "reference.csv")}
    assert [(int(ref[k]["substeps"]), int(ref[k]["iterations"])) for k in ("reference", "half K", "half S")] == [
        (16, 32), (16, 16), (8, 32)]
    for kind in ("traj", "final"):  # trajectory 1.1e-4 / 2.3e-4, final frame 1.7e-4 / 3.9e-4
        diffs = [float(ref[k][f"diff_{kind}"]) for k in ("half K", "half S")]
        assert all(d > 0 for d in diffs)  # they are different runs
        column = "pos_error_traj" if kind == "traj" else "pos_error"
        assert max(diffs) < 0.5 * min(float(r[column]) for r in rows)  # smallest: 6.1e-4 / 1.03e-3


def test_pareto():
    pts = [(1.0, 5.0), (2.0, 2.0), (3.0, 3.0), (0.5, 9.0), (2.0, 2.0), (float("nan"), 1.0)]
    # (3, 3) is beaten by (2, 2); the two equal (2, 2) points do not beat each other; NaN is never on the front.
    assert wpb.pareto(pts) == [True, True, False, True, True, False]


def test_point_scene_changes_the_budget_and_nothing_else():
    # Damping (1/s) and compliance (m/N) are per second and physical: two budgets of one scene run the same values.
    base = wpb.load(wpb.DEFAULT_SCENE, 8)
    assert base.simulation.damping > 0 and base.cloths[0].compliance  # the check below is not vacuous
    s0 = base.simulation.substeps
    coarse = wpb.point_scene(base, s0, 3, "coloured", 5)
    fine = wpb.point_scene(base, 4 * s0, 8, "coloured", 5)
    assert (coarse.simulation.substeps, coarse.simulation.iterations, coarse.simulation.frames) == (s0, 3, 5)
    assert (fine.simulation.substeps, fine.simulation.iterations, fine.simulation.relaxation) == (4 * s0, 8, "coloured")
    for point in (coarse, fine):
        assert point.simulation.damping == base.simulation.damping
        assert [c.compliance for c in point.cloths] == [c.compliance for c in base.cloths]
    assert base.cloths[0].resolution == (8, 8) and base.cloths[0].pins == ((0, 0), (0, 7))


def test_jacobi_points_of_a_soft_scene_run_it_rigid_and_say_so():
    base = wpb.load(wpb.DEFAULT_SCENE, 8)
    with pytest.raises(ValueError, match="rigid sticks only"):  # never silently rigid
        wpb.point_scene(base, 4, 8, "jacobi", 5)
    assert wpb.rigid_for(base, ["coloured"]) == (base, None)
    rigid, note = wpb.rigid_for(base, ["coloured", "jacobi"])
    assert [c.compliance for c in rigid.cloths] == [{}] and "bend = 0.7 m/N" in note
    assert rigid.simulation == base.simulation
    assert wpb.point_scene(rigid, 4, 8, "jacobi", 5).simulation.relaxation == "jacobi"


def test_newton_absent_message(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(wpb.newton_peer, "available", lambda: False)
    args = ["--resolution", "4", "--iterations", "1", "--substeps", "1", "--solvers", "coloured", "--seconds", "0.02",
            "--repeats", "1", "--ref-substeps", "2", "--ref-iterations", "2", "--no-plot", "--out", str(tmp_path)]
    assert wpb.main(args) == 0
    assert "Newton not installed: skipped" in capsys.readouterr().out
    assert "Newton not installed: skipped" in (tmp_path / "work_precision.md").read_text()
    monkeypatch.setattr(newton_peer, "available", lambda: False)
    assert newton_peer.main(["--size", "4"]) == 0
    assert capsys.readouterr().out.strip() == "Newton not installed: skipped"


@pytest.mark.skipif(not newton_peer.available(), reason="Newton not installed (optional peer)")
def test_newton_peer_runs():
    scene = hanging_cloth(8, 2, 4)
    cloth = newton_peer.NewtonCloth(scene)
    sim = Simulator(scene, "cpu")
    assert np.abs(cloth.positions() - sim.positions()).max() < 1e-6  # same start pose, same particle order
    for _ in range(3):
        cloth.step_frame()
    x = cloth.positions()
    pins = [r * 8 + c for r, c in scene.cloths[0].pins]
    assert np.abs(x[pins] - sim.positions()[pins]).max() < 1e-6  # pins hold
    assert np.isfinite(x).all() and x[:, 1].min() < sim.positions()[:, 1].min()  # the free cloth sags
    assert sim.stretch(x).rms < 0.1


# ---------------------------------------------------------------- numpy_baseline.py

@pytest.mark.parametrize("solver", ["jacobi", "coloured"])
def test_numpy_baseline_matches_warp(solver):
    # 16 x 16 hanging cloth (rigid sticks), 4 x 8, 10 frames, float32 on both sides with the same sticks: positions
    # agree within 1e-5 m (1e-5 of the cloth size; measured 1.8e-7 m Jacobi, 1.3e-7 m coloured), while the cloth
    # moved 0.071 m (Jacobi) and 2.0e-3 m (coloured): 200x the tolerance at least, so the check is not vacuous.
    c = npb.compare_with_warp(hanging_cloth(16, 4, 8), solver, 10)
    assert c["max_diff"] < 1e-5, c
    assert c["max_moved"] > 100 * 1e-5, c
    assert c["stretch_rms_numpy"] == pytest.approx(c["stretch_rms_warp"], rel=1e-3)


def test_numpy_baseline_measure():
    r = npb.measure(npb.NumpyCloth.from_scene(hanging_cloth(8, 1, 2), "jacobi"), frames=2, repeats=2)
    assert 0 < r["min"] <= r["s_per_frame"] <= r["max"] and math.isfinite(r["proj_per_s"]) and r["proj_per_s"] > 0


# ---------------------------------------------------------------- cpu_reference.py and the C reference

needs_cc = pytest.mark.skipif(cref.find_compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


@needs_cc
def test_c_reference_matches_warp(tmp_path):
    # Same sticks in the same colour order, float32: after 10 frames of a 16 x 16 cloth the largest particle
    # distance to the Warp CPU simulator is under 1e-5 m (measured 1.8e-7 m; the two compilers contract
    # multiply-adds differently) while the cloth moved 2.0e-3 m.
    lib, version = cref.build_c_reference(tmp_path)
    assert version
    scene = hanging_cloth(16, 4, 8)
    c, sim = cref.CCloth(lib, scene), Simulator(scene, "cpu")
    for _ in range(10):
        c.step_frame()
        sim.step_frame()
    diff = np.abs(c.positions().astype(np.float64) - sim.positions()).max()
    moved = np.abs(sim.positions() - sim.model.rest_positions).max()
    assert diff < 1e-5 and moved > 100 * 1e-5, (diff, moved)


def test_cpu_reference_outputs(tmp_path, capsys):
    args = ["--size", "8", "--frames", "2", "--repeats", "2", "--numpy-frames", "1", "--out", str(tmp_path),
            "--threads", "2"]
    assert cref.main(args) == 0
    rows = _rows(tmp_path / "cpu_reference.csv")
    assert list(rows[0]) == ["contender", "grid", "sticks", "substeps", "iterations", "frames_timed", "ms_per_frame",
                             "ms_min", "ms_max", "Mproj_per_s"]
    names = [r["contender"] for r in rows]
    has_c = cref.find_compiler() is not None
    warp = [f"warp {solver}, {t}" for solver in ("coloured", "jacobi") for t in ("1 thread", "2 threads")]
    assert names == warp + (["C (1 thread)"] if has_c else []) + ["numpy jacobi", "numpy coloured"]
    assert {r["grid"] for r in rows} == {"8x8"} and len({r["sticks"] for r in rows}) == 1 and int(rows[0]["sticks"]) > 0
    for r in rows:
        for key in ("ms_per_frame", "ms_min", "ms_max", "Mproj_per_s"):
            assert math.isfinite(float(r[key])) and float(r[key]) > 0, (key, r)
    md = (tmp_path / "cpu_reference.md").read_text()
    assert "warp coloured, 1 thread / numpy jacobi" in md
    assert "bit-identical to the 1-thread runs: yes" in md
    if has_c:
        assert "C / warp coloured, 1 thread" in md and "within the tolerance" in md
    else:
        assert "no C compiler found" in capsys.readouterr().out


@pytest.mark.slow
def test_work_precision_in_a_local_pool_gives_the_same_points_and_says_so(wp_run, tmp_path):
    # The same grid in a 2-worker process pool: every point is the same simulation, so everything but the timings
    # is bit for bit the serial run's; the outputs say that these timings were taken in parallel.
    assert wpb.main([*TINY, "--newton-points", "--no-plot", "--workers", "2", "--out", str(tmp_path)]) == 0
    serial, pooled = _rows(wp_run / "work_precision.csv"), _rows(tmp_path / "work_precision.csv")
    timing = {"wall_per_sim_s", "wall_min", "wall_max", "Mproj_per_s", "pareto"}
    assert [{k: v for k, v in r.items() if k not in timing} for r in pooled] == \
        [{k: v for k, v in r.items() if k not in timing} for r in serial]
    md = (tmp_path / "work_precision.md").read_text()
    assert "Timings: in parallel: up to 2 variants at once on one machine" in md
    assert "compare them only with timings taken the same way" in md
    assert "Timings: isolated: one variant at a time on cpu." in (wp_run / "work_precision.md").read_text()
