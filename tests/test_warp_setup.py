"""How Warp is started (warp_verlet/core/warp_setup.py): its CUDA-driver warning on a run that asked for CUDA on a machine
without the driver. (The CPU run and the sweep's workers are tested in test_cli.py and test_sweep.py.)"""

import subprocess
import sys

import pytest

from warp_verlet.core.warp_setup import CUDA_DRIVER_WARNING

SCENE = """\
[simulation]
frames = 2

[[cloth]]
resolution = [3, 3]
size = [1.0, 1.0]
"""


@pytest.mark.slow
def test_a_cuda_run_without_the_driver_says_why_in_one_note_before_its_error(tmp_path):
    bare = subprocess.run([sys.executable, "-c", "import warp; warp.init()"], capture_output=True, text=True)
    if CUDA_DRIVER_WARNING not in bare.stderr:
        pytest.skip("Warp finds the CUDA driver on this machine")
    (tmp_path / "small.toml").write_text(SCENE)

    def run(*extra):
        return subprocess.run([sys.executable, "-m", "warp_verlet", "run", "small.toml", "--device", "cuda", "-q",
                               *extra], cwd=tmp_path, capture_output=True, text=True, timeout=300)

    done = run()
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        "note: Warp could not find or load the NVIDIA CUDA driver, so no CUDA device can be used",
        "error: device 'cuda' asked for, but no CUDA device is available (try --device cpu)"]
    verbose = run("-v")  # -v shows Warp's own words
    assert verbose.returncode == 1 and f"Warp CUDA warning: {CUDA_DRIVER_WARNING}" in verbose.stderr
