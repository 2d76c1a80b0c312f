"""Convergence at scale: stretch against time for plain relaxation, tethers and small steps, and the peer.

    python -m bench.convergence [--device cuda] [--sizes 256 1024 2048] [--out DIR] [--peer]

The two cloths of shared/notes/convergence.md, built the same way:

- **hanging**: 1 m square, 0.2 kg, vertical, pinned at its two top corners, structural + shear + bend sticks
  (rigid), damping 0.24 /s (the old drag 0.999 at 240 substeps/s), 60 fps, read at 1 s;
- **drape**: the same cloth flat, no pins, dropped from 0.5 m onto a 0.25 m sphere at the origin, ground at
  -0.5 m, read at 1.5 s.

For each method and budget (substeps S x sweeps K): ms/frame (mean of frames 2 .. N, the first frame
captures the graph), and the RMS and max structural stretch |D - L| / L at the end. With ``--peer``, Newton's
Style3D and VBD run the hanging cloth in the same process (skipped with a message when Newton is absent).
Results go to DIR/convergence.md and DIR/convergence.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.scene import parse_scene
from warp_verlet.simulator import Simulator

FPS = 60.0
DAMPING = 0.24  # 1/s


def hanging(n: int, substeps: int, iterations: int, tethers: bool) -> dict:
    return {"simulation": {"fps": FPS, "substeps": substeps, "iterations": iterations, "damping": DAMPING},
            "cloth": [{"name": "cloth", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 1.0, 0.0],
                       "mass": 0.2, "pins": ["top-left", "top-right"], "sticks": ["structural", "shear", "bend"],
                       "tethers": tethers}]}


def drape(n: int, substeps: int, iterations: int, tethers: bool = False) -> dict:
    return {"simulation": {"fps": FPS, "substeps": substeps, "iterations": iterations, "damping": DAMPING},
            "cloth": [{"name": "cloth", "resolution": [n, n], "size": [1.0, 1.0], "origin": [-0.5, 0.5, -0.5],
                       "orientation": "horizontal", "mass": 0.2, "sticks": ["structural", "shear", "bend"]}],
            "collider": [{"type": "sphere", "name": "ball", "radius": 0.25, "centre": [0.0, 0.0, 0.0]},
                         {"type": "plane", "name": "ground", "point": [0.0, -0.5, 0.0]}]}


SCENES = {"hanging": (hanging, 60), "drape": (drape, 90)}


def measure(kind: str, n: int, substeps: int, iterations: int, tethers: bool, device: str) -> dict:
    build, frames = SCENES[kind]
    scene = parse_scene(build(n, substeps, iterations, tethers), file=f"<{kind} {n}^2>")
    sim = Simulator(scene, device)
    sim.step_frame()
    wp.synchronize_device(sim.device)
    start = time.perf_counter()
    for _ in range(frames - 1):
        sim.step_frame()
    wp.synchronize_device(sim.device)
    per_frame = (time.perf_counter() - start) / (frames - 1)
    stretch = sim.stretch()
    low = float(sim.positions()[:, 1].min())
    sim.close()
    return {"scene": kind, "n": n, "method": "tethers" if tethers else "plain", "substeps": substeps,
            "iterations": iterations, "ms_per_frame": per_frame * 1e3, "rms": stretch.rms, "max": stretch.max,
            "lowest_y": low, "frames": frames}


def peer_rows(sizes: list[int], device: str) -> list[dict]:
    try:
        from bench import newton_style3d as peer
    except ImportError:
        print("peer: bench.newton_style3d is missing; skipped")
        return []
    if not peer.available():
        print("peer: Newton is not installed (pip install newton); skipped")
        return []
    rows = []
    for solver in ("style3d", "vbd"):
        for n in sizes:
            try:
                r = peer.run_peer(solver, n, frames=60, device=device)
            except Exception as exc:  # a peer failing must not lose our own rows
                print(f"peer {solver} {n}^2 failed: {exc}")
                continue
            rms, mx = peer.structural_stretch(r["positions"], n)
            rows.append({"scene": "hanging", "n": n, "method": f"newton-{solver}", "substeps": r["substeps"],
                         "iterations": r["iterations"], "ms_per_frame": r["ms_per_frame"], "rms": rms, "max": mx,
                         "setup_s": r["setup_s"], "first_frame_s": r["first_frame_s"], "frames": 60})
            print(_line(rows[-1]), flush=True)
    return rows


def _line(r: dict) -> str:
    return (f"{r['scene']:8s} {r['n']:5d}^2 {r['method']:15s} {r['substeps']:3d} x {r['iterations']:2d}  "
            f"{r['ms_per_frame']:9.2f} ms/frame  RMS {r['rms'] * 100:9.4f}%  max {r['max'] * 100:10.3f}%")


def plan(sizes: list[int]) -> list[tuple]:
    runs = []
    for n in sizes:
        runs.append(("hanging", n, 4, 8, False))
        for s, k in ((4, 8), (16, 2), (32, 1), (64, 1)):
            runs.append(("hanging", n, s, k, True))
    for n in sizes:
        if n >= 256:
            for s, k in ((4, 8), (32, 2), (64, 2)):
                runs.append(("drape", n, s, k, False))
    return runs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--drape-sizes", type=int, nargs="*", default=None,
                        help="grid sizes of the drape (default: the --sizes of 256 and up)")
    parser.add_argument("--peer", action="store_true", help="run Newton Style3D and VBD on the hanging cloth too")
    parser.add_argument("--peer-sizes", type=int, nargs="*", default=None)
    parser.add_argument("--out", type=Path, default=Path("bench/results/convergence"))
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    machine = (wp.get_cuda_device(device.ordinal).name if device.is_cuda else platform.processor() or platform.machine())
    rows = []
    runs = plan(args.sizes)
    if args.drape_sizes is not None:
        runs = [r for r in runs if r[0] == "hanging"] + [r for r in plan(args.drape_sizes) if r[0] == "drape"]
    for kind, n, s, k, tethers in runs:
        try:
            rows.append(measure(kind, n, s, k, tethers, str(device)))
        except Exception as exc:  # one refused budget (dt below the float32 limit) must not stop the table
            print(f"{kind} {n}^2 {s} x {k} tethers={tethers}: {exc}")
            continue
        print(_line(rows[-1]), flush=True)
    if args.peer:
        rows += peer_rows(args.peer_sizes or args.sizes, str(device))
    args.out.mkdir(parents=True, exist_ok=True)
    header = (f"Device: {machine} ({device}), warp {wp.__version__}, {time.strftime('%Y-%m-%d')}. "
              "ms/frame: mean of frames 2..N; stretch at the last frame (hanging 1 s, drape 1.5 s).\n\n")
    table = ["| scene | grid | method | S x K | ms/frame | RMS stretch | max stretch |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        table.append(f"| {r['scene']} | {r['n']}² | {r['method']} | {r['substeps']} × {r['iterations']} | "
                     f"{r['ms_per_frame']:.2f} | {r['rms'] * 100:.4f}% | {r['max'] * 100:.3f}% |")
    (args.out / "convergence.md").write_text(header + "\n".join(table) + "\n")
    (args.out / "convergence.json").write_text(json.dumps({"device": machine, "rows": rows}, indent=1))
    print(f"wrote {args.out / 'convergence.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
