"""Random small grid scenes with line passes, to look for non-finite positions: random sizes, orientation, mass,
pins (named and interior), tethers, soft or rigid shear and bend, a ball and a ground plane that may cut the
cloth, 1 to 64 substeps and 1 to 3 passes; 30 frames each. Prints each scene that ends with a NaN or raises.

    PYTHONPATH=. python bench/results/line_solve/cpu/fuzz_line_passes.py SEED TRIALS
"""

import sys

import numpy as np
import warp as wp

from warp_verlet.core.simulator import Simulator
from warp_verlet.input.scene import parse_scene

NAMED_PINS = ["top-left", "top-right", "bottom-left", "bottom-right", "top-edge", "left-edge"]


def random_scene(rng: np.random.Generator) -> dict:
    r, c = int(rng.integers(2, 24)), int(rng.integers(2, 24))
    pins = [str(p) for p in rng.choice(NAMED_PINS, size=int(rng.integers(0, 3)), replace=False)]
    pins += [[int(rng.integers(0, r)), int(rng.integers(0, c))] for _ in range(int(rng.integers(0, 3)))]
    substeps, iterations = int(rng.choice([1, 4, 16, 64])), int(rng.choice([1, 2, 8]))
    cloth = {"name": "c", "resolution": [r, c], "size": [float(rng.uniform(0.2, 2)), float(rng.uniform(0.2, 2))],
             "orientation": str(rng.choice(["horizontal", "vertical"])), "mass": float(rng.uniform(0.01, 2)),
             "sticks": ["structural", "shear", "bend"], "line_passes": int(rng.integers(1, 4)),
             "tethers": bool(rng.integers(0, 2)) and bool(pins), "pins": pins}
    if rng.integers(0, 2):
        cloth["compliance"] = {"shear": 1.0, "bend": 1.0}
    colliders = []
    if rng.integers(0, 2):
        colliders.append({"type": "sphere", "name": "ball", "radius": 0.3, "centre": [0.2, -0.4, 0.1]})
    if rng.integers(0, 2):
        colliders.append({"type": "plane", "name": "ground", "point": [0, -1.0, 0]})
    data = {"simulation": {"fps": 60, "frames": 30, "substeps": substeps, "iterations": iterations},
            "cloth": [cloth]}
    if colliders:
        data["collider"] = colliders
    return data


def main(seed: int, trials: int) -> int:
    wp.config.quiet = True
    rng = np.random.default_rng(seed)
    bad = 0
    for trial in range(trials):
        data = random_scene(rng)
        sim = Simulator(parse_scene(data, file="<fuzz>"), "cpu")
        try:
            for _ in range(30):
                sim.step_frame()
            finite = bool(np.isfinite(sim.positions()).all())
        except Exception as e:  # noqa: BLE001 - a fuzz reports whatever it finds
            finite = False
            print("error", type(e).__name__, str(e)[:200])
        if not finite:
            bad += 1
            print("non-finite", trial, data)
    print(f"seed {seed}: {bad} of {trials} scenes ended non-finite")
    return bad


if __name__ == "__main__":
    sys.exit(1 if main(int(sys.argv[1]), int(sys.argv[2])) else 0)
