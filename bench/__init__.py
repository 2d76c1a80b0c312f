"""The benchmark scripts, one module each, run from the repository root as ``python -m bench.NAME``:
work_precision, throughput, cpu_reference, thread_scaling, numpy_baseline, integrators, overlap, parity,
stability and newton_peer (``--help`` on each says what it measures). ``bench.common`` holds what they
share (scenes, timing, the machine description, tables, and the one way into a simulator's state);
``bench.stability_cases`` the stability cases, by category.

``python -m`` puts the current directory first on ``sys.path``, so from a checkout ``warp_verlet`` is the
checkout's own source tree. That tree keeps its kernels in ``kernels/``, which only an install maps to
``warp_verlet.kernels``: an editable one (``pip install -e .``) maps it to the checkout itself, a plain
``pip install .`` does not, and every script would then stop at its first kernel import. Say so at once.
"""

import importlib.util

try:
    _kernels = importlib.util.find_spec("warp_verlet.kernels")
except ModuleNotFoundError:  # no warp_verlet at all: the scripts' own imports say so
    _kernels = True
if _kernels is None:
    raise ImportError("bench runs the checkout's warp_verlet (python -m puts the current directory first on "
                      "sys.path), and a source checkout has warp_verlet.kernels only when installed editable: run "
                      "`pip install -e .` in the checkout")
del _kernels
