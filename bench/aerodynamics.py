"""What air costs, and how a flag flutters in it.

Cost: the benchmark cloth (bench.common.hanging_sheet: n x n, 1 m, pinned at its top corners, all three stick
families, 4 substeps x 8 sweeps) per frame without and with ``[simulation.air]`` (a 5 m/s stream with gusts:
the face kernel with its clock, and the gather in the Verlet step): batches of frames, alternated between the two
so that both see the same load, after a warm-up frame each; the median batch and the best. On the CPU one thread (``--threads``), on CUDA a captured frame, as the simulator runs them.

Flutter (``--flutter``, the CPU): the flag of tests/test_aerodynamics.py (20 x 30 particles, 1.0 m x 0.6 m,
0.09 kg, nailed along its pole side, damping 2 /s) in a steady stream U, after a push of 1e-4 m/s out of its
plane: over the last 2 s of 6, its free edge's mid-height particle's motion across the stream: RMS,
peak-to-peak A, the spectrum's peak frequency f, and the Strouhal number St = f A / U, against the same flag
under the uniform ``wind`` acceleration.

    python -m bench.aerodynamics --threads 1 --sizes 64 --flutter --out bench/results
    python -m bench.aerodynamics --device cuda --sizes 256 1024 --out bench/results/h100-air
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.core.simulator import Simulator

from .common import arg_parser, hanging_sheet, machine, median_spread, quiet_warp, scene, time_frames, markdown_table

AIR = {"velocity": [5.0, 0.0, 2.0], "gust_speed": 1.0, "gust_length": 0.5, "gust_period": 0.5}
COST_COLUMNS = ["device", "cloth", "particles", "faces", "ms/frame without air", "ms/frame with air", "air ms/frame",
                "with / without", "spread"]
FLUTTER_COLUMNS = ["push", "U (m/s)", "substeps", "RMS across (m)", "A peak-to-peak (m)", "f (Hz)", "St = f A / U"]


def sheet(n: int, air: dict | None):
    simulation = {"substeps": 4, "iterations": 8, "damping": 0.24}
    if air is not None:
        simulation["air"] = air
    return scene(simulation, hanging_sheet(n), name=f"<air {n}x{n}>")


def cost_rows(sizes: list[int], device: str, threads: int | None, frames: int, repeats: int) -> list[dict]:
    """Per size, batches of ``frames`` frames without and with air, alternated so that both see the same load
    on a shared machine: the median and the best batch of each."""
    rows = []
    for n in sizes:
        plain = Simulator(sheet(n, None), device, threads=threads)
        aired = Simulator(sheet(n, AIR), device, threads=threads)
        times: dict[str, list[float]] = {"plain": [], "air": []}
        try:
            for name, sim in (("plain", plain), ("air", aired)):
                time_frames(sim, 1, 1)  # warm-up: binding, compiling, a CUDA graph's capture
            for _ in range(repeats):
                for name, sim in (("plain", plain), ("air", aired)):
                    times[name] += [1e3 * s for s in time_frames(sim, frames, 1)]
        finally:
            plain.close()
            aired.close()
        (without, spread_plain), (with_air, spread_air) = median_spread(times["plain"]), median_spread(times["air"])
        best_without, best_with = min(times["plain"]), min(times["air"])
        rows.append({"device": device, "cloth": f"{n} x {n}", "particles": n * n, "faces": (n - 1) ** 2,
                     "ms/frame without air": f"{without:.3f} (best {best_without:.3f})",
                     "ms/frame with air": f"{with_air:.3f} (best {best_with:.3f})",
                     "air ms/frame": f"{with_air - without:.3f} (best {best_with - best_without:.3f})",
                     "with / without": f"{with_air / without:.3f} (best {best_with / best_without:.3f})",
                     "spread": f"±{100 * max(spread_plain, spread_air):.1f}%"})
    return rows


STAGE_COLUMNS = ["device", "cloth", "stage", "µs/substep without air", "µs/substep with air",
                 "µs/substep with steady air (no gusts, no clock)"]
STEADY_AIR = {"velocity": AIR["velocity"]}


def stage_rows(sizes: list[int], device: str, threads: int | None, runs: int = 100, repeats: int = 15) -> list[dict]:
    """Each stage of one substep on its own (the solver's bound stages, run ``runs`` times against the state of a
    frame already stepped), the best of ``repeats``: the air's own cost, out of the frame's noise."""
    rows = []
    for n in sizes:
        timings: dict[str, dict[str, float]] = {}
        for label, air in (("without", None), ("with", AIR), ("steady", STEADY_AIR)):
            sim = Simulator(sheet(n, air), device, threads=threads)
            sim.step_frame()
            dt = sim.settings.dt
            for name, run in sim.solver.bind(sim.state):
                best = math.inf
                for _ in range(repeats):
                    wp.synchronize_device(sim.device)
                    start = time.perf_counter()
                    for _ in range(runs):
                        run(sim.state, dt)
                    wp.synchronize_device(sim.device)
                    best = min(best, (time.perf_counter() - start) / runs)
                timings.setdefault(name, {})[label] = 1e6 * best
            sim.close()
        for name in sorted(timings, key=lambda name: list(timings).index(name) if name != "air" else -1):
            t = timings[name]
            rows.append({"device": device, "cloth": f"{n} x {n}", "stage": name,
                         "µs/substep without air": f"{t['without']:.0f}" if "without" in t else "–",
                         "µs/substep with air": f"{t['with']:.0f}" if "with" in t else "–",
                         "µs/substep with steady air (no gusts, no clock)": f"{t['steady']:.0f}" if "steady" in t
                         else "–"})
    return rows


FLAG = {"name": "flag", "resolution": [20, 30], "size": [0.6, 1.0], "origin": [0.0, 2.0, 0.0], "mass": 0.09,
        "pins": ["left-edge"], "sticks": ["structural", "shear", "bend"], "compliance": {"bend": 1.0}}


def flutter(push: dict, substeps: int, seconds: float = 6.0, frames_kept: int = 120) -> dict:
    """The flag's free-edge motion across the stream (z) over its last ``frames_kept`` frames, under ``push``
    ({"air": ...} or {"wind": ...})."""
    rows, cols = FLAG["resolution"]
    sim = Simulator(scene({"substeps": substeps, "iterations": 4, "damping": 2.0, **push}, FLAG), "cpu")
    kick = np.zeros((rows * cols, 3))
    kick[:, 2] = 1e-4 * np.random.default_rng(1).standard_normal(rows * cols)
    sim.state.set_velocity(kick)
    across = []
    for _ in range(int(seconds * 60)):
        sim.step_frame()
        across.append(float(sim.positions()[(rows // 2) * cols + cols - 1, 2]))
    sim.close()
    z = np.array(across[-frames_kept:])
    spectrum = np.abs(np.fft.rfft(z - z.mean()))
    f = float(np.fft.rfftfreq(len(z), 1.0 / 60.0)[spectrum.argmax()])
    return {"rms": float(z.std()), "A": float(np.ptp(z)), "f": f}


def flutter_rows(speeds: list[float], substeps_list: list[int]) -> list[dict]:
    rows = []
    for substeps in substeps_list:
        for speed in speeds:
            m = flutter({"air": {"velocity": [speed, 0.0, 0.0]}}, substeps)
            rows.append({"push": "air", "U (m/s)": f"{speed:g}", "substeps": substeps, "RMS across (m)": f"{m['rms']:.4f}",
                         "A peak-to-peak (m)": f"{m['A']:.3f}", "f (Hz)": f"{m['f']:.1f}",
                         "St = f A / U": f"{m['f'] * m['A'] / speed:.2f}"})
        m = flutter({"wind": [0.8 * 9.81, 0.0, 0.0]}, substeps)
        rows.append({"push": "uniform wind 0.8 g", "U (m/s)": "–", "substeps": substeps,
                     "RMS across (m)": f"{m['rms']:.4f}", "A peak-to-peak (m)": f"{m['A']:.4f}", "f (Hz)": f"{m['f']:.1f}",
                     "St = f A / U": "–"})
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = arg_parser("bench.aerodynamics", __doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default cpu)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64], help="cloth sides n (n x n particles)")
    parser.add_argument("--threads", type=int, default=None, help="CPU relaxation threads (default: chosen)")
    parser.add_argument("--frames", type=int, default=30, help="frames per timed batch")
    parser.add_argument("--repeats", type=int, default=5, help="timed batches; the median is reported")
    parser.add_argument("--flutter", action="store_true", help="also the flag's flutter table (CPU, about a minute)")
    parser.add_argument("--speeds", type=float, nargs="+", default=[5.0, 10.0, 20.0], help="flutter streams, m/s")
    parser.add_argument("--out", type=Path, help="folder for aerodynamics.md")
    args = parser.parse_args(argv)
    quiet_warp()
    wp.init()
    sections = [
        "### Air: frame time without and with `[simulation.air]`", "", *machine(args.device).lines(["bench.aerodynamics", *argv]),
        "", f"The benchmark cloth, 4 substeps x 8 sweeps, air {AIR}; median (and best) of {args.repeats} batches "
        f"of {args.frames} frames each, alternated without / with air; spread: half the range of the batches.", "",
        markdown_table(cost_rows(args.sizes, args.device, args.threads, args.frames, args.repeats), COST_COLUMNS),
        "", "Each stage of a substep on its own, best of 15 x 100 runs (\"air\" is the face kernel with its clock; "
        "\"integrate\" with air gathers each particle's faces):", "",
        markdown_table(stage_rows(args.sizes, args.device, args.threads), STAGE_COLUMNS)]
    if args.flutter:
        sections += ["", "### A flag in a steady stream (CPU)", "",
                     "Motion across the stream of the free edge's mid-height particle over the last 2 s of 6.", "",
                     markdown_table(flutter_rows(args.speeds, [8, 16]), FLUTTER_COLUMNS)]
    text = "\n".join(sections) + "\n"
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "aerodynamics.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
