"""Random scenes, run to look for what the stability suite's chosen cases miss: a position that ends non-finite, or
an error that is not one clear refusal.

    python -m bench.fuzz [--kind KIND] [--seed N] [--scenes N] [--frames N] [--cache] [--out DIR]

Kinds (each a generator of scene tables, drawn from ``numpy.random.default_rng(seed)`` in a fixed order, so a seed
gives the same scenes on every machine):

- **lines**: one grid cloth with ``line_passes`` (1 to 3): 2 to 23 particles a side, 0.2 to 2 m, either orientation,
  0.01 to 2 kg, named and interior pins, tethers or not, soft or rigid shear and bend, a ball and a ground plane that
  may cut the cloth, 1 to 64 substeps of 1, 2 or 8 sweeps; 30 frames;
- **features**: one or two grid cloths with any of self-collision, line passes, tearing and tethers off; a ball,
  a ground plane and the table mesh of ``scenes/assets``, each with or without friction; the air at up to 20 m/s;
  1 to 32 substeps; 20 frames;
- **extreme**: ``features`` with sizes from 1 cm to 32 m along each axis (so faces can be thousands of times longer
  than wide), masses from 10 mg to 1 t, and up to 64 substeps;
- **assorted**: one or two cloths, each the tablecloth mesh of ``scenes/assets`` scaled 0.1 to 10 times or a grid
  with pins, a heavy particle and a rigid patch, with any of a soft bend, a bend limit, self-collision, tearing by
  tension and tethers off; a keyframed ball, the ground and a moved table mesh of thickness 0 to 5 cm; float32 or
  float64; the air at up to 30 m/s and gravity up to 1000 m/s^2; 1 to 64 substeps; 15 frames;
- **solvers**: grids (some tearing) and the tablecloth mesh under random solver settings: coloured or Jacobi
  relaxation, the contact projection, damping, precision, a ``target_stretch`` budget, the global correction, the
  multilevel pass, wind; a ball, the ground and the table mesh; 12 frames;
- **input**: a shipped scene (``INPUT_SCENES``) with one to three of its values made wrong (another type, out of
  range, not finite), a key removed or an unknown key added: the loader must refuse it with one clear error that
  names the scene, or the scene must run; its frames (use ``--frames`` to cut long ones short).

With ``--cache`` each scene runs as ``warp-verlet run`` runs it (``warp_verlet.apps.runner.run_scene``), writing its
USD point cache, which must then pass ``validate_cache``; a cache that does not is a finding too.

With ``--sticks FORM`` each scene's simulator is asked for that form of its sticks (``Simulator(sticks=FORM)``:
"explicit", "implicit", "tiled" or "clustered"), so that the shared-memory sweeps, which "auto" takes only on a GPU,
run the random scenes on the CPU too. A form that does not take a scene refuses it with a ``StickFormRefused``
(an ``ArgumentError`` that names the form and the reason): that counts as refused, any other ``ArgumentError`` as a
finding.

With ``--threads T`` each scene runs on T CPU relaxation threads (its frames captured, one graph a thread) and again
on one; positions that differ at the end, which the threads must give bit for bit, are a finding.

A scene the loader refuses (a ``SceneError``, one clear message) counts as refused; one the simulator stops with a
``WarpVerletError`` of its own (a divergence it detects, a step below the float type's limit, memory it lacks:
named) as stopped. An ``ArgumentError`` or ``StateError`` is the project calling itself wrongly, not a refusal of
the scene: it, every other error, and a run whose positions end non-finite, is a finding: printed with its scene
tables, so that it can be run again by itself. Exits 1 when there is a finding.
"""

from __future__ import annotations

import copy
import sys
import tempfile
from pathlib import Path

import numpy as np

from warp_verlet.core.simulator import Simulator
from warp_verlet.core.stages import STICK_FORMS
from warp_verlet.errors import ArgumentError, SceneError, StateError, StickFormRefused, WarpVerletError
from warp_verlet.input.scene import parse_scene

from .common import arg_parser, machine, quiet_warp, write_table

NAMED_PINS = ["top-left", "top-right", "bottom-left", "bottom-right", "top-edge", "left-edge"]
TABLE = Path(__file__).resolve().parent.parent / "scenes" / "assets" / "table.obj"


def lines_scene(rng: np.random.Generator) -> dict:
    """A grid cloth with line passes, among pins and colliders (the kind that found singular lines)."""
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


