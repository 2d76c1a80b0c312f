"""How much memory a scene needs, known from its counts before anything is allocated.

The simulator checks the estimate against what the device and the host have free and refuses a scene that
cannot fit with one clear error, instead of failing half-way through allocation (or swapping the machine to
a halt). ``warp-verlet validate`` prints it. This module imports neither warp nor pxr.

The device figure is the sum of what the stages and constraint sets of the table (warp_verlet/core/stages.py)
declare for the scene, the same declarations the solver binds its launches from; the host figure is the
peak of the numpy temporaries that building a grid's sticks takes, per stick, measured with tracemalloc and
rounded up (bench/results/code_choices.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import WarpVerletError
from ..machine import gib
from ..input.scene import Scene
from ..geometry.topology import stick_count  # noqa: F401 (the count before building; memory's callers ask here)

HOST_BUILD_BYTES_PER_STICK = 160


@dataclass(frozen=True)
class MemoryNeed:
    particles: int
    sticks: int
    device_bytes: int  # the simulator's arrays, on the device it runs on
    host_bytes: int  # peak host memory while the sticks are built
    precision: str = "float32"  # the positions' float type ("auto" resolved), which sets their bytes

    def describe(self) -> str:
        return f"about {gib(self.device_bytes)} of device arrays and {gib(self.host_bytes)} of host memory to build them"


def estimate(scene: Scene, sticks: str = "auto", requirements=None) -> MemoryNeed:
    """``sticks``: the sticks' form the simulator is asked for ("auto", "explicit", "implicit");
    ``requirements``: the scene's stages.Requirements for that form where the caller has them already."""
    from .stages import Requirements, device_bytes

    req = requirements if requirements is not None else Requirements.of(scene, sticks)
    return MemoryNeed(
        particles=req.particles,
        sticks=req.sticks,
        device_bytes=device_bytes(req),
        host_bytes=req.sticks * HOST_BUILD_BYTES_PER_STICK + req.particles * 64,
        precision=req.precision,
    )


def check_fits(scene: Scene, device_name: str, device_free: int | None, host_free: int | None,
               sticks: str = "auto", requirements=None) -> MemoryNeed:
    """Raise one clear error when the scene cannot fit; ``device_free`` None means the device is the host."""
    req = estimate(scene, sticks, requirements)
    host_need = req.host_bytes + (req.device_bytes if device_free is None else 0)
    what = f"{scene.source}: {req.particles:,} particles and {req.sticks:,} sticks need {req.describe()}"
    if device_free is not None and req.device_bytes > device_free:
        raise WarpVerletError(f"{what}, but {device_name} has only {gib(device_free)} free; "
                              "lower the resolution or run on a larger device")
    if host_free is not None and host_need > host_free:
        raise WarpVerletError(f"{what}, but this machine has only {gib(host_free)} of memory available; "
                              "lower the resolution or run on a larger machine")
    return req
