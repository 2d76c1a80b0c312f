"""warp-verlet: cloth simulation with Verlet integration and graph-coloured constraint relaxation,
run as NVIDIA Warp kernels on the CPU or a CUDA GPU, written to USD point caches.

Heavy modules (warp, pxr, trimesh) are imported lazily, where they are used, so that
``import warp_verlet`` and ``warp-verlet validate`` stay fast.
"""

from .errors import (ArgumentError, DiskFullError, DivergenceError, OutputBusyError, OutputError, SceneError,
                     StateError, WarpVerletError)
from .scene import Scene, load_scene, parse_scene

__version__ = "0.1.0"

__all__ = [
    "ArgumentError", "DiskFullError", "DivergenceError", "OutputBusyError", "OutputError", "Scene", "SceneError",
    "Simulator", "StateError", "WarpVerletError", "load_scene", "parse_scene", "__version__",
]


def __getattr__(name):
    if name == "Simulator":  # imports warp: keep it off the import path of validate/--help
        from .simulator import Simulator

        return Simulator
    raise AttributeError(name)
