"""Registers the repository's bench/ as the package ``bench``, so that the tests import its modules as
``from bench import throughput``, as ``python -m bench.throughput`` runs them.

Not by putting the repository root on sys.path (pytest's ``pythonpath = ["."]``): that would also put the
source tree's warp_verlet ahead of the installed one, and the source tree has no warp_verlet.kernels (kernels/
is mapped there only by an install), so under CI's non-editable install every test would fail to import.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "bench"

if "bench" not in sys.modules:
    _spec = importlib.util.spec_from_file_location("bench", BENCH / "__init__.py",
                                                   submodule_search_locations=[str(BENCH)])
    _module = importlib.util.module_from_spec(_spec)
    sys.modules["bench"] = _module
    _spec.loader.exec_module(_module)
