"""GPU time per kernel of one frame (Warp's CUDA activity timing), launched kernel by kernel (no graph).

    python -m bench.kernel_times --device cuda --size 1024 --budget 4x8
    python -m bench.kernel_times --device cuda --scene folded_drop --size 1024 --budget 32x1
    python -m bench.kernel_times --device cuda --scene drape_global --size 1024 --budget 32x1

Scenes (``--scene``):
- **hanging** (default): the benchmark's hanging sheet with tethers (bench.implicit_grid), after two warm-up
  frames, once per sticks' form: stick arrays against implicit grid sticks, a launch per colour or tiled;
- **folded_drop**: bench.self_contact's folded cloth dropped on the ground with self-collision, timed at frame 15,
  when its layers are in contact;
- **drape_global**: bench.convergence's drape with the global correction (``global_iterations = 3``), timed at
  frame 26, when the cloth lies on the ball.

Prints each kernel's total GPU time in the frame, its launches, and the frame's sum; the two contact scenes count
memory copies and sets too. The CPU has no activity timing: there the tables are empty.
"""

from __future__ import annotations

import sys
from collections import defaultdict

import warp as wp

from warp_verlet.core.simulator import Simulator

from .common import arg_parser, quiet_warp
from .implicit_grid import sheet

SCENES = ("hanging", "folded_drop", "drape_global")


def frame_times(sim: Simulator, warm_frames: int, what=wp.TIMING_KERNEL):
    """Each kernel's (ms, launches) over frame ``warm_frames + 1``, and the frame's first 16 launches."""
    for _ in range(warm_frames):
        sim.step_frame()
    wp.synchronize_device(sim.device)
    wp.timing_begin(cuda_filter=what)
    sim.step_frame()
    results = wp.timing_end()
    total: dict[str, list] = defaultdict(lambda: [0.0, 0])
    for r in results:
        name = r.name.split("(")[0].replace("forward kernel ", "")
        total[name][0] += r.elapsed
        total[name][1] += 1
    first = [(r.name.split("(")[0].replace("forward kernel ", ""), r.elapsed) for r in results[:16]]
    return {k: (v[0], v[1]) for k, v in total.items()}, first


def kernel_times(size: int, substeps: int, iterations: int, device: str, sticks: str):
    """The hanging sheet's kernels in its third frame."""
    return frame_times(Simulator(sheet(size, substeps, iterations), device, use_graph=False, sticks=sticks), 2)


def contact_scene(scene: str, size: int, substeps: int, iterations: int, device: str) -> tuple[Simulator, int]:
    """A contact scene's simulator, stepped launch by launch, and the frames to run before the timed one."""
    if scene == "folded_drop":
        from warp_verlet.constraints.self_contact import DEFAULT_FRACTION

        from .self_contact import SIZE, folded, folded_scene

        sim = Simulator(folded_scene(size, True, 20, substeps, iterations), device, use_graph=False)
        spacing = SIZE / (size - 1)
        sim.state.set_positions(folded(sim.model.rest_positions, spacing, DEFAULT_FRACTION * spacing))
        return sim, 14
    from .convergence import build_scene

    return Simulator(build_scene("drape", size, "global3", substeps, iterations), device, use_graph=False), 25


def print_times(label: str, times: dict, first=None) -> None:
    print(f"{label}: {sum(t for t, _ in times.values()):.3f} ms of GPU work in the frame")
    for name, (ms, n) in sorted(times.items(), key=lambda kv: -kv[1][0]):
        print(f"  {name:60s} {ms:8.3f} ms  {n:5d} launches  {ms / n * 1e3:8.1f} us each")
    if first is not None:
        print("  the first launches, in order: " + ", ".join(f"{n} {t * 1e3:.0f} us" for n, t in first))


def main(argv=None) -> int:
    p = arg_parser("bench.kernel_times", __doc__)
    p.add_argument("--device", default="cuda")
    p.add_argument("--scene", choices=SCENES, default="hanging")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--budget", default="4x8")
    p.add_argument("--block-dims", type=int, nargs="*", default=[],
                   help="hanging: also time the implicit sticks ('auto') with these threads per block "
                        "(sticks.GRID_BLOCK_DIM)")
    args = p.parse_args(argv)
    quiet_warp()
    substeps, iterations = (int(v) for v in args.budget.split("x"))
    if args.scene != "hanging":
        sim, warm = contact_scene(args.scene, args.size, substeps, iterations, args.device)
        times, _ = frame_times(sim, warm, wp.TIMING_ALL)
        print_times(f"{args.size}^2 {args.scene} {args.budget}, frame {warm + 1}", times)
        return 0
    from warp_verlet.constraints import sticks

    chosen = sticks.GRID_BLOCK_DIM
    for block in args.block_dims:
        sticks.GRID_BLOCK_DIM = block
        times, _ = kernel_times(args.size, substeps, iterations, args.device, "auto")
        colour = [k for k in times if k.startswith("relax_grid_colour")]
        if colour:  # CUDA only: the CPU has no activity timing
            ms, n = times[colour[0]]
            print(f"{args.size}^2 {args.budget} auto, {block} threads per block: a colour {ms / n * 1e3:.1f} us")
    sticks.GRID_BLOCK_DIM = chosen  # the table below is of the block size the simulator uses
    for form in ("explicit", "auto", "implicit", "tiled"):
        times, first = kernel_times(args.size, substeps, iterations, args.device, form)
        print_times(f"{args.size}^2 {args.budget} {form}", times, first)
    return 0


if __name__ == "__main__":
    sys.exit(main())