def features_scene(rng: np.random.Generator, extreme: bool = False) -> dict:
    """One or two grid cloths with a random set of features, among random colliders and air."""
    cloths = []
    for ci in range(int(rng.integers(1, 3))):
        r, c = int(rng.integers(2, 20)), int(rng.integers(2, 20))
        pins = [str(p) for p in rng.choice(NAMED_PINS, size=int(rng.integers(0, 3)), replace=False)]
        pins += [[int(rng.integers(0, r)), int(rng.integers(0, c))] for _ in range(int(rng.integers(0, 2)))]
        if extreme:
            size = [float(10 ** rng.uniform(-2, 1.5)), float(10 ** rng.uniform(-2, 1.5))]
        else:
            size = [float(rng.uniform(0.2, 1.5)), float(rng.uniform(0.2, 1.5))]
        orientation = str(rng.choice(["horizontal", "vertical"]))
        mass = float(10 ** rng.uniform(-5, 3)) if extreme else float(rng.uniform(0.01, 2))
        cloth = {"name": f"c{ci}", "resolution": [r, c], "size": size, "orientation": orientation, "mass": mass,
                 "origin": [float(rng.uniform(-0.7, 0.0)), float(rng.uniform(0.3, 1.5)), float(rng.uniform(-0.7, 0.0))],
                 "sticks": ["structural", "shear", "bend"], "pins": pins}
        rng.integers(0, 6)  # unused: kept so that the seeds in bench/results/fuzz give the same scenes
        if rng.integers(0, 2):
            cloth["compliance"] = {"shear": float(rng.choice([0.01, 1.0])), "bend": 1.0}
        if rng.integers(0, 3) == 0:
            cloth["self_collision"] = True
        if rng.integers(0, 3) == 0:
            cloth["line_passes"] = int(rng.integers(1, 3))
        elif rng.integers(0, 3) == 0:
            cloth["tear_threshold"] = float(rng.uniform(1.05, 2.0))
        if rng.integers(0, 4) == 0:
            cloth["tethers"] = False
        cloths.append(cloth)
    colliders = []
    if rng.integers(0, 2):
        colliders.append({"type": "sphere", "name": "ball", "radius": float(rng.uniform(0.05, 0.4)),
                          "centre": [0.0, float(rng.uniform(-0.2, 0.8)), 0.0],
                          "friction_coefficient": float(rng.choice([0, 0.5]))})
    if rng.integers(0, 2):
        colliders.append({"type": "plane", "name": "ground", "point": [0, float(rng.uniform(-0.5, 0.3)), 0],
                          "friction_coefficient": float(rng.choice([0, 0.6]))})
    if rng.integers(0, 3) == 0:
        colliders.append({"type": "mesh", "name": "table", "mesh": str(TABLE), "thickness": 0.01,
                          "friction_coefficient": float(rng.choice([0, 0.5]))})
    substeps = int(rng.choice([1, 2, 8, 32, 64] if extreme else [1, 2, 8, 32]))
    simulation = {"fps": 60, "frames": 20, "substeps": substeps, "iterations": int(rng.choice([1, 4, 8]))}
    if rng.integers(0, 4) == 0:
        simulation["air"] = {"velocity": [float(rng.uniform(0, 20)), 0.0, 0.0], "density": 1.2}
    data = {"simulation": simulation, "cloth": cloths}
    if colliders:
        data["collider"] = colliders
    return data


CLOTH_MESH = Path(__file__).resolve().parent.parent / "scenes" / "assets" / "tablecloth.obj"


def mesh_cloth(rng: np.random.Generator, name: str, log_mass: tuple[float, float], scaled: bool = False) -> dict:
    """The tablecloth mesh 0.5 to 1.5 m up, scaled 0.1 to 10 times when ``scaled``, of 10^log_mass kg."""
    cloth = {"name": name, "mesh": str(CLOTH_MESH), "translate": [0.0, float(rng.uniform(0.5, 1.5)), 0.0]}
    if scaled:
        cloth["scale"] = float(10 ** rng.uniform(-1, 1))
    return {**cloth, "mass": float(10 ** rng.uniform(*log_mass)), "sticks": ["structural", "bend"]}


