"""Sweep throughput: the same sweep run in this process, in a local process pool and on a local Ray instance, and
what each backend costs per task beside the run time of a small variant.

    python -m bench.sweep_throughput [--cases 24x30 64x60] [--variants 24] [--workers 1 2] [--no-ray]
        [--noop 200] [--out bench/results/sweep] [--stem cpu-2core]

Each case NxF is a sweep of ``--variants`` variants of the hanging cloth at N x N particles, F frames, 4 substeps x
4 sweeps, one relaxation thread each, differing only in damping (so every variant costs the same). Each backend
runs the whole sweep from scratch (``run_sweep(..., resume=False)``) into its own directory; its row gives:

- total s: wall seconds for the whole sweep, from creating the backend (spawning the pool's workers; Ray's own
  ``ray.init`` is timed apart) to the last summary write, and variants/s over it;
- first result s: from creating the backend to the first variant's result: worker start-up (spawn, importing warp
  and pxr, loading the kernels) plus one variant;
- steady variants/s: (variants - 1) / (last result - first result), the rate once the workers are up;
- task s: the median seconds a variant spends in its worker (``task_s``: building the simulator, simulating,
  writing its cache; the first variant in each worker also loads the kernels), and wall_s, its simulation and
  writing alone (``RunSummary.wall_seconds``);
- busy: the sum of task_s over (workers x total s): how much of the backend's worker time ran variants.

The bare round trips: ``--noop`` sequential submit-and-wait calls of a function that returns at once, through a
one-worker ProcessPoolExecutor and through Ray (``ray.get(f.remote())``): the fixed cost of one task. For Ray also
the rate at which as many no-op tasks submitted together complete.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from warp_verlet.apps.sweep import load_sweep, run_sweep
from warp_verlet.apps.sweep_backends import InlineBackend, LocalBackend, RayBackend, Slot

from .common import arg_parser, machine, markdown_table, quiet_warp, write_csv

HERE = Path(__file__).resolve().parent

SCENE = """\
[simulation]
fps = 60
frames = {frames}
substeps = 4
iterations = 4
damping = 0.24

[[cloth]]
name = "cloth"
resolution = [{size}, {size}]
size = [1.0, 1.0]
origin = [-0.5, 1.5, 0.0]
mass = 0.2
pins = ["top-left", "top-right"]
sticks = ["structural", "shear", "bend"]
compliance = {{ bend = 0.7 }}
"""

SWEEP = """\
[sweep]
scene = "base.toml"

[axes]
"simulation.damping" = {{ start = 0.1, stop = 1.0, num = {variants} }}
"""

COLUMNS = ["backend", "at once", "variants", "total s", "variants/s", "first result s", "steady variants/s",
           "task s (median)", "wall_s (median)", "busy"]


class Recording:
    """A backend that records each outcome's latency (dispatch to arrival) as it passes through."""

    def __init__(self, backend):
        self.backend = backend
        self.description, self.timing_note, self.parallel = backend.description, backend.timing_note, backend.parallel
        self.latency: dict = {}
        self.arrival: list[float] = []

    def run(self, fn, items):
        for outcome in self.backend.run(fn, items):
            self.latency[outcome.key] = outcome.latency
            self.arrival.append(time.perf_counter())
            yield outcome


def measure(name: str, make, sweep_file: Path, root: Path) -> dict:
    t0 = time.perf_counter()
    backend = make()
    recording = Recording(backend)
    try:
        result = run_sweep(load_sweep(sweep_file, root / name.replace(" ", "_")), recording, resume=False,
                           progress=False)  # the summary rewritten at most once a second, as for the command
    finally:
        backend.close()
    total = time.perf_counter() - t0
    rows = result.rows
    bad = [r for r in rows if r["status"] != "ok"]
    if bad:
        raise RuntimeError(f"{name}: {len(bad)} variants failed: {bad[0].get('error')}")
    task = [r["task_s"] for r in rows]
    first, last = recording.arrival[0], recording.arrival[-1]
    steady = (len(rows) - 1) / (last - first) if len(rows) > 1 and last > first else float("nan")
    return {"backend": name, "at once": backend.parallel, "variants": len(rows), "total s": f"{total:.2f}",
            "variants/s": f"{len(rows) / total:.2f}", "first result s": f"{first - t0:.2f}",
            "steady variants/s": f"{steady:.2f}", "task s (median)": f"{statistics.median(task):.4f}",
            "wall_s (median)": f"{statistics.median(r['wall_s'] for r in rows):.4f}",
            "busy": f"{sum(task) / (backend.parallel * total):.0%}"}


def _noop(payload, slot=None):
    return payload


