"""Warp's CPU simulator against a single-threaded C reference and a plain numpy baseline, in one run.

    python -m bench.cpu_reference [--size 256] [--frames 10] [--repeats 3] [--out bench/results/cpu_reference]

The README's throughput setup (bench.throughput): an n x n, 1 m hanging cloth pinned at its top corners,
structural + shear + bend sticks, 4 substeps x 8 iterations at 60 fps. Each contender runs from the initial
state: ``--warm-up`` frames (Warp compiles its kernels there), then ``--repeats`` timed batches of ``--frames``
frames; the median batch gives ms/frame, and stick projections/s = sticks x substeps x iterations / (s/frame).

- warp coloured, 1 thread: the full simulator, ``Simulator(scene, "cpu", threads=1).step_frame()`` (coloured
  Gauss-Seidel, every stick's ends, rest length and weight read from arrays), the like-for-like peer of the
  single-threaded C.
- warp coloured, implicit grid sticks, 1 thread (with ``--implicit``): the same with ``sticks="implicit"``, each
  stick's ends and rest length computed from the grid (kernels/grid_relax.py); its positions must equal the
  stick arrays' run bit for bit.
- warp coloured, N threads: the same with the relaxation cut over N threads (``--threads N``; by default
  what the simulator picks by itself for this grid on this machine, and no such row when that is 1); its
  positions must equal the 1-thread run's bit for bit.
- warp jacobi, 1 and N threads: the same with ``relaxation = "jacobi"``, the like-for-like peer of numpy Jacobi.
- C: bench/c_reference/relax.c, compiled here with ``cc -O3 -march=native -shared -fPIC`` (``$CC`` if set) into
  a temporary directory and called through ctypes once per frame: Verlet plus Gauss-Seidel sweeps over the
  simulator's own sticks in its colour order, one thread. Skipped, with a message, if there is no compiler.
- numpy jacobi / numpy coloured: bench.numpy_baseline, fewer frames (``--numpy-frames``): it is slow.

Same-physics check: Warp coloured and C run the same number of frames from the same start, and the largest
particle distance between them is reported (and checked against ``--tolerance``, as a fraction of the cloth
size). Written: cpu_reference.csv and cpu_reference.md under ``--out``.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from warp_verlet.core.cpu_team import usable_cores
from warp_verlet.core.simulator import Simulator

from .common import arg_parser, cloth_size, hanging_cloth, machine, markdown_table, quiet_warp, time_frames, write_csv
from .numpy_baseline import NumpyCloth

HERE = Path(__file__).resolve().parent
C_SOURCE = HERE / "c_reference" / "relax.c"
C_FLAGS = ["-O3", "-march=native", "-shared", "-fPIC"]
_F32P = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_I32P = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")


# ---------------------------------------------------------------- the C reference

def find_compiler() -> str | None:
    for name in filter(None, [os.environ.get("CC"), "cc", "gcc", "clang"]):
        path = shutil.which(name)
        if path:
            return path
    return None


def build_c_reference(out_dir: str | Path) -> tuple[ctypes.CDLL, str] | None:
    """Compile relax.c into ``out_dir``; the loaded library and the compiler's version line, or None when
    no C compiler is found."""
    cc = find_compiler()
    if cc is None:
        return None
    lib_path = Path(out_dir) / "librelax.so"
    subprocess.run([cc, *C_FLAGS, str(C_SOURCE), "-o", str(lib_path), "-lm"], check=True)
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()
    lib = ctypes.CDLL(str(lib_path))
    lib.verlet_start.argtypes = [ctypes.c_int, _F32P, _F32P, _F32P, ctypes.c_float, _F32P, _F32P]
    lib.verlet_start.restype = None
    lib.step_frame.argtypes = [ctypes.c_int, _F32P, _F32P, _F32P, _F32P, ctypes.c_int, _I32P, _F32P, _F32P,
                               ctypes.c_int, ctypes.c_int, ctypes.c_float, _F32P]
    lib.step_frame.restype = None
    return lib, f"{Path(cc).name}: {version[0] if version else '?'} {' '.join(C_FLAGS)}"


class CCloth:
    """The C reference on the arrays of a coloured ``Simulator``'s model (sticks in device colour order)."""

    def __init__(self, lib: ctypes.CDLL, scene):
        if scene.colliders:
            raise ValueError("the C reference has no colliders")
        s = scene.simulation
        coloured = dataclasses.replace(scene, simulation=dataclasses.replace(s, relaxation="coloured"))
        m = Simulator(coloured, device="cpu", sticks="explicit").model  # the stick arrays the C code reads
        self.lib, self.n, self.stick_count = lib, m.particle_count, m.stick_count
        self.substeps, self.iterations = s.substeps, s.iterations
        self.x = np.ascontiguousarray(m.rest_positions, dtype=np.float32)
        self.inv_mass = np.ascontiguousarray(m.inv_mass.numpy(), dtype=np.float32)
        self.ends = np.ascontiguousarray(m.host_sticks, dtype=np.int32)
        self.rest = np.ascontiguousarray(m.host_rest, dtype=np.float32)
        if m.compliant:
            raise ValueError("the C reference has rigid sticks only (no compliance)")
        self.weight = np.ascontiguousarray(m.stick_weight.numpy(), dtype=np.float32)  # all 1: every stick holds
        accel = np.add(s.gravity, s.wind).astype(np.float32)
        # As the simulator: the acceleration rounded to float32, times dt (dt + dt_prev) / 2 in double, rounded.
        self.accel_offset = (accel.astype(np.float64) * (s.dt * s.dt)).astype(np.float32)
        # As the simulator: the velocity kept per fixed step, exp(-damping dt), rounded to float32.
        self.velocity_scale = float(np.float32(math.exp(-s.damping * s.dt)))
        self.x_inertial = np.empty_like(self.x)
        self.delta = np.empty_like(self.x)
        lib.verlet_start(self.n, self.x, self.inv_mass, accel, s.dt, self.x_inertial, self.delta)

    def step_frame(self) -> None:
        self.lib.step_frame(self.n, self.x, self.x_inertial, self.delta, self.inv_mass, self.stick_count, self.ends,
                            self.rest, self.weight, self.substeps, self.iterations, self.velocity_scale,
                            self.accel_offset)

    def positions(self) -> np.ndarray:
        return self.x.copy()