def grid_cloth(rng: np.random.Generator, name: str, sides_below: int, log_mass: tuple[float, float],
               some_families: bool = False) -> dict:
    """A grid of 2 to ``sides_below`` - 1 particles a side, 0.2 to 1.5 m, of 10^log_mass kg, with up to two named pins;
    structural sticks and, with ``some_families``, each of shear and bend at random (else both)."""
    r, c = int(rng.integers(2, sides_below)), int(rng.integers(2, sides_below))
    return {"name": name, "resolution": [r, c], "size": [float(rng.uniform(0.2, 1.5)), float(rng.uniform(0.2, 1.5))],
            "orientation": str(rng.choice(["horizontal", "vertical"])), "mass": float(10 ** rng.uniform(*log_mass)),
            "origin": [float(rng.uniform(-0.7, 0.0)), float(rng.uniform(0.3, 1.5)), float(rng.uniform(-0.7, 0.0))],
            "sticks": [s for s in ["structural", "shear", "bend"]
                       if s == "structural" or not some_families or rng.integers(0, 2)],
            "pins": [str(p) for p in rng.choice(NAMED_PINS, size=int(rng.integers(0, 3)), replace=False)]}


def assorted_scene(rng: np.random.Generator) -> dict:
    """Mesh and grid cloths with the features the other kinds leave out, among moving colliders."""
    cloths = []
    for ci in range(int(rng.integers(1, 3))):
        if rng.integers(0, 2):
            cloth = mesh_cloth(rng, f"m{ci}", (-3, 1), scaled=True)
        else:
            cloth = grid_cloth(rng, f"g{ci}", 16, (-3, 1))
            r, c = cloth["resolution"]
            if rng.integers(0, 3) == 0:
                cloth["particle_masses"] = [[int(rng.integers(0, r)), int(rng.integers(0, c)),
                                             float(10 ** rng.uniform(-4, 2))]]
            if rng.integers(0, 3) == 0:  # a box over the cloth's left part (or none of it: a clear refusal)
                box = {"min": [-2.0, -2.0, -2.0], "max": [float(rng.uniform(-0.6, 0.5)), 3.0, 3.0]}
                cloth["rigid_patches"] = [[box]]
        if rng.integers(0, 2):
            cloth["compliance"] = {"bend": float(10 ** rng.uniform(-3, 1))}
        if rng.integers(0, 3) == 0:
            cloth["max_bend_angle"] = float(rng.uniform(1, 90))
        if rng.integers(0, 3) == 0:
            cloth["self_collision"] = True
        if rng.integers(0, 3) == 0:
            cloth["tear_tension"] = float(10 ** rng.uniform(-3, 1))
        if rng.integers(0, 4) == 0:
            cloth["tethers"] = False
        cloths.append(cloth)
    colliders = []
    if rng.integers(0, 2):
        end = float(rng.uniform(0.1, 1.0))
        colliders.append({"type": "sphere", "name": "ball", "radius": float(rng.uniform(0.05, 0.4)),
                          "path": [[0.0, 0.0, float(rng.uniform(-0.5, 1.5)), 0.0],
                                   [end, float(rng.uniform(-1, 1)), float(rng.uniform(-0.5, 1.5)), 0.0]],
                          "friction_coefficient": float(rng.choice([0, 0.5]))})
    if rng.integers(0, 2):
        colliders.append({"type": "plane", "name": "ground", "point": [0, float(rng.uniform(-0.5, 0.3)), 0],
                          "friction_coefficient": float(rng.choice([0, 0.6]))})
    if rng.integers(0, 3) == 0:
        colliders.append({"type": "mesh", "name": "table", "mesh": str(TABLE),
                          "thickness": float(rng.choice([0.0, 0.01, 0.05])),
                          "friction_coefficient": float(rng.choice([0, 0.5])),
                          "translate": [float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)), 0.0]})
    simulation = {"fps": 60, "frames": 15, "substeps": int(rng.choice([1, 4, 16, 64])),
                  "iterations": int(rng.choice([1, 4, 8])), "precision": str(rng.choice(["auto", "float64"]))}
    if rng.integers(0, 4) == 0:
        simulation["air"] = {"velocity": [float(rng.uniform(0, 30)), 0.0, 0.0]}
    if rng.integers(0, 4) == 0:
        simulation["gravity"] = [0.0, float(-10 ** rng.uniform(0, 3)), 0.0]
    data = {"simulation": simulation, "cloth": cloths}
    if colliders:
        data["collider"] = colliders
    return data


