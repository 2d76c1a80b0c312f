"""Error against run time: a work-precision sweep over iterations K, substeps S and solver.

    python -m bench.work_precision [SCENE] [--iterations 1 2 4 ...] [--substeps 1 2 4 8 16]
        [--solvers coloured jacobi] [--seconds 0.5] [--repeats 3] [--resolution N] [--out DIR] [--device cpu]

For every (K, S, solver) point the scene (default scenes/swinging_cloth.toml) is simulated for ``--seconds``
of simulated time (a whole number of frames at the scene's fps) from its initial state:

- wall time per simulated second: one untimed warm-up run (Warp compiles its kernels in its first frame; it
  also records the trajectory for the error below), then ``--repeats`` timed runs, each from a fresh
  simulator at the initial state; the median is reported with the spread (min..max). The repeats must end
  bit-identical to the warm-up run (the simulator is deterministic); any that do not are listed. (On CUDA
  each timed run includes its one-off graph capture.)
- stick projections per second: K * S * sticks * frames / wall.
- constraint error at the final frame: RMS and max relative stretch |D - L| / L over structural sticks.
- position error against a converged reference run of the same scene (by default S = 64, K = 128, coloured
  Gauss-Seidel), as RMS particle distance divided by the cloth size (the largest ``size`` entry), two ways:
  ``pos_error_traj`` is the RMS over every particle of every frame (the trajectory), ``pos_error`` over the
  final frame only. A hanging cloth released at rest bounces, and a softer (less converged) cloth bounces at
  a lower frequency, so the final-frame error depends on where in its bounce each run happens to end and is
  not monotone in K; the trajectory error averages over the bounce, and the Pareto front uses it.
  The reference is checked by re-running it at half its K and at half its S; those differences are printed
  and written: errors near them are not resolved by this reference.

One physical problem: the scene's ``damping`` (1/s) and soft sticks' ``compliance`` (m/N, XPBD) are
per-second and physical quantities, the same at any S and K, so every point and the reference run the scene's
own values. The Jacobi solver has rigid sticks only: when the sweep includes it and the scene has a
compliance, every point (and the reference) runs the scene with all sticks rigid, and the outputs say so.

Where the points run (warp_verlet.apps.sweep_backends): by default one at a time in this process, so that every
timing is isolated; ``--workers N`` runs them in a local process pool and ``--ray [ADDRESS]`` as Ray tasks (the grid
on a cluster). Points that ran in parallel on one machine share its cores and memory bandwidth: the outputs say how
the timings were taken, and parallel timings are not to be mixed with isolated ones. On CUDA a local pool or Ray
pins one point per GPU.

Newton (optional peer): when ``import newton`` works, the same cloth also runs through Newton's VBD solver
(bench.newton_peer) at ``--newton-points`` and its points join the table and plot; otherwise the sweep
prints "Newton not installed: skipped".

Outputs under ``--out`` (default bench/results/work_precision): work_precision.csv, reference.csv (the reference
and its half-K / half-S differences), work_precision.md (machine,
command line, reference and its convergence check, the table, the Pareto front) and work_precision.png
(log-log, wall time per simulated second against the trajectory error with the Pareto front marked, against the
final-frame error, and against the final RMS stretch).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from warp_verlet.input.scene import load_scene, parse_scene
from warp_verlet.core.simulator import Simulator
from warp_verlet.apps.sweep_backends import quiet_warp as worker_quiet_warp

from . import newton_peer
from .common import arg_parser, cloth_size, machine, markdown_table, quiet_warp, time_frames, write_csv

HERE = Path(__file__).resolve().parent
DEFAULT_SCENE = HERE.parent / "scenes" / "swinging_cloth.toml"
COLUMNS = ["solver", "substeps", "iterations", "frames", "sticks", "wall_per_sim_s", "wall_min", "wall_max",
           "Mproj_per_s", "stretch_rms", "stretch_max", "pos_error_traj", "pos_error", "pareto"]


# ---------------------------------------------------------------- scenes

def load(path: Path, resolution: int | None = None):
    """The scene at ``path``; with ``resolution``, every cloth re-gridded to N x N before validation (so that
    named pins such as "top-right" land on the new grid's corners)."""
    if resolution is None:
        return load_scene(path)
    data = tomllib.loads(Path(path).read_text())
    for cloth in data.get("cloth", []):
        cloth["resolution"] = [resolution, resolution]
    return parse_scene(data, str(path), Path(path))


def point_scene(base, substeps: int, iterations: int, solver: str, frames: int):
    """``base`` with S, K and the solver replaced; everything else (damping per second, compliance) as it
    is: the physics does not depend on the budget."""
    if solver == "jacobi" and base.compliant:
        raise ValueError("the Jacobi solver has rigid sticks only, and this scene has a compliance: "
                         "run it through rigid_for(scene, solvers) first")
    settings = dataclasses.replace(base.simulation, substeps=substeps, iterations=iterations, relaxation=solver,
                                   frames=frames)
    return dataclasses.replace(base, simulation=settings)


def rigid_for(scene, solvers) -> tuple[object, str | None]:
    """The scene every point runs: ``scene`` itself, or, when ``solvers`` include Jacobi (rigid sticks only)
    and the scene has a compliance, the scene with every stick rigid, so that all points simulate one
    problem. Returns it and a note saying what was changed (None when nothing was)."""
    if "jacobi" not in solvers or not scene.compliant:
        return scene, None
    soft = "; ".join(f"{c.name}: {', '.join(f'{f} = {a:g} m/N' for f, a in c.compliance.items())}"
                     for c in scene.cloths if c.compliance)
    note = (f"The Jacobi solver has rigid sticks only, so every point and the reference run this scene with its "
            f"soft sticks made rigid (scene compliance: {soft}); sweep --solvers coloured to keep them soft.")
    return dataclasses.replace(scene, cloths=tuple(dataclasses.replace(c, compliance={}) for c in scene.cloths)), note


# ---------------------------------------------------------------- runs

def simulate(scene, device: str, frames: int) -> tuple[Simulator, float]:
    """A fresh simulator run ``frames`` frames from the initial state; the simulator and the wall seconds."""
    sim = Simulator(scene, device)
    (per_frame,) = time_frames(sim, frames, 1)
    return sim, per_frame * frames


def trajectory(scene, device: str, frames: int) -> tuple[Simulator, np.ndarray]:
    """An untimed run from the initial state: the simulator and its positions after every frame, (F, N, 3)."""
    sim = Simulator(scene, device)
    out = []
    for _ in range(frames):
        sim.step_frame()
        out.append(sim.positions())
    return sim, np.stack(out)


def measure_point(scene, device: str, frames: int, repeats: int) -> dict:
    """The untimed warm-up run (its trajectory), then ``repeats`` timed runs from the initial state, each of
    which must end bit-identical to the warm-up run."""
    sim, traj = trajectory(scene, device, frames)
    times, identical = [], True
    for _ in range(repeats):
        timed, seconds = simulate(scene, device, frames)
        times.append(seconds)
        identical &= bool(np.array_equal(timed.positions(), traj[-1]))
    return {"sim": sim, "trajectory": traj, "times": times, "identical": identical}


def rms_distance(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of the particle distances between two (..., N, 3) position arrays (all frames and particles)."""
    d = a.astype(np.float64) - b.astype(np.float64)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=-1))))


def pareto(points: list[tuple[float, float]]) -> list[bool]:
    """True for points no other point beats in both coordinates (lower is better in each)."""
    out = []
    for i, (e, t) in enumerate(points):
        ok = math.isfinite(e) and math.isfinite(t)
        for j, (e2, t2) in enumerate(points):
            if j != i and e2 <= e and t2 <= t and (e2 < e or t2 < t):
                ok = False
                break
        out.append(ok)
    return out


def reference_task(payload: dict, slot) -> dict:
    """One reference run, in whichever process the backend chose: its trajectory, stretch and wall seconds.
    (Ray sends bench's code with the task; warp_verlet's quiet_warp, not bench.common's, keeps ``wp.config``, which
    cloudpickle cannot send, out of what travels.)"""
    worker_quiet_warp()
    t0 = time.perf_counter()
    sim, traj = trajectory(payload["scene"], slot.device, payload["frames"])
    st = sim.stretch()
    return {"trajectory": traj, "stretch_rms": st.rms, "stretch_max": st.max, "wall": time.perf_counter() - t0}


def point_task(payload: dict, slot) -> dict:
    """One point of the grid (warm-up run and timed repeats, ``measure_point``), in whichever process the backend
    chose: its times, final stretch, stick count, trajectory and whether the repeats were bit-identical."""
    worker_quiet_warp()
    m = measure_point(payload["scene"], slot.device, payload["frames"], payload["repeats"])
    st = m["sim"].stretch(m["trajectory"][-1])
    return {"times": m["times"], "identical": m["identical"], "trajectory": m["trajectory"],
            "sticks": m["sim"].model.stick_count, "stretch_rms": st.rms, "stretch_max": st.max}


def _results(backend, fn, items: dict) -> dict:
    """Run ``fn`` on every payload of ``items`` (key -> payload) through ``backend``; the values by key, in any
    finishing order. A point that fails stops the benchmark: a grid with holes has no Pareto front to report."""
    out = {}
    for outcome in backend.run(fn, list(items.items())):
        if outcome.status != "done":
            raise RuntimeError(f"work-precision point {outcome.key} {outcome.status}: {outcome.error}")
        out[outcome.key] = outcome.value
    return out


def run(scene, iterations, substeps, solvers, seconds=0.5, repeats=3, device="cpu",
        ref_substeps=64, ref_iterations=128, ref_solver="coloured", newton_points=(), log=print,
        backend=None) -> dict:
    """The sweep. ``backend`` (warp_verlet.apps.sweep_backends) runs the reference runs and the points: by default
    ``InlineBackend(device)``, one at a time in this process (isolated timings); a local pool or Ray runs them in
    parallel, and the result's ``timing`` says so."""
    from warp_verlet.apps.sweep_backends import InlineBackend

    backend = backend or InlineBackend(device)
    scene, rigid_note = rigid_for(scene, [*solvers, ref_solver])
    if rigid_note:
        log(rigid_note, flush=True)
    fps = scene.simulation.fps
    frames = max(1, round(seconds * fps))
    sim_seconds = frames / fps
    size = cloth_size(scene)
    started = time.perf_counter()
    log(f"runs: {backend.description}; timings {backend.timing_note}", flush=True)

    # The reference, and its convergence check at half its K and half its S.
    log(f"reference: S = {ref_substeps}, K = {ref_iterations}, {ref_solver}, {frames} frames "
        f"({sim_seconds:.3f} s simulated)", flush=True)
    budgets = {"ref": (ref_substeps, ref_iterations), "half K": (ref_substeps, max(1, ref_iterations // 2)),
               "half S": (max(1, ref_substeps // 2), ref_iterations)}
    done = _results(backend, reference_task, {
        key: {"scene": point_scene(scene, s_, k_, ref_solver, frames), "frames": frames}
        for key, (s_, k_) in budgets.items()})
    ref_runs = {}
    for key, (s_, k_) in budgets.items():
        r = done[key]
        ref_runs[key] = {"substeps": s_, "iterations": k_, "trajectory": r["trajectory"]}
        log(f"  {key:6s} S = {s_:3d}, K = {k_:4d}: {r['wall']:.1f} s wall, stretch rms {r['stretch_rms']:.3e}",
            flush=True)
    traj_ref = ref_runs["ref"]["trajectory"]
    x_ref = traj_ref[-1]
    reference = {
        "substeps": ref_substeps, "iterations": ref_iterations, "solver": ref_solver, "frames": frames,
        "stretch_rms": done["ref"]["stretch_rms"], "stretch_max": done["ref"]["stretch_max"],
        "half_K": {"iterations": ref_runs["half K"]["iterations"],
                   "diff": rms_distance(ref_runs["half K"]["trajectory"][-1], x_ref) / size,
                   "diff_traj": rms_distance(ref_runs["half K"]["trajectory"], traj_ref) / size},
        "half_S": {"substeps": ref_runs["half S"]["substeps"],
                   "diff": rms_distance(ref_runs["half S"]["trajectory"][-1], x_ref) / size,
                   "diff_traj": rms_distance(ref_runs["half S"]["trajectory"], traj_ref) / size},
    }
    log(f"  reference vs half K: {reference['half_K']['diff_traj']:.2e} trajectory, {reference['half_K']['diff']:.2e} "
        f"final frame; vs half S: {reference['half_S']['diff_traj']:.2e}, {reference['half_S']['diff']:.2e} "
        f"(RMS distance / cloth size)", flush=True)

    grid = [(solver, s_, k_) for solver in solvers for s_ in substeps for k_ in iterations]
    rows, total, nondeterministic = {}, len(grid), []
    payloads = {point: {"scene": point_scene(scene, point[1], point[2], point[0], frames), "frames": frames,
                        "repeats": repeats} for point in grid}
    for outcome in backend.run(point_task, list(payloads.items())):
        if outcome.status != "done":
            raise RuntimeError(f"work-precision point {outcome.key} {outcome.status}: {outcome.error}")
        (solver, s_, k_), m = outcome.key, outcome.value
        times = m["times"]
        wall = float(np.median(times))
        row = {"solver": solver, "substeps": s_, "iterations": k_, "frames": frames,
               "sticks": m["sticks"], "wall_per_sim_s": wall / sim_seconds,
               "wall_min": min(times) / sim_seconds, "wall_max": max(times) / sim_seconds,
               "Mproj_per_s": k_ * s_ * m["sticks"] * frames / wall / 1e6,
               "stretch_rms": m["stretch_rms"], "stretch_max": m["stretch_max"],
               "pos_error_traj": rms_distance(m["trajectory"], traj_ref) / size,
               "pos_error": rms_distance(m["trajectory"][-1], x_ref) / size}
        rows[outcome.key] = row
        if not m["identical"]:
            nondeterministic.append((solver, s_, k_))
        log(f"[{len(rows):3d}/{total}] {solver:8s} S = {s_:2d}, K = {k_:3d}: {row['wall_per_sim_s']:.4f} s per "
            f"simulated s ({row['wall_min']:.4f}..{row['wall_max']:.4f}), {row['Mproj_per_s']:6.1f} M proj/s, "
            f"position error {row['pos_error_traj']:.2e} trajectory, {row['pos_error']:.2e} final, "
            f"stretch rms {row['stretch_rms']:.2e} max {row['stretch_max']:.2e}  "
            f"[{time.perf_counter() - started:.0f} s]", flush=True)
    rows = [rows[point] for point in grid]  # the grid's order, whatever order the points finished in
    nondeterministic.sort(key=grid.index)

    newton_note = None
    if newton_points:
        if not newton_peer.available():
            newton_note = newton_peer.SKIP_MESSAGE
            log(newton_note)
        else:
            probe = Simulator(scene, device="cpu")  # for the stretch metric over the same structural sticks
            for s_, k_ in newton_points:
                sc = point_scene(scene, s_, k_, "coloured", frames)
                r = newton_peer.run(sc, s_, k_, frames, repeats, device)
                wall = float(np.median(r["times"]))
                st = probe.stretch(r["trajectory"][-1])
                rows.append({"solver": "newton-vbd", "substeps": s_, "iterations": k_, "frames": frames,
                             "sticks": "", "wall_per_sim_s": wall / sim_seconds,
                             "wall_min": min(r["times"]) / sim_seconds, "wall_max": max(r["times"]) / sim_seconds,
                             "Mproj_per_s": "", "stretch_rms": st.rms, "stretch_max": st.max,
                             "pos_error_traj": rms_distance(r["trajectory"], traj_ref) / size,
                             "pos_error": rms_distance(r["trajectory"][-1], x_ref) / size})
                log(f"newton-vbd S = {s_:2d}, K = {k_:3d}: {rows[-1]['wall_per_sim_s']:.4f} s per simulated s, "
                    f"position error {rows[-1]['pos_error_traj']:.2e} trajectory, {rows[-1]['pos_error']:.2e} final, "
                    f"stretch rms {st.rms:.2e}", flush=True)
            import newton

            newton_note = (f"Newton {newton.__version__} VBD (tri_ke = tri_ka = {newton_peer.TRI_KE:g}, edge_ke = {newton_peer.EDGE_KE:g}, "
                           "no damping): a membrane model, not sticks; its position error includes that model difference")

    for row, on in zip(rows, pareto([(r["pos_error_traj"], r["wall_per_sim_s"]) for r in rows])):
        row["pareto"] = int(on)
    return {"rows": rows, "reference": reference, "frames": frames, "sim_seconds": sim_seconds, "size": size,
            "nondeterministic": nondeterministic, "newton": newton_note, "rigid": rigid_note,
            "elapsed": time.perf_counter() - started, "timing": backend.timing_note,
            "parallel": backend.parallel > 1, "backend": backend.description}


# ---------------------------------------------------------------- output

def _fmt(v):
    return f"{v:.1f}" if isinstance(v, float) else str(v)


FRONT_COLUMNS = ["solver", "S", "K", "s wall / s simulated", "position error, trajectory", "final", "stretch RMS"]
POINT_COLUMNS = ["solver", "S", "K", "s wall / s simulated", "min..max", "M proj/s", "position error, trajectory",
                 "final", "stretch RMS", "stretch max", "Pareto"]


def _shown(r: dict) -> dict:
    """A result row as the markdown tables show it (POINT_COLUMNS)."""
    return {"solver": r["solver"], "S": r["substeps"], "K": r["iterations"],
            "s wall / s simulated": f"{r['wall_per_sim_s']:.4g}",
            "min..max": f"{r['wall_min']:.4g}..{r['wall_max']:.4g}",
            "M proj/s": _fmt(r["Mproj_per_s"]), "position error, trajectory": f"{r['pos_error_traj']:.3g}",
            "final": f"{r['pos_error']:.3g}", "stretch RMS": f"{r['stretch_rms']:.3g}",
            "stretch max": f"{r['stretch_max']:.3g}", "Pareto": "yes" if r["pareto"] else ""}


def write_outputs(res: dict, out: Path, title: str, command: list[str], plot: bool = True,
                  device: str = "cpu") -> None:
    out.mkdir(parents=True, exist_ok=True)
    rows = res["rows"]
    write_csv(out / "work_precision.csv", [{k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()}
                                           for r in rows], COLUMNS)
    ref = res["reference"]
    write_csv(out / "reference.csv", [
        {"run": "reference", "solver": ref["solver"], "substeps": ref["substeps"], "iterations": ref["iterations"],
         "diff_traj": 0.0, "diff_final": 0.0},
        *({"run": name, "solver": ref["solver"], "substeps": ref[key].get("substeps", ref["substeps"]),
           "iterations": ref[key].get("iterations", ref["iterations"]), "diff_traj": f"{ref[key]['diff_traj']:.6g}",
           "diff_final": f"{ref[key]['diff']:.6g}"} for key, name in (("half_K", "half K"), ("half_S", "half S")))])
    front = sorted((r for r in rows if r["pareto"]), key=lambda r: r["pos_error_traj"])
    lines = [
        f"# Work-precision: {title}", "", *machine(device).lines(command), "",
        f"Simulated {res['frames']} frames ({res['sim_seconds']:.3f} s) from the initial state per point; wall time is "
        "the median of the timed repeats (min..max beside it), after an untimed warm-up run. Position error: RMS "
        f"particle distance to the reference / cloth size ({res['size']:g} m), over all frames (trajectory) and at "
        "the last frame (final); the Pareto front uses the trajectory error, since the final-frame error depends on "
        "the phase of the cloth's bounce at that instant. Stretch: |D - L| / L over structural sticks at the last "
        "frame.",
        "",
        f"Runs: {res.get('backend', 'in this process, one at a time')}. Timings: "
        f"{res.get('timing', 'isolated: one point at a time')}"
        + (" — compare them only with timings taken the same way." if res.get("parallel") else "."),
        "",
        "Damping (1/s) and compliance (m/N) are the scene's own at every point: they are per second and physical, "
        "so every point simulates the same problem." + (" " + res["rigid"] if res.get("rigid") else ""),
        "",
        f"Reference: S = {ref['substeps']}, K = {ref['iterations']}, {ref['solver']}; stretch RMS "
        f"{ref['stretch_rms']:.3e}, max {ref['stretch_max']:.3e}. Convergence check (RMS distance / cloth size, "
        f"trajectory / final frame): vs K = {ref['half_K']['iterations']}: {ref['half_K']['diff_traj']:.2e} / "
        f"{ref['half_K']['diff']:.2e}; vs S = {ref['half_S']['substeps']}: {ref['half_S']['diff_traj']:.2e} / "
        f"{ref['half_S']['diff']:.2e}. Position errors near these are not resolved.",
        "",
    ]
    if res["newton"]:
        lines += [res["newton"], ""]
    if res["nondeterministic"]:
        lines += [f"Repeats that did not end bit-identical: {res['nondeterministic']}", ""]
    lines += ["## Pareto front (no other point is both faster and more accurate)", "",
              markdown_table([_shown(r) for r in front], FRONT_COLUMNS),
              "", "## All points", "", markdown_table([_shown(r) for r in rows], POINT_COLUMNS)]
    if plot:
        lines += ["", "![work-precision](work_precision.png)"]
    (out / "work_precision.md").write_text("\n".join(lines) + "\n")
    if plot:
        plot_front(res, out / "work_precision.png", title)


def plot_front(res: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = res["rows"]
    tiny = 1e-12
    fig, axes = plt.subplots(1, 3, figsize=(20, 6.5), sharey=True)
    substeps = sorted({r["substeps"] for r in rows})
    cmap = plt.get_cmap("viridis")
    colour = {s: cmap(i / max(1, len(substeps) - 1)) for i, s in enumerate(substeps)}
    style = {"coloured": ("-", "o"), "jacobi": ("--", "s"), "newton-vbd": (":", "^")}
    for ax, xkey, xlabel in (
            (axes[0], "pos_error_traj", "position error over the trajectory: RMS distance to reference / cloth size"),
            (axes[1], "pos_error", "position error at the final frame / cloth size"),
            (axes[2], "stretch_rms", "RMS structural stretch |D - L| / L at the final frame")):
        for solver in dict.fromkeys(r["solver"] for r in rows):
            ls, marker = style.get(solver, ("-.", "x"))
            for s in substeps:
                pts = sorted((r for r in rows if r["solver"] == solver and r["substeps"] == s),
                             key=lambda r: r["iterations"])
                if not pts:
                    continue
                ax.plot([max(p[xkey], tiny) for p in pts], [p["wall_per_sim_s"] for p in pts], ls=ls, marker=marker,
                        color=colour[s], ms=4, label=f"{solver}, S = {s}")
        if xkey == "pos_error_traj":
            front = sorted((r for r in rows if r["pareto"]), key=lambda r: r["pos_error_traj"])
            xs, ys = [max(r["pos_error_traj"], tiny) for r in front], [r["wall_per_sim_s"] for r in front]
            ax.step(xs, ys, where="post", color="red", lw=1.5, alpha=0.7, label="Pareto front")
            ax.scatter(xs, ys, s=90, facecolors="none", edgecolors="red", lw=1.5, zorder=5)
            for r in front:
                ax.annotate(f"{r['solver'][0]} S{r['substeps']} K{r['iterations']}", (max(r["pos_error_traj"], tiny),
                            r["wall_per_sim_s"]), fontsize=6, xytext=(4, 4), textcoords="offset points")
            for key, ls in (("half_K", ":"), ("half_S", "-.")):
                ax.axvline(max(res["reference"][key]["diff_traj"], tiny), color="grey", ls=ls, lw=1,
                           label=f"reference vs its {key.replace('_', ' ')}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("wall seconds per simulated second")
    axes[0].legend(fontsize=6, ncol=2)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ---------------------------------------------------------------- command line

def _points(text: str) -> tuple[int, int]:
    s, k = text.lower().split("x")
    return int(s), int(k)


def _backend(args):
    """Where the points run: this process (default), a local pool (--workers), or Ray (--ray). A benchmark sweep
    pins one point per device: on CUDA one per GPU; on the CPU one at a time unless --workers or --ray asks for
    more, and then every output says the timings were taken in parallel."""
    from warp_verlet.apps.sweep_backends import InlineBackend, LocalBackend, RayBackend, device_slots

    if args.ray is not None:
        device = "cuda" if args.device.startswith("cuda") else "cpu"
        return RayBackend(args.ray, device, cpus_per_task=args.cpus_per_point)
    if args.workers is not None:
        threads = 1 if args.device == "cpu" else None
        return LocalBackend(device_slots(args.device, args.workers, threads))
    return InlineBackend(args.device)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = arg_parser("bench.work_precision", __doc__)
    p.add_argument("scene", nargs="?", type=Path, default=DEFAULT_SCENE)
    p.add_argument("--iterations", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64])
    p.add_argument("--substeps", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    p.add_argument("--solvers", nargs="+", choices=["coloured", "jacobi"], default=["coloured", "jacobi"])
    p.add_argument("--seconds", type=float, default=0.5, help="simulated time per point (whole frames)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--resolution", type=int, default=None, help="re-grid every cloth to N x N")
    p.add_argument("--device", default="cpu")
    p.add_argument("--ref-substeps", type=int, default=64)
    p.add_argument("--ref-iterations", type=int, default=128)
    p.add_argument("--ref-solver", choices=["coloured", "jacobi"], default="coloured")
    p.add_argument("--newton-points", type=_points, nargs="*", default=[(4, 2), (4, 8)], metavar="SxK",
                   help="Newton VBD points (substeps x iterations), run when `import newton` works")
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--workers", type=int, default=None,
                   help="run the points in a local process pool of N workers (default: one at a time in this "
                        "process, so that timings are isolated; with N > 1 the output says they ran in parallel)")
    p.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                   help="run each point as a Ray task (alone: a local Ray instance; auto or ADDRESS: a cluster); "
                        "needs pip install 'warp-verlet[ray]'")
    p.add_argument("--cpus-per-point", type=float, default=None,
                   help="Ray: num_cpus per point on the CPU (default 1); on CUDA each point takes one GPU")
    p.add_argument("--out", type=Path, default=HERE / "results" / "work_precision")
    args = p.parse_args(argv)
    quiet_warp()
    scene = load(args.scene, args.resolution)
    with _backend(args) as backend:
        res = run(scene, args.iterations, args.substeps, args.solvers, args.seconds, args.repeats, args.device,
                  args.ref_substeps, args.ref_iterations, args.ref_solver, args.newton_points, backend=backend)
    grid = " + ".join(f"{c.resolution[0]}x{c.resolution[1]}" for c in scene.cloths)
    title = (f"{args.scene.name} ({grid}), {res['sim_seconds']:.3f} s simulated, device {args.device}, "
             f"reference S = {args.ref_substeps}, K = {args.ref_iterations} {args.ref_solver}")
    write_outputs(res, args.out, title, ["bench.work_precision", *argv], plot=not args.no_plot,
                  device=args.device)
    front = [r for r in res["rows"] if r["pareto"]]
    print(f"Pareto front ({len(front)} points):")
    for r in sorted(front, key=lambda r: r["pos_error_traj"]):
        print(f"  {r['solver']:10s} S = {r['substeps']:2d}, K = {r['iterations']:3d}: {r['wall_per_sim_s']:.4f} s per "
              f"simulated s, position error {r['pos_error_traj']:.2e} trajectory ({r['pos_error']:.2e} final), "
              f"stretch rms {r['stretch_rms']:.2e}")
    print(f"timings: {res['timing']}")
    print(f"wrote {args.out}/work_precision.csv, .md, .png in {res['elapsed']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