# ---------------------------------------------------------------- the contenders, timed

def run(size: int = 256, frames: int = 10, repeats: int = 3, warm_up: int = 2, numpy_frames: int = 2,
        substeps: int = 4, iterations: int = 8, with_c: bool = True, threads: int | None = None,
        implicit: bool = False, log=print) -> dict:
    """Measure every contender; returns {"rows": [...], "check": {...} or None, "compiler": str or None}."""
    scene = hanging_cloth(size, substeps, iterations)
    jacobi = hanging_cloth(size, substeps, iterations, "jacobi")
    rows, finals = [], {}

    def record(name, times, sticks, frames_run):
        per_frame = float(np.median(times))
        rows.append({"contender": name, "grid": f"{size}x{size}", "sticks": sticks, "substeps": substeps,
                     "iterations": iterations, "frames_timed": frames_run, "ms_per_frame": per_frame * 1e3,
                     "ms_min": min(times) * 1e3, "ms_max": max(times) * 1e3,
                     "Mproj_per_s": sticks * substeps * iterations / per_frame / 1e6})
        log(f"  {name:15s} {per_frame * 1e3:9.2f} ms/frame ({min(times) * 1e3:.2f}..{max(times) * 1e3:.2f}), "
            f"{rows[-1]['Mproj_per_s']:8.2f} M projections/s", flush=True)

    if threads is None:
        threads = Simulator(scene, device="cpu").threads  # the simulator's own choice for this grid here
    for solver, sc in (("coloured", scene), ("jacobi", jacobi)):
        for count in sorted({1, threads}):
            name = f"warp {solver}, {count} thread" + ("s" if count > 1 else "")
            sim = Simulator(sc, device="cpu", threads=count)
            times = time_frames(sim, frames, repeats, warm_up)
            record(name, times, sim.model.stick_count, frames * repeats)
            finals[name] = (sim, sim.positions())
    implicit_identical = None
    if implicit:
        name = "warp coloured, implicit grid sticks, 1 thread"
        sim = Simulator(scene, device="cpu", threads=1, sticks="implicit")
        record(name, time_frames(sim, frames, repeats, warm_up), sim.model.stick_count, frames * repeats)
        implicit_identical = np.array_equal(sim.positions(), finals["warp coloured, 1 thread"][1])
    threaded_identical = all(
        np.array_equal(finals[f"warp {solver}, 1 thread"][1], finals[f"warp {solver}, {threads} threads"][1])
        for solver in ("coloured", "jacobi")) if threads > 1 else None

    compiler = None
    with tempfile.TemporaryDirectory() as tmp:
        built = build_c_reference(tmp) if with_c else None
        if built is None:
            log("  C reference: " + ("no C compiler found (cc, gcc, clang; $CC): skipped" if with_c else "skipped"))
        else:
            lib, compiler = built
            c = CCloth(lib, scene)
            record("C (1 thread)", time_frames(c, frames, repeats, warm_up), c.stick_count, frames * repeats)
            finals["C (1 thread)"] = (None, c.positions())

    for name, solver in (("numpy jacobi", "jacobi"), ("numpy coloured", "coloured")):
        cloth = NumpyCloth.from_scene(scene, solver)
        record(name, time_frames(cloth, numpy_frames, repeats, warm_up=1), cloth.stick_count,
               numpy_frames * repeats)

    check = None
    if "C (1 thread)" in finals:
        sim, xw = finals["warp coloured, 1 thread"]
        xc = finals["C (1 thread)"][1]
        dist = np.linalg.norm(xw.astype(np.float64) - xc, axis=1)
        check = {"frames": warm_up + frames * repeats, "max_diff": float(dist.max()),
                 "rms_diff": float(np.sqrt(np.mean(dist**2))), "cloth_size": cloth_size(scene),
                 "stretch_rms_warp": sim.stretch(xw).rms, "stretch_rms_c": sim.stretch(xc).rms}
    return {"rows": rows, "check": check, "compiler": compiler, "threaded_identical": threaded_identical,
            "threads": threads, "implicit_identical": implicit_identical}


