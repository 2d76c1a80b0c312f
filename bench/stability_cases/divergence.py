"""Divergence: run_scene stops at the predicted frame, names the particle, and leaves a valid cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from warp_verlet.errors import DivergenceError

from .base import Check, count_check, scene


def divergence(device: str = "cpu", size: str = "test", out_dir: Path | None = None) -> list[Check]:
    """A cloth with no relaxation (iterations = 0) under 1000 m/s^2 with position_bound = 20 m: its free
    particles fall exactly (x0 + a t^2 / 2), so the frame where one first passes 20 m and the lowest such
    particle index are known in advance. run_scene must stop there with DivergenceError naming the frame,
    the cloth and the particle, leave a valid partial cache (diverges.partial.usdc) holding frames
    0 .. frame - 1, and write nothing at the output path."""
    import tempfile

    from pxr import Usd, UsdGeom

    from warp_verlet.apps.runner import run_scene
    from warp_verlet.output.usd_writer import validate_cache

    case = "divergence: run_scene end to end"
    bound, g, fps = 20.0, 1000.0, 60
    sc = scene({"fps": fps, "frames": 60, "iterations": 0, "gravity": [0.0, -g, 0.0], "position_bound": bound},
               [{"name": "calm", "resolution": [2, 2], "size": [0.1, 0.1], "origin": [5.0, 0.0, 0.0],
                 "pins": ["top-edge", "bottom-edge"]},
                {"name": "net", "resolution": [4, 4], "size": [1.0, 1.0], "pins": ["top-edge"]}])
    y0 = np.concatenate([np.zeros(4), -np.repeat(np.arange(4) / 3.0, 4)])  # calm first, then net rows
    free = np.r_[np.zeros(4, bool), np.arange(16) >= 4]
    frame = next(f for f in range(1, 61) if np.any(free & (np.abs(y0 - 0.5 * g * (f / fps) ** 2) > bound)))
    y = y0 - 0.5 * g * (frame / fps) ** 2
    beyond = free & (np.abs(y) > bound)
    particle = int(np.flatnonzero(beyond)[0]) - 4
    assert np.min(np.abs(np.abs(y[free]) - bound)) > 0.1, "the prediction must not be borderline"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(out_dir or tmp) / "diverges.usdc"
        try:
            run_scene(sc, output=out, device=device)
            err = None
        except DivergenceError as exc:
            err = exc
        partial = out.with_name(f"{out.stem}.partial{out.suffix}")  # a failed run's frames (output_file.py)
        samples, problems, written = [], ["no cache"], out.exists()
        if partial.exists():
            stage = Usd.Stage.Open(str(partial))
            samples = list(UsdGeom.Mesh.Get(stage, "/World/net").GetPointsAttr().GetTimeSamples())
            problems = validate_cache(partial)
            del stage
    message = str(err) if err else "no DivergenceError"
    named = (err is not None and err.frame == frame and err.cloth == "net" and err.particle == particle
             and f"frame {frame}: cloth 'net' particle {particle}" in message and "beyond position_bound" in message)
    return [
        count_check(case, "DivergenceError names the predicted frame, cloth and particle", int(not named),
                    f"predicted frame {frame}, particle {particle}; got: {message}"),
        count_check(case, "cache time samples other than frames 0 .. frame - 1",
                    len(set(samples) ^ set(range(frame))), f"{len(samples)} samples"),
        count_check(case, "validate_cache problems", len(problems), "; ".join(problems)[:200]),
        count_check(case, "a file at the output path after the failed run", int(written), str(out.name)),
    ]
