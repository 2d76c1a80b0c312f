"""kernels/ installs as warp_verlet.kernels, and no top-level module named "kernels" is importable."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

PROBE = (
    "import importlib.util, warp_verlet.kernels.relax as r; "
    "print(importlib.util.find_spec('kernels')); print(r.__name__)"
)


def test_kernels_install_under_the_package_only(tmp_path):
    # Run from an empty directory, and without the repository root on PYTHONPATH, so that only what was
    # installed is importable (the repository's own kernels/ folder would otherwise be found).
    paths = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != REPO]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(paths))
    installed = subprocess.run([sys.executable, "-c", "import warp_verlet"], cwd=tmp_path, env=env, capture_output=True)
    if installed.returncode != 0:
        pytest.skip("warp_verlet is not installed here (only importable from the source tree)")
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
    spec, name = out.stdout.split()[-2:]  # Warp may print its banner first
    assert spec == "None"
    assert name == "warp_verlet.kernels.relax"


def test_a_source_checkout_maps_its_kernels_like_an_install(tmp_path):
    """Without site-packages (-S: no install, no editable finder) and with only the checkout on sys.path, as
    Ray's workers and `python -m` in the checkout see it: warp_verlet.kernels is the checkout's kernels/, and
    the mapping loads no top-level "kernels" module (the checkout's root on sys.path exposes its folders, so
    one could be imported by name there, but nothing here does)."""
    probe = ("import sys; sys.path.insert(0, sys.argv[1]); import warp_verlet.kernels as k; "
             "print(k.__file__, k.__name__, 'kernels' in sys.modules)")
    out = subprocess.run([sys.executable, "-S", "-c", probe, str(REPO)], cwd=tmp_path, capture_output=True, text=True,
                         check=True)
    kernels_file, name, top_level = out.stdout.split()[-3:]
    assert Path(kernels_file) == REPO / "kernels" / "__init__.py"
    assert (name, top_level) == ("warp_verlet.kernels", "False")