def solvers_scene(rng: np.random.Generator) -> dict:
    """Grids and the tablecloth mesh under random solver settings: the relaxation, the contact projection, damping,
    precision, a target_stretch budget, the global correction, the multilevel pass and wind."""
    cloths = []
    for ci in range(int(rng.integers(1, 3))):
        if rng.integers(0, 4) == 0:
            cloth = mesh_cloth(rng, f"m{ci}", (-2, 0.5))
        else:
            cloth = grid_cloth(rng, f"g{ci}", 24, (-2, 0.5), some_families=True)
            if rng.integers(0, 3) == 0:
                cloth["tear_threshold"] = float(rng.uniform(1.05, 3))
        if rng.integers(0, 2):
            cloth["compliance"] = {"bend": float(10 ** rng.uniform(-3, 1))}
        if rng.integers(0, 3) == 0:
            cloth["self_collision"] = True
        if rng.integers(0, 4) == 0:
            cloth["tethers"] = bool(rng.integers(0, 2))
        if rng.integers(0, 4) == 0:
            cloth["tether_scale"] = float(rng.uniform(1.0, 2.0))
        cloths.append(cloth)
    simulation = {"fps": float(rng.choice([24, 30, 60, 120])), "frames": 12, "iterations": int(rng.choice([1, 2, 8])),
                  "relaxation": str(rng.choice(["coloured", "jacobi"])),
                  "contact_projection": str(rng.choice(["after_sweeps", "every_sweep"])),
                  "damping": float(rng.choice([0.0, 0.5, 5.0])),
                  "precision": str(rng.choice(["auto", "float32", "float64"]))}
    if rng.integers(0, 3) == 0:
        simulation["target_stretch"] = float(10 ** rng.uniform(-4, -1))
        simulation["max_substeps"] = 64
    else:
        simulation["substeps"] = int(rng.choice([1, 4, 16, 64]))
    if rng.integers(0, 3) == 0:
        simulation["global_iterations"] = int(rng.integers(1, 6))
    if rng.integers(0, 4) == 0:
        simulation["multilevel"] = True
    if rng.integers(0, 4) == 0:
        simulation["wind"] = [float(rng.uniform(-5, 5)), 0.0, float(rng.uniform(-5, 5))]
    colliders = []
    if rng.integers(0, 2):
        colliders.append({"type": "sphere", "name": "ball", "radius": float(rng.uniform(0.1, 0.4)),
                          "centre": [0.0, float(rng.uniform(-0.2, 0.8)), 0.0],
                          "thickness": float(rng.choice([0.0, 0.01]))})
    if rng.integers(0, 2):
        colliders.append({"type": "plane", "name": "ground", "point": [0, float(rng.uniform(-0.5, 0.3)), 0],
                          "friction_coefficient": float(rng.choice([0, 0.6])),
                          "static_friction_coefficient": float(rng.choice([0.6, 1.0]))})
    if rng.integers(0, 4) == 0:
        colliders.append({"type": "mesh", "name": "table", "mesh": str(TABLE)})
    data = {"simulation": simulation, "cloth": cloths}
    if colliders:
        data["collider"] = colliders
    return data


SCENES = Path(__file__).resolve().parent.parent / "scenes"
INPUT_SCENES = ("ball_through_net", "banner_batten", "cloth_on_sphere", "cloth_on_table", "curtain_frame",
                "curtain_override", "drape", "flag_air", "flag_tear", "hanging_cloth", "rope", "rope_bend_limit",
                "sphere_sweep", "swinging_cloth", "tablecloth", "two_cloths", "wind_sheet")
"""The shipped scenes the ``input`` kind mutates: those a CPU runs in seconds (not the 1024² ones)."""
NUMBER_MUTANTS = (float("nan"), float("inf"), float("-inf"), -1, 0, 0.0, 1e30, -1e-30, 1e-300, 2 ** 63, True,
                  "1.0", [1.0], {})
STRING_MUTANTS = ("", "nonsense", "../no/such/file.obj", 3, 1.5, False, ["x"], {})
LIST_MUTANTS = ([], [[]], [1], [1, 2, 3], ["a", "b"], [float("nan"), 1.0], 5, "list", [1e30, 1e30], [-1, -1],
                [0, 0], [2 ** 40, 2], [True, False], [{}], [[1, 2], [3, 4]])
TABLE_MUTANTS = ({}, [], 1, "table")


