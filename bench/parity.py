"""CPU/CUDA parity and CUDA determinism on every shipped scene.

    python -m bench.parity --frames 30 --out bench/results/h100

Runs each scene on the CPU and on CUDA from the same start, and reports the largest and RMS difference in
particle position after the given frames, relative to the cloth's size; whether two CUDA runs of the
same scene are bit-identical; and, for scenes that tear, the torn-stick count on each device (a float
rounding difference can decide whether a stick on the edge of its threshold tears).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.input.scene import load_scene
from warp_verlet.core.simulator import Simulator

from .common import arg_parser, cloth_size, machine, quiet_warp, write_table

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def run(scene, device, frames):
    sim = Simulator(scene, device)
    for _ in range(frames):
        sim.step_frame()
    return sim.positions(), sim.torn_count()


def main(argv=None) -> int:
    p = arg_parser("bench.parity", __doc__)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--big-frames", type=int, default=3, help="frames for grids over 256^2 (slow on the CPU)")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    quiet_warp()
    if not wp.is_cuda_available():
        print("parity: no CUDA device, nothing to compare")
        return 0
    rows = []
    for path in sorted(SCENES.glob("*.toml")):
        scene = load_scene(path)
        frames = args.big_frames if scene.particle_count > 256 * 256 else args.frames
        (cpu, torn_cpu), (cuda, torn_cuda), (cuda2, _) = (run(scene, d, frames) for d in ("cpu", "cuda", "cuda"))
        extent = cloth_size(scene)  # metres
        diff = np.linalg.norm(cpu.astype(np.float64) - cuda, axis=1)
        rows.append({
            "scene": path.name, "particles": scene.particle_count, "frames": frames,
            "max |cpu - cuda| / size": f"{diff.max() / extent:.2e}",
            "rms |cpu - cuda| / size": f"{np.sqrt(np.mean(diff**2)) / extent:.2e}",
            "cuda runs bit-identical": bool(np.array_equal(cuda, cuda2)),
            "torn cpu / cuda": f"{torn_cpu} / {torn_cuda}" if scene.tears else "-",
        })
        print(rows[-1], flush=True)
    write_table(rows, args.out, "parity", f"CPU vs CUDA parity: {machine('cuda')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