def noop_pool(n: int) -> float:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from warp_verlet.apps.sweep_backends import _package_of, _worker_init  # as LocalBackend starts its workers

    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                             initargs=(_package_of(_noop),)) as pool:
        pool.submit(_noop, 0).result()  # start the worker
        times = []
        for i in range(n):
            t = time.perf_counter()
            pool.submit(_noop, i).result()
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def noop_ray(n: int) -> tuple[float, float]:
    """Median sequential round trip, and tasks per second for n no-op tasks submitted at once."""
    import ray

    f = ray.remote(num_cpus=1)(_noop)
    ray.get(f.remote(0))  # start a worker
    times = []
    for i in range(n):
        t = time.perf_counter()
        ray.get(f.remote(i))
        times.append(time.perf_counter() - t)
    t = time.perf_counter()
    ray.get([f.remote(i) for i in range(n)])
    return statistics.median(times), n / (time.perf_counter() - t)


def _case(text: str) -> tuple[int, int]:
    size, frames = text.lower().split("x")
    return int(size), int(frames)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = arg_parser("bench.sweep_throughput", __doc__)
    p.add_argument("--cases", type=_case, nargs="+", default=[(24, 30), (64, 60)], metavar="NxF",
                   help="cloth N x N, F frames (default: 24x30 and 64x60)")
    p.add_argument("--variants", type=int, default=24)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="local pool sizes to measure")
    p.add_argument("--ray-cpus", type=int, default=None, help="num_cpus of the local Ray instance (default: the cores)")
    p.add_argument("--no-ray", action="store_true")
    p.add_argument("--noop", type=int, default=200, help="bare round trips per backend")
    p.add_argument("--out", type=Path, default=HERE / "results" / "sweep")
    p.add_argument("--stem", default="cpu-2core")
    args = p.parse_args(argv)
    quiet_warp()
    load_start = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    tables, csv_rows = [], []
    ray = None
    if not args.no_ray:
        import logging

        import ray

        t0 = time.perf_counter()
        ray.init(num_cpus=args.ray_cpus or cores, include_dashboard=False, logging_level=logging.WARNING,
                 log_to_driver=False)
        init_s = time.perf_counter() - t0
    try:
        for size, frames in args.cases:
            rows = []
            with tempfile.TemporaryDirectory(prefix="sweep-throughput-") as tmp:
                root = Path(tmp)
                (root / "base.toml").write_text(SCENE.format(frames=frames, size=size))
                sweep_file = root / "sweep.toml"
                sweep_file.write_text(SWEEP.format(variants=args.variants))
                # Warm this process (kernels loaded) first, so that the inline row times its steady state.
                run_sweep(load_sweep(sweep_file, root / "warm"), InlineBackend("cpu", 1), resume=False, progress=False)
                rows.append(measure("inline (this process)", lambda: InlineBackend("cpu", 1), sweep_file, root))
                for n in args.workers:
                    rows.append(measure(f"local pool, {n} worker(s)",
                                        lambda n=n: LocalBackend([Slot("cpu", 1)] * n), sweep_file, root))
                if ray is not None:
                    rows.append(measure("Ray, local instance", lambda: RayBackend(device="cpu", threads=1),
                                        sweep_file, root))
            title = (f"{args.variants} variants of a {size} x {size} hanging cloth, {frames} frames at 4 substeps x "
                     "4 sweeps, one relaxation thread each")
            tables += [f"### {title}", "", markdown_table(rows, COLUMNS), ""]
            csv_rows += [{"case": f"{size}x{frames}", **r} for r in rows]
            print("\n".join(tables[-4:]), flush=True)
        noop = [{"round trip": "ProcessPoolExecutor (spawn), 1 worker", "median s": f"{noop_pool(args.noop):.6f}",
                 "tasks/s, all at once": ""}]
        if ray is not None:
            median, rate = noop_ray(args.noop)
            noop.append({"round trip": f"Ray {ray.__version__}, num_cpus = 1", "median s": f"{median:.6f}",
                         "tasks/s, all at once": f"{rate:.0f}"})
    finally:
        if ray is not None:
            ray.shutdown()
    m = machine("cpu")
    command = ["bench.sweep_throughput", *argv]
    lines = [f"# Sweep throughput: {m}", "", *m.lines(command), f"- load average at the start: {load_start} (on "
             f"{cores} cores: above {cores} means other work competed for them, and parallel rows gain less)", "",
             f"Every backend runs the whole sweep from scratch on this {cores}-core machine; the local pool and Ray "
             "each run at most one variant per core. Columns: `python -m bench.sweep_throughput --help`."
             + (f" Ray: a local instance (`ray.init(num_cpus={args.ray_cpus or cores})`, {init_s:.1f} s, not in "
                "the totals), one task per variant with num_cpus = 1." if ray is not None else ""), "",
             *tables,
             f"### Bare round trips ({args.noop} sequential submit-and-wait calls of a function that returns at once)",
             "", markdown_table(noop, ["round trip", "median s", "tasks/s, all at once"]), ""]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.stem}.md").write_text("\n".join(lines))
    write_csv(args.out / f"{args.stem}.csv", csv_rows, ["case", *COLUMNS])
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