def _paths(value, path=()):
    """Every (path, value) under a scene's tables, tables and arrays included, the document itself left out."""
    if path:
        yield path, value
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _paths(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _paths(item, (*path, index))


def _mutant(rng: np.random.Generator, value):
    """A wrong value for a place that holds ``value``: of another type, out of range, or not finite."""
    if isinstance(value, bool) or isinstance(value, (int, float)):
        pool = NUMBER_MUTANTS
    elif isinstance(value, str):
        pool = STRING_MUTANTS
    elif isinstance(value, list):
        pool = LIST_MUTANTS
    else:
        pool = TABLE_MUTANTS
    return copy.deepcopy(pool[int(rng.integers(0, len(pool)))])


def input_scene(rng: np.random.Generator) -> dict:
    """A shipped scene's tables (``INPUT_SCENES``; its mesh files made absolute, so that they load from anywhere)
    with one to three of its values made wrong, or a key removed, or a key added that no table knows."""
    import tomllib

    name = INPUT_SCENES[int(rng.integers(0, len(INPUT_SCENES)))]
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    for table in [*data.get("cloth", []), *data.get("collider", [])]:
        if isinstance(table.get("mesh"), str):
            table["mesh"] = str(SCENES / table["mesh"])
    for _ in range(int(rng.integers(1, 4))):
        places = list(_paths(data))
        path, value = places[int(rng.integers(0, len(places)))]
        parent = data
        for step in path[:-1]:
            parent = parent[step]
        action = int(rng.integers(0, 6))
        if action == 0 and isinstance(parent, dict):
            del parent[path[-1]]
        elif action == 1 and isinstance(value, dict):
            value["no_such_key"] = 1.0
        else:
            parent[path[-1]] = _mutant(rng, value)
    return data


KINDS = {"lines": lines_scene, "features": features_scene,
         "extreme": lambda rng: features_scene(rng, extreme=True), "assorted": assorted_scene,
         "solvers": solvers_scene, "input": input_scene}
"""Kind -> generator of one scene's tables from the random generator."""


def _stopped(e: WarpVerletError) -> str:
    """A WarpVerletError's outcome: "stopped: ..." where the simulator refuses to go on, a finding ("error: ...")
    where the project passed itself a wrong argument or used an object in a wrong state."""
    if isinstance(e, (ArgumentError, StateError)):
        return f"error: {type(e).__name__}: {str(e)[:300]}"
    return f"stopped: {str(e)[:200]}"


def run_scene(data: dict, frames: int, device: str = "cpu", cache: Path | None = None, sticks: str = "auto",
              threads: int | None = None) -> str:
    """Run the scene tables ``data`` for ``frames`` frames: "finite", "refused: ...", "stopped: ..." or a finding,
    "non-finite at frame F", "invalid cache: ...", "threads differ: ..." or "error: ...". With ``cache`` (a path
    ending .usdc or .usda), run it as ``warp-verlet run`` does, writing its cache there, and validate the cache.
    ``sticks``: the form of the sticks the simulator is asked for; where it is not "auto", the form's refusal of the
    scene counts as refused. ``threads``: the CPU relaxation's threads; above one, the scene runs again on one and
    must end with the same positions. Never raises."""
    try:
        scene = parse_scene(data, file="<fuzz>")
        if cache is not None:
            return _run_with_cache(scene, frames, device, cache)
        sim = Simulator(scene, device, sticks=sticks, threads=threads)
    except SceneError as e:
        return f"refused: {str(e)[:200]}"
    except WarpVerletError as e:
        if sticks != "auto" and isinstance(e, StickFormRefused):
            return f"refused: {str(e)[:200]}"
        return _stopped(e)
    except Exception as e:  # noqa: BLE001 - a fuzz reports whatever it finds
        return f"error: {type(e).__name__}: {str(e)[:300]}"
    try:
        for frame in range(frames):
            sim.step_frame()
            if not np.isfinite(sim.positions()).all():
                return f"non-finite at frame {frame}"
        positions = sim.positions()
    except WarpVerletError as e:
        return _stopped(e)
    except Exception as e:  # noqa: BLE001
        return f"error: {type(e).__name__}: {str(e)[:300]}"
    finally:
        sim.close()
    if threads is not None and threads > 1:
        return _same_on_one_thread(scene, frames, device, sticks, threads, positions)
    return "finite"


def _same_on_one_thread(scene, frames: int, device: str, sticks: str, threads: int, positions: np.ndarray) -> str:
    """"finite" where ``frames`` frames of ``scene`` on one thread end at ``positions`` bit for bit, else a finding."""
    try:
        sim = Simulator(scene, device, sticks=sticks, threads=1)
        try:
            for _ in range(frames):
                sim.step_frame()
            one = sim.positions()
        finally:
            sim.close()
    except Exception as e:  # noqa: BLE001 - it ran on threads, so on one it must too
        return f"error: on one thread: {type(e).__name__}: {str(e)[:300]}"
    if np.array_equal(one, positions):
        return "finite"
    return f"threads differ: {threads} threads end {np.abs(one - positions).max():.3g} m from one thread"


def _run_with_cache(scene, frames: int, device: str, cache: Path) -> str:
    from warp_verlet.apps.runner import run_scene as run_to_cache
    from warp_verlet.output.usd_writer import validate_cache

    try:
        run_to_cache(scene, cache, device=device, frames=frames)
        problems = validate_cache(cache)
    finally:
        for leftover in cache.parent.glob(f"{cache.stem}*"):
            leftover.unlink()
    return f"invalid cache: {'; '.join(problems)[:300]}" if problems else "finite"


def is_finding(outcome: str) -> bool:
    return outcome.startswith(("non-finite", "invalid cache", "threads differ", "error"))


def fuzz(kind: str, seed: int, scenes: int, frames: int | None = None, device: str = "cpu",
         cache_dir: Path | None = None, log=print, sticks: str = "auto", threads: int | None = None) -> dict[str, int]:
    """Generate and run ``scenes`` scenes of ``kind`` from ``seed`` for ``frames`` frames each (None: each scene's
    own), writing and validating each cache in ``cache_dir`` when given, with the sticks' form ``sticks`` and the
    CPU threads ``threads``; print each finding with its tables. The count of each outcome: finite, refused,
    stopped, findings."""
    rng = np.random.default_rng(seed)
    counts = {"finite": 0, "refused": 0, "stopped": 0, "findings": 0}
    for index in range(scenes):
        data = KINDS[kind](rng)
        cache = None if cache_dir is None else cache_dir / f"scene{index}{'.usda' if index % 2 else '.usdc'}"
        outcome = run_scene(data, frames or data["simulation"]["frames"], device, cache, sticks, threads)
        if is_finding(outcome):
            counts["findings"] += 1
            log(f"finding: scene {index}: {outcome}\n  {data}")
        else:
            counts[outcome.split(":")[0]] += 1
    return counts


def main(argv=None) -> int:
    p = arg_parser("bench.fuzz", __doc__)
    p.add_argument("--kind", choices=list(KINDS), default="features")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--scenes", type=int, default=100)
    p.add_argument("--frames", type=int, default=None, help="frames each (default: the kind's own, the scene's "
                                                            "frames)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--cache", action="store_true", help="run each scene as warp-verlet run does, writing its USD "
                                                        "cache (.usdc and .usda in turn), and validate the cache")
    p.add_argument("--sticks", choices=STICK_FORMS, default="auto",
                   help="the form of the sticks each simulator is asked for (not with --cache)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU relaxation threads for every scene (default: the simulator's choice); above one, each "
                        "scene also runs on one and must end bit for bit the same")
    p.add_argument("--out", type=Path, default=None, help="write fuzz-KIND-SEED.md and .csv there")
    args = p.parse_args(argv)
    if args.cache and (args.sticks != "auto" or args.threads is not None):
        p.error("--sticks and --threads run the simulator directly; --cache runs each scene as warp-verlet run does")
    if args.threads is not None and (args.threads < 1 or args.device != "cpu"):
        p.error(f"--threads: expected 1 or more CPU threads (with --device cpu), got {args.threads}")
    quiet_warp()
    frames = args.frames
    with tempfile.TemporaryDirectory() as scratch:
        counts = fuzz(args.kind, args.seed, args.scenes, frames, args.device,
                      Path(scratch) if args.cache else None, sticks=args.sticks, threads=args.threads)
    command = ["bench.fuzz", *(argv if argv is not None else sys.argv[1:])]
    header = "\n".join(machine(args.device).lines(command))
    forced = ("" if args.sticks == "auto" else f"-{args.sticks}") + (f"-{args.threads}threads" if args.threads else "")
    write_table([{"kind": args.kind, "seed": args.seed, "scenes": args.scenes,
                  "frames": frames or "each scene's", "caches": "written and validated" if args.cache else "none",
                  "sticks": args.sticks, "threads": args.threads or "auto", **counts}],
                args.out, f"fuzz-{args.kind}-{args.seed}{'-cache' if args.cache else ''}{forced}",
                f"Fuzz: {args.kind}, seed {args.seed}\n\n{header}")
    return 1 if counts["findings"] else 0


if __name__ == "__main__":
    sys.exit(main())
