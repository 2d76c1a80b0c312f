"""Command line: ``warp-verlet run|validate`` (also ``python -m warp_verlet``).

Exit codes: 0 success, 1 a run failed (divergence, unwritable output, device), 2 invalid scene or
arguments, 130 interrupted (the cache holds the frames done).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import __version__
from .errors import SceneError, WarpVerletError
from .scene import load_scene


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of frames, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected at least 1 frame, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warp-verlet",
        description="Verlet cloth simulation on NVIDIA Warp (CPU or CUDA), written as a USD point cache.",
    )
    parser.add_argument("--version", action="version", version=f"warp-verlet {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = commands.add_parser("run", help="simulate a scene and write its USD point cache")
    run.add_argument("scene", type=Path, help="scene file (TOML, see docs/scenes.md)")
    run.add_argument("-o", "--output", type=Path, help="output .usd/.usdc/.usda (default: the scene's [output] path)")
    run.add_argument("--device", help="cpu, cuda or cuda:N (default: CUDA when present, else CPU)")
    run.add_argument("--frames", type=_positive_int, help="number of frames (default: the scene's)")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    run.add_argument("-v", "--verbose", action="store_true", help="show Warp's device and kernel-compilation messages")

    validate = commands.add_parser("validate", help="check a scene file without running it")
    validate.add_argument("scene", type=Path)
    return parser


def _validate(args) -> int:
    scene = load_scene(args.scene)
    sim = scene.simulation
    print(f"{args.scene}: valid scene, {len(scene.cloths)} cloth(s), {scene.particle_count} particles, "
          f"{sim.frames} frames at {sim.fps:g} fps, {sim.substeps} substeps x {sim.iterations} iterations, "
          f"solver {sim.solver}")
    return 0


def _run(args) -> int:
    scene = load_scene(args.scene)
    import warp as wp

    if not args.verbose:  # Warp's start-up banner and its per-module load timings
        wp.config.quiet = True
        wp.config.log_level = wp.LOG_WARNING
    from .runner import run_scene

    frames = args.frames or scene.simulation.frames
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=frames, unit="frame", desc=scene.cloths[0].name if len(scene.cloths) == 1 else "scene",
                   file=sys.stderr, dynamic_ncols=True)
    try:
        summary = run_scene(scene, output=args.output, device=args.device, frames=args.frames,
                            progress=(lambda frame: bar.update(1)) if bar else None)
    finally:
        if bar is not None:
            bar.close()
    print(summary.format())
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return _validate(args) if args.command == "validate" else _run(args)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except WarpVerletError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted: the cache holds the frames simulated so far", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
