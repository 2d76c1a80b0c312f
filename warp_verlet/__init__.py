"""warp-verlet: cloth simulation with Verlet integration and graph-coloured constraint relaxation,
run as NVIDIA Warp kernels on the CPU or a CUDA GPU, written to USD point caches.

Heavy modules (warp, pxr, trimesh) are imported lazily, where they are used, so that
``import warp_verlet`` and ``warp-verlet validate`` stay fast.
"""



def _map_checkout_kernels() -> None:
    """Map a source checkout's ``kernels/`` to ``warp_verlet.kernels``, as an install does.

    An install (plain or editable) maps the top-level ``kernels/`` folder to ``warp_verlet.kernels``. When
    ``warp_verlet`` is instead imported straight from a checkout (the checkout on ``sys.path``: ``python -m``
    run there, or Ray workers started in it), that mapping is missing and the first kernel import fails. So,
    only when nothing else provides ``warp_verlet.kernels`` and this package sits beside a ``kernels/``
    folder, the same mapping is made here. No module named ``kernels`` is ever made importable."""
    import importlib.util
    import sys
    from pathlib import Path

    folder = Path(__file__).resolve().parent.parent / "kernels"
    if f"{__name__}.kernels" in sys.modules or not (folder / "__init__.py").is_file():
        return
    if importlib.util.find_spec(f"{__name__}.kernels") is not None:  # an install's mapping
        return
    spec = importlib.util.spec_from_file_location(f"{__name__}.kernels", folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)


_map_checkout_kernels()

from .errors import (ArgumentError, DiskFullError, DivergenceError, OutputBusyError,  # noqa: E402
                     OutputError, SceneError, StateError, WarpVerletError)
from .input.scene import Scene, load_scene, parse_scene  # noqa: E402
from .builder import SceneBuilder  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ArgumentError", "DiskFullError", "DivergenceError", "OutputBusyError", "OutputError", "Scene", "SceneBuilder",
    "SceneError", "Simulator", "StateError", "WarpVerletError", "load_scene", "parse_scene", "__version__",
]


def __getattr__(name):
    if name == "Simulator":  # imports warp: keep it off the import path of validate/--help
        from .core.simulator import Simulator

        return Simulator
    raise AttributeError(name)