def ratios(rows: list[dict]) -> dict[str, float]:
    """Ratios of projection rates: C against Warp on the same single core, and Warp (on one core and on all
    of them) against the numpy baselines, which run on one core."""
    rate = {r["contender"]: r["Mproj_per_s"] for r in rows}
    warp = [name for name in rate if name.startswith("warp ")]
    out = {}
    if "C (1 thread)" in rate:
        out["C / warp coloured, 1 thread"] = rate["C (1 thread)"] / rate["warp coloured, 1 thread"]
        implicit = "warp coloured, implicit grid sticks, 1 thread"
        if implicit in rate:
            out[f"C / {implicit}"] = rate["C (1 thread)"] / rate[implicit]
    for name in warp:
        solver = "coloured" if "coloured" in name else "jacobi"
        out[f"{name} / numpy {solver}"] = rate[name] / rate[f"numpy {solver}"]
        if solver == "coloured":
            out[f"{name} / numpy jacobi"] = rate[name] / rate["numpy jacobi"]
    return out


def write(res: dict, out: Path, size: int, argv: list[str], tolerance: float) -> str:
    out.mkdir(parents=True, exist_ok=True)
    rows = res["rows"]
    write_csv(out / "cpu_reference.csv", rows)
    r0 = rows[0]
    shown = [{"contender": r["contender"], "sticks": f"{r['sticks']:,}", "frames timed": r["frames_timed"],
              "ms/frame (median)": f"{r['ms_per_frame']:.2f}", "min..max": f"{r['ms_min']:.2f}..{r['ms_max']:.2f}",
              "M projections/s": f"{r['Mproj_per_s']:.1f}"} for r in rows]
    lines = [f"# CPU reference: {size}x{size} hanging cloth, {r0['substeps']} substeps x {r0['iterations']} iterations",
             "", *machine("cpu").lines(argv), f"- C compiler: {res['compiler'] or 'none found: C skipped'}", "",
             markdown_table(shown), "",
             markdown_table([{"ratio of projection rates": k, "value": f"{v:.2f}"} for k, v in ratios(rows).items()])]
    c = res["check"]
    if c:
        verdict = "within" if c["max_diff"] <= tolerance * c["cloth_size"] else "NOT within"
        lines += ["", f"Same physics: after {c['frames']} frames from the same start, Warp coloured and C differ by "
                  f"at most {c['max_diff']:.2e} m (RMS {c['rms_diff']:.2e} m), {verdict} the tolerance "
                  f"{tolerance:g} x cloth size; RMS structural stretch Warp {c['stretch_rms_warp']:.4e}, "
                  f"C {c['stretch_rms_c']:.4e}."]
    if res.get("implicit_identical") is not None:
        lines += ["", "Implicit grid sticks: the run computing every stick from the grid ended bit-identical to the "
                  f"stick arrays' run: {'yes' if res['implicit_identical'] else 'NO'}."]
    if res["threaded_identical"] is not None:
        lines += ["", f"Threads: the {res['threads']}-thread runs ended bit-identical to the 1-thread runs: "
                  f"{'yes' if res['threaded_identical'] else 'NO'}."]
    text = "\n".join(lines) + "\n"
    (out / "cpu_reference.md").write_text(text)
    return text


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = arg_parser("bench.cpu_reference", __doc__)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--frames", type=int, default=10, help="frames per timed batch (Warp, C)")
    p.add_argument("--numpy-frames", type=int, default=2, help="frames per timed batch (numpy)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--warm-up", type=int, default=2)
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--no-c", action="store_true", help="skip the C reference")
    p.add_argument("--threads", type=int, default=None,
                   help="threads of the threaded Warp rows (default: the simulator's choice; usable cores here: "
                        f"{usable_cores()})")
    p.add_argument("--implicit", action="store_true",
                   help="also time the coloured simulator with implicit grid sticks (sticks='implicit')")
    p.add_argument("--tolerance", type=float, default=1e-4,
                   help="largest Warp-C particle distance accepted, as a fraction of the cloth size")
    p.add_argument("--out", type=Path, default=HERE / "results" / "cpu_reference")
    args = p.parse_args(argv)
    quiet_warp()
    print(f"{args.size}x{args.size} hanging cloth, {args.substeps} x {args.iterations}:", flush=True)
    res = run(args.size, args.frames, args.repeats, args.warm_up, args.numpy_frames, args.substeps, args.iterations,
              with_c=not args.no_c, threads=args.threads, implicit=args.implicit)
    print(write(res, args.out, args.size, ["bench.cpu_reference", *argv], args.tolerance))
    c = res["check"]
    if c and c["max_diff"] > args.tolerance * c["cloth_size"]:
        print("error: the C reference and Warp disagree beyond the tolerance", file=sys.stderr)
        return 1
    if res["implicit_identical"] is False:
        print("error: the implicit grid sticks' run differs from the stick arrays' run", file=sys.stderr)
        return 1
    if res["threaded_identical"] is False:
        print("error: the threaded Warp runs differ from the 1-thread runs", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
