"""kernels/ installs as warp_verlet.kernels, and no top-level module named "kernels" is importable."""

import subprocess
import sys

PROBE = (
    "import importlib.util, warp_verlet.kernels.relax as r; "
    "print(importlib.util.find_spec('kernels')); print(r.__name__)"
)


def test_kernels_install_under_the_package_only(tmp_path):
    # Run from an empty directory so that the repository's own kernels/ folder is not on sys.path.
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=tmp_path, capture_output=True, text=True, check=True)
    spec, name = out.stdout.split()[-2:]  # Warp may print its banner first
    assert spec == "None"
    assert name == "warp_verlet.kernels.relax"
