"""Parameter sweeps: a sweep file names a base scene and the scene keys to vary; every combination is a variant.

    [sweep]
    scene = "../wind_sheet.toml"          # the base scene, relative to this file
    frames = 60                           # optional: every variant's simulation.frames

    [axes]                                # the grid: every combination of these values
    "simulation.substeps" = [8, 16, 32]

The package is split by job:

* ``sweep_file.py``: the language. Reading a sweep file, its axes (grids, ranges, random draws), and every
  variant's Scene, validated by ``scene.parse_scene`` before anything runs (``load_sweep``, ``parse_sweep``).
* ``running.py``: running with resume (``run_sweep``). The output directory's lock, the variants an earlier
  run finished (sidecars, cache digests, ``cache_problems``), each variant's run on a backend
  (``sweep_backends.py``: this process, a process pool, Ray tasks) and what a failure or Ctrl-C leaves.
* ``summary.py``: ``sweep.csv`` and ``sweep.md``, one row per variant.

The names below are the package's public ones, importable from ``warp_verlet.apps.sweep`` as before the split.
"""

from .running import (MAX_SIDECAR_BYTES, SWEEP_LOCK_NAME, SweepResult, cache_path, cache_problems, done_row,
                      file_sha256, run_sweep, run_variant)
from .summary import COLUMNS_AFTER, COLUMNS_BEFORE, STATUSES, summary_columns
from .sweep_file import (DEFAULT_FORMAT, DISTRIBUTIONS, MAX_RANGE, MAX_VARIANTS, RANGE_KEYS, Axis, Sweep, Variant,
                         draws, formats, load_sweep, parameter_hash, parse_sweep, read_toml, set_at, short_names, show,
                         variant_name)

__all__ = [
    "COLUMNS_AFTER", "COLUMNS_BEFORE", "DEFAULT_FORMAT", "DISTRIBUTIONS", "MAX_RANGE", "MAX_SIDECAR_BYTES",
    "MAX_VARIANTS", "RANGE_KEYS", "STATUSES", "SWEEP_LOCK_NAME", "Axis", "Sweep", "SweepResult", "Variant",
    "cache_path", "cache_problems", "done_row", "draws", "file_sha256", "formats", "load_sweep", "parameter_hash",
    "parse_sweep", "read_toml", "run_sweep", "run_variant", "set_at", "short_names", "show", "summary_columns",
    "variant_name",
]
