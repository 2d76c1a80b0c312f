"""Convergence at scale: stretch and position error against time, per method, with the peer in the same run.

    python -m bench.convergence [--device cpu|cuda] [--methods plain tethers ...]
        [--scenes hanging swinging drape torn_net] [--sizes N ...] [--drape-sizes N ...] [--net-sizes N ...]
        [--budgets SxK ...] [--ref SxK]
        [--peer] [--peer-sizes N ...] [--out DIR] [--stem NAME] [--fresh] [--no-plot]

Scenes (each built as the tables of a scene file, then the method's overrides merged in):

- **hanging**: 1 m square, 0.2 kg, vertical, pinned at its two top corners, structural + shear + bend sticks
  (rigid), damping 0.24 /s (the old drag 0.999 at 240 substeps/s), 60 fps, read at 1 s (60 frames);
- **swinging**: the hanging cloth started level (horizontal, pinned at the two corners of its edge at y = 1 m)
  and read at 1 s, as it swings down through the vertical. Hung in its rest pose, every particle of the hanging
  cloth already lies at the lowest point its two tethers allow, so with tethers that scene measures how still it
  stays; this one loads the sticks and the tethers as the cloth moves;
- **drape**: the same cloth flat, no pins, dropped from 0.5 m onto a 0.25 m sphere at the origin, ground at
  -0.5 m, read at 1.5 s (90 frames);
- **torn_net**: the same cloth flat at y = 1 m, pinned along its left and right edges, tear_threshold 1.5; a
  kinematic 0.2 m ball falls freely from y = 2 m (sampled every 0.02 s) through it onto the ground at y = 0
  (it lands at 0.61 s); read at 1 s (60 frames), after the ball has torn it (the sticks torn are recorded).
  tether_scale 1.6, above the tear threshold, so that a method with tethers can still tear.

Methods are data: ``METHODS`` maps a name to overrides merged into the scene's tables ({"simulation": {...}}
into [simulation], {"cloth": {...}} into every [[cloth]]); adding a method is one line there. ``--methods a+b``
merges a's and b's overrides. The base scenes have tethers off, so ``plain`` adds nothing. A method the
installed warp_verlet refuses for a scene (an unknown key, e.g. ``precision`` before float64 landed, tethers on
the pinless drape, multilevel on the tearing net) is skipped with one printed message.

Per row (scene, grid, method, budget S substeps x K sweeps):

- ms/frame: frame 1 initialises x_prev and frame 2 captures the frame's graph; frames 3 .. N are timed in up
  to 6 synchronised blocks and ms/frame is the fastest block's mean (other work on a shared machine only slows
  a block down; the json's ms_per_frame_mean is the mean over all of them). A tearing scene also syncs its
  tears once a frame, as the runner does.
- the RMS and max structural stretch |D - L| / L over intact sticks at the last frame;
- the same over the run's second half: the mean RMS and the largest max at the ends of the timed blocks from
  the run's middle on, read between blocks (a chaotic scene's last frame alone can swing widely);
- the RMS and max particle distance to a converged reference at the last frame (m, and / cloth size);
- the deepest penetration of each collider at the last frame (m; ``deepest_penetrations``);
- torn_net: the sticks torn.

The reference, per (scene, grid, device): the first method of ``REFERENCE_ORDER`` the scene accepts, at its
budget (``--ref`` S x K overrides it): float64 + tethers at 256 x 4 on the CPU, 256 x 8 on CUDA; in float32
(before float64, or where it is refused) 64 x 16 and 64 x 64, since float32 positions refuse dt below about
2.2e-4 s (S <= 75 at 60 fps) and only K can grow. The default table's largest budget is 64 x 4. Its self-
consistency is its RMS distance to the same run at half its K and at half its S: a row's position error is
resolved when the larger of the two is <= 1/3 of it (the rows' "pos resolved"), and the references table says
whether the best row's is. Where the final state is chaotic (the drape's folds on a symmetric sphere, where
the net tears) the halves differ by centimetres and no row is resolved: there the stretch is the measure.
References are cached in DIR/STEM.json (metadata) and DIR/references/*.npy (positions; not committed) and
reused unless ``--fresh`` or the scene, method or budget changed.

With ``--peer``, Newton's Style3D and VBD run the hanging and the swinging cloth (whichever of them run) in the
same process (skipped with a message when Newton is absent); their position error includes the model difference
(a triangle membrane, not sticks).

Outputs in DIR: STEM.md (machine, device, date, command, references, rows, and a targets table at the end),
STEM.json, and STEM-SCENE-N.png (log-log fronts: ms/frame against RMS stretch and position error, one series
per method and peer, each method's Pareto front as a line). On the CPU every simulator runs one relaxation
thread (``threads=1``): the targets are for one core.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_verlet.errors import SceneError
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator

from .common import HANGING_DAMPING, arg_parser, machine, quiet_warp

FPS = 60.0
DAMPING = HANGING_DAMPING  # 1/s, about 0.24
G = 9.81

# ---------------------------------------------------------------- methods (data)

METHODS: dict[str, dict] = {
    "plain": {},                                            # the base scenes: tethers off
    "tethers": {"cloth": {"tethers": True}},
    "multilevel": {"simulation": {"multilevel": True}},      # refused by a tearing cloth (the net)
    "float64": {"simulation": {"precision": "float64"}},
    "contact_sweeps": {"simulation": {"contact_projection": "every_sweep"}},  # the clamp also ends every sweep
    # the global correction: n conjugate-gradient iterations a substep, multigrid- or Jacobi-preconditioned
    **{f"global{n}": {"simulation": {"global_iterations": n}} for n in (3, 5, 10, 30)},
    **{f"global_jacobi{n}": {"simulation": {"global_iterations": n, "global_preconditioner": "jacobi"}}
       for n in (10, 30, 100)},
    # a cloth that can drape without stretching: soft shear and bend sticks (rigid ones make a grid a flat plate)
    "soft": {"cloth": {"compliance": {"shear": 1.0, "bend": 1.0}}},
    "softer": {"cloth": {"compliance": {"shear": 10.0, "bend": 10.0}}},
    "net": {"cloth": {"sticks": ["structural"]}},  # a net of threads: no shear or bend sticks at all
    # exact solves of the structural rows and columns before each substep's sweeps
    **{("lines" if n == 1 else f"lines{n}"): {"cloth": {"line_passes": n}} for n in (1, 2)},
}
"""Method name -> scene overrides. Combine with "+" on the command line (``multilevel+tethers``)."""

_F64 = {"cpu": (256, 4), "cuda": (256, 8)}  # float64 lifts the dt floor: S grows too
_F32 = {"cpu": (64, 16), "cuda": (64, 64)}   # float32 refuses dt below ~2.2e-4 s (S <= 75 at 60 fps): K grows
REFERENCE_ORDER = (("float64+tethers", _F64), ("float64", _F64), ("tethers", _F32), ("plain", _F32))
"""The reference runs the first of these the scene accepts, at its budget for the device (``--ref`` overrides
it): float64 (no float32 floor on dt, so S can pass 75: at 64^2 on the CPU, 256 x 4 in float64 is 4 x closer
to its half-S run than 64 x 16 in float32, at the same time), tethers where there are pins (they change the
answer only where the cloth is stretched past its rest geodesics, which a converged cloth is not), else plain.
Multilevel is left out until its converged answer is checked to be the plain one."""


def method_overrides(name: str, methods: dict | None = None) -> dict:
    """The merged overrides of ``name`` ("a" or "a+b+..."); KeyError for a name not in ``methods``."""
    methods = METHODS if methods is None else methods
    out: dict = {}
    for part in name.split("+"):
        if part not in methods:
            raise KeyError(f"unknown method {part!r} (known: {', '.join(methods)}; combine with '+')")
        out = merge(out, methods[part])
    return out


def merge(base: dict, overrides: dict) -> dict:
    """``base`` with ``overrides`` merged in (a copy): tables merge key by key, a table merged into an array of
    tables ([[cloth]], [[collider]]) merges into each of them, anything else replaces."""
    out = copy.deepcopy(base)
    for key, value in overrides.items():
        old = out.get(key)
        if isinstance(value, dict) and isinstance(old, list):
            out[key] = [merge(t, value) for t in old]
        elif isinstance(value, dict) and isinstance(old, dict):
            out[key] = merge(old, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


# ---------------------------------------------------------------- scenes

def _sheet(n: int, **cloth) -> dict:
    return {"name": "cloth", "resolution": [n, n], "size": [1.0, 1.0], "mass": 0.2,
            "sticks": ["structural", "shear", "bend"], "tethers": False, **cloth}


def _simulation(substeps: int, iterations: int, frames: int) -> dict:
    return {"fps": FPS, "frames": frames, "substeps": substeps, "iterations": iterations, "damping": DAMPING}


def hanging(n: int, substeps: int, iterations: int, frames: int = 60) -> dict:
    return {"simulation": _simulation(substeps, iterations, frames),
            "cloth": [_sheet(n, origin=[-0.5, 1.0, 0.0], pins=["top-left", "top-right"])]}


def swinging(n: int, substeps: int, iterations: int, frames: int = 60) -> dict:
    return {"simulation": _simulation(substeps, iterations, frames),
            "cloth": [_sheet(n, origin=[-0.5, 1.0, 0.0], orientation="horizontal", pins=["top-left", "top-right"])]}


def drape(n: int, substeps: int, iterations: int, frames: int = 90) -> dict:
    return {"simulation": _simulation(substeps, iterations, frames),
            "cloth": [_sheet(n, origin=[-0.5, 0.5, -0.5], orientation="horizontal")],
            "collider": [{"type": "sphere", "name": "ball", "radius": 0.25, "centre": [0.0, 0.0, 0.0]},
                         {"type": "plane", "name": "ground", "point": [0.0, -0.5, 0.0]}]}


BALL_RADIUS, BALL_TOP = 0.2, 2.0


def ball_path(step: float = 0.02) -> list[list[float]]:
    """[time, x, y, z] keyframes of the ball: free fall from y = 2 m, sampled every ``step`` s, until its
    centre is at its radius above the ground."""
    landing = math.sqrt((BALL_TOP - BALL_RADIUS) / (0.5 * G))
    times = [i * step for i in range(int(landing / step) + 1)] + [landing]
    return [[t, 0.05, max(BALL_TOP - 0.5 * G * t * t, BALL_RADIUS), 0.02] for t in times]


def torn_net(n: int, substeps: int, iterations: int, frames: int = 60) -> dict:
    return {"simulation": _simulation(substeps, iterations, frames),
            "cloth": [_sheet(n, origin=[-0.5, 1.0, -0.5], orientation="horizontal", pins=["left-edge", "right-edge"],
                             tear_threshold=1.5, tether_scale=1.6)],
            "collider": [{"type": "sphere", "name": "ball", "radius": BALL_RADIUS, "thickness": 0.01,
                          "path": ball_path()},
                         {"type": "plane", "name": "ground", "point": [0.0, 0.0, 0.0]}]}


SCENES = {"hanging": (hanging, 60), "swinging": (swinging, 60), "drape": (drape, 90), "torn_net": (torn_net, 60)}
"""Scene name -> (builder(n, S, K, frames) -> scene tables, frames read)."""

CLOTH_SIZE = 1.0  # m: every scene's cloth; position errors are also given as a fraction of it

DEFAULT_SIZES = {"cuda": {"hanging": [256, 1024, 2048], "swinging": [256, 1024, 2048], "drape": [1024],
                          "torn_net": [512]},
                 "cpu": {"hanging": [64, 128], "swinging": [64, 128], "drape": [64], "torn_net": [64]}}
DEFAULT_BUDGETS = {"cuda": [(4, 8), (16, 2), (32, 1), (64, 1), (64, 2), (64, 4)],
                   "cpu": [(1, 8), (2, 8), (4, 8), (8, 4), (16, 1), (16, 2), (24, 1), (32, 1), (64, 1), (64, 2), (64, 4)]}
RESOLVED_RATIO = 1 / 3  # the reference's half-budget difference must be <= this x the best row's error


def scene_tables(kind: str, n: int, method: str, substeps: int, iterations: int, frames: int | None = None,
                 methods: dict | None = None) -> dict:
    build, default_frames = SCENES[kind]
    return merge(build(n, substeps, iterations, frames or default_frames), method_overrides(method, methods))


def build_scene(kind: str, n: int, method: str, substeps: int, iterations: int, frames: int | None = None,
                methods: dict | None = None):
    """The validated scene; SceneError when the installed warp_verlet refuses the method's overrides."""
    tables = scene_tables(kind, n, method, substeps, iterations, frames, methods)
    return parse_scene(tables, file=f"<{kind} {n}^2 {method}>")


def device_kind(device) -> str:
    return "cuda" if wp.get_device(device).is_cuda else "cpu"


# ---------------------------------------------------------------- measuring

BLOCKS = 6  # frames 3..N are timed in up to this many blocks (of 5 frames or more)


def simulate(scene, device: str, threads: int | None) -> dict:
    """Run ``scene`` for its frames and return its final positions, stretch and torn sticks, and its time:
    frames 3..N in up to BLOCKS synchronised blocks, ms/frame the fastest block's mean (other work on a shared
    machine only slows a block down) and ms_per_frame_mean over all of them. ``rms_late`` and ``max_late`` are
    the mean RMS and the largest max stretch at the ends of the blocks in the run's second half, read between
    blocks (outside the timing): a chaotic scene's last frame alone can swing widely (a frictionless drape)."""
    sim = Simulator(scene, device, threads=threads)
    frames = scene.simulation.frames
    tears = sim.model.tears
    torn = 0

    def frame():
        nonlocal torn
        sim.step_frame()
        if tears:  # as the runner does: react to new tears once a frame (drops tethers cut off from their pin)
            count = sim.torn_count()
            if count != torn:
                torn = count
                sim.sync_tears()

    warm = min(2, frames)
    for _ in range(warm):
        frame()
    timed = frames - warm
    blocks = [len(b) for b in np.array_split(np.arange(timed), max(1, min(BLOCKS, timed // 5)))] if timed else []
    per_block, late, done = [], [], warm
    for size in blocks:
        wp.synchronize_device(sim.device)
        start = time.perf_counter()
        for _ in range(size):
            frame()
        wp.synchronize_device(sim.device)
        per_block.append((time.perf_counter() - start, size))
        done += size
        if 2 * done >= frames:
            late.append(sim.stretch())
    best = min(t / size for t, size in per_block) if per_block else float("nan")
    mean = sum(t for t, _ in per_block) / timed if timed else float("nan")
    x = sim.positions()
    stretch = sim.stretch(x)
    if not late:
        late = [stretch]
    out = {"ms_per_frame": best * 1e3, "ms_per_frame_mean": mean * 1e3, "rms": stretch.rms, "max": stretch.max,
           "rms_late": float(np.mean([s.rms for s in late])), "max_late": max(s.max for s in late),
           "positions": x, "torn": sim.torn_count() if tears else None, "lowest_y": float(x[:, 1].min()),
           "inside": deepest_penetrations(scene, sim.time, x),
           "frames": frames}
    sim.close()
    return out


def deepest_penetrations(scene, time: float, x: np.ndarray) -> dict[str, float]:
    """Per collider (by name), how far the deepest particle lies inside it at ``time``, in m (0 where none does):
    its radius or plane plus its thickness, less the particle's distance from its centre or plane. The scenes'
    colliders are spheres (a moving one placed at ``time``) and planes; any other kind is left out."""
    x = np.asarray(x, np.float64)
    depths = [(c.name, c.radius + c.thickness - np.linalg.norm(x - np.asarray(c.centre_at(time)), axis=1))
              for c in scene.spheres]
    depths += [(c.name, c.thickness - (x - np.asarray(c.point)) @ np.asarray(c.normal)) for c in scene.planes]
    return {name: float(max(0.0, depth.max())) for name, depth in depths}


def position_error(x: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(RMS, max) particle distance (m) between two (N, 3) position arrays, in float64."""
    d = np.linalg.norm(np.asarray(x, np.float64) - np.asarray(ref, np.float64), axis=-1)
    return float(np.sqrt(np.mean(d * d))), float(d.max())


def _with_error(row: dict, ref: dict | None) -> dict:
    if ref is None or ref.get("positions") is None or len(ref["positions"]) != len(row["positions"]):
        e_rms = e_max = float("nan")
    else:
        e_rms, e_max = position_error(row["positions"], ref["positions"])
    row.update(pos_rms_m=e_rms, pos_max_m=e_max, pos_rms_frac=e_rms / CLOTH_SIZE, pos_max_frac=e_max / CLOTH_SIZE)
    return row


class MethodFilter:
    """Which methods each scene accepts; prints one message per distinct refusal (method, key, problem)."""

    def __init__(self, methods: dict | None = None, log=print):
        self.methods, self.log = methods, log
        self.refused: dict[tuple[str, str], str] = {}
        self._said: set = set()

    def accepts(self, kind: str, n: int, method: str) -> bool:
        if (kind, method) in self.refused:
            return False
        try:
            build_scene(kind, n, method, 4, 1, methods=self.methods)
        except SceneError as exc:
            self.refused[(kind, method)] = exc.problem
            said = (method, exc.key, exc.problem)
            if said not in self._said:
                self._said.add(said)
                unknown = exc.problem.startswith("unknown key")
                why = "the installed warp_verlet does not know this key yet" if unknown else "the scene refuses it"
                self.log(f"method {method} skipped for {kind}{' (and any scene with the same refusal)' if unknown else ''}: "
                         f"{why}: {exc.key}: {exc.problem}", flush=True)
            return False
        return True


# ---------------------------------------------------------------- the reference

def _hash(tables: dict) -> str:
    return hashlib.sha256(json.dumps(tables, sort_keys=True).encode()).hexdigest()[:16]


def reference(kind: str, n: int, device: str, threads: int | None, budget: tuple[int, int] | None, cache: dict,
              out: Path | None, fresh: bool = False, frames: int | None = None, methods: dict | None = None,
              order=REFERENCE_ORDER, log=print) -> dict | None:
    """The converged reference of (scene, n, device): cached in ``cache`` (the json's "references") with its
    positions in out/references/KEY.npy; computed (with its half-K and half-S runs) when missing, stale or
    ``fresh``. ``budget`` (S, K) overrides ``order``'s. None when no method of ``order`` is accepted or the run
    is refused."""
    key = f"{kind}-{n}-{device_kind(device)}"
    for name, budgets in order:
        s_ref, k_ref = budget or budgets[device_kind(device)]
        try:
            scene = build_scene(kind, n, name, s_ref, k_ref, frames, methods)
            break
        except (SceneError, KeyError):
            continue
    else:
        log(f"reference {key}: no method of {[m for m, _ in order]} accepted; position errors are not measured")
        return None
    tables = scene_tables(kind, n, name, s_ref, k_ref, frames, methods)
    digest = _hash(tables)
    npy = (out / "references" / f"{key}.npy") if out is not None else None
    old = cache.get(key)
    if not fresh and old and old.get("hash") == digest and npy is not None and npy.exists():
        positions = np.load(npy)
        if positions.shape == (n * n, 3):
            log(f"reference {key}: {old['method']} {s_ref} x {k_ref}, cached ({npy})", flush=True)
            return {**old, "positions": positions, "cached": True}
    log(f"reference {key}: {name} {s_ref} x {k_ref}, {scene.simulation.frames} frames ...", flush=True)
    t0 = time.perf_counter()
    try:
        r = simulate(scene, device, threads)
        halves = {}
        for half, (s_, k_) in (("half_K", (s_ref, max(1, k_ref // 2))), ("half_S", (max(1, s_ref // 2), k_ref))):
            h = simulate(build_scene(kind, n, name, s_, k_, frames, methods), device, threads)
            e_rms, e_max = position_error(h["positions"], r["positions"])
            halves[half] = {"substeps": s_, "iterations": k_, "rms_m": e_rms, "max_m": e_max, "torn": h["torn"]}
    except Exception as exc:  # a refused budget (dt below the float32 floor) or out of memory
        log(f"reference {key} failed: {exc}")
        return None
    rec = {"key": key, "scene": kind, "n": n, "device": device_kind(device), "method": name, "substeps": s_ref,
           "iterations": k_ref, "frames": r["frames"], "hash": digest, "rms": r["rms"], "max": r["max"],
           "torn": r["torn"], "ms_per_frame": r["ms_per_frame"], "wall_s": time.perf_counter() - t0, **halves}
    log(f"  {rec['wall_s']:.0f} s; stretch RMS {r['rms']:.2e}; vs half K {halves['half_K']['rms_m']:.2e} m RMS, "
        f"vs half S {halves['half_S']['rms_m']:.2e} m RMS", flush=True)
    if npy is not None:
        npy.parent.mkdir(parents=True, exist_ok=True)
        np.save(npy, r["positions"])
    cache[key] = rec
    return {**rec, "positions": r["positions"], "cached": False}


# ---------------------------------------------------------------- the peer

PEER_SOLVERS = ("style3d", "vbd")


def peer_rows(sizes: list[int], device: str, references: dict | None = None,
              solvers: tuple[str, ...] = PEER_SOLVERS, scene: str = "hanging") -> list[dict]:
    """Newton's rows for the hanging cloth, or (``scene`` "swinging") the same cloth started level."""
    try:
        from bench import newton_style3d as peer
    except ImportError:
        print("peer: bench.newton_style3d is missing; skipped")
        return []
    if not peer.available():
        print("peer: Newton is not installed (pip install newton); skipped")
        return []
    rows = []
    for solver in solvers:
        for n in sizes:
            try:
                r = peer.run_peer(solver, n, frames=60, device=device, level=scene == "swinging")
            except Exception as exc:  # a peer failing must not lose our own rows
                print(f"peer {solver} {n}^2 failed: {exc}")
                continue
            rms, mx = peer.structural_stretch(r["positions"], n)
            rows.append({"scene": scene, "n": n, "method": f"newton-{solver}", "substeps": r["substeps"],
                         "iterations": r["iterations"], "ms_per_frame": r["ms_per_frame"], "rms": rms, "max": mx,
                         "setup_s": r["setup_s"], "first_frame_s": r["first_frame_s"], "frames": 60,
                         "positions": r["positions"], "torn": None, "peer": True})
            _with_error(rows[-1], (references or {}).get((scene, n)))
            print(_line(rows[-1]), flush=True)
    return rows


def _line(r: dict) -> str:
    torn = f"  torn {r['torn']}" if r.get("torn") is not None else ""
    inside = f"  inside {_inside(r)}" if r.get("inside") else ""
    return (f"{r['scene']:8s} {r['n']:5d}^2 {r['method']:18s} {r['substeps']:3d} x {r['iterations']:2d}  "
            f"{r['ms_per_frame']:9.2f} ms/frame  RMS {r['rms'] * 100:9.4f}%  max {r['max'] * 100:10.3f}%  "
            f"{_late(r)}"
            f"pos RMS {r.get('pos_rms_m', float('nan')):.2e} m max {r.get('pos_max_m', float('nan')):.2e} m{torn}"
            f"{inside}")


def _late(r: dict) -> str:
    """A row's stretch over the run's second half ("late RMS 0.1% max 2%  "), or nothing (a peer's row)."""
    if r.get("rms_late") is None:
        return ""
    return f"late RMS {r['rms_late'] * 100:.4g}% max {r['max_late'] * 100:.4g}%  "


def _inside(r: dict) -> str:
    """A row's deepest penetration of each collider, "ball 1.2e-08, ground 0" (m), or "—"."""
    inside = r.get("inside") or {}
    return ", ".join(f"{name} {depth:.2g}" for name, depth in inside.items()) or "—"


# ---------------------------------------------------------------- the run

def run(plan: dict[str, list[int]], methods: list[str], budgets: list[tuple[int, int]], device: str = "cpu",
        ref_budget: tuple[int, int] | None = None, out: Path | None = None, cache: dict | None = None,
        fresh: bool = False, frames: int | None = None, peer: bool = False, peer_sizes: list[int] | None = None,
        method_table: dict | None = None, log=print, peer_solvers: tuple[str, ...] = PEER_SOLVERS) -> dict:
    """Every (scene, size) of ``plan`` x accepted method x budget, with its reference; ``cache`` (the json's
    "references", updated in place). Returns {"rows", "references", "skipped"}."""
    kind_of_device = device_kind(device)
    threads = 1 if kind_of_device == "cpu" else None
    cache = {} if cache is None else cache
    for m in methods:
        method_overrides(m, method_table)  # a typo fails here, before any work
    accept = MethodFilter(method_table, log)
    rows, refs, started = [], {}, time.perf_counter()
    for kind, sizes in plan.items():
        for n in sizes:
            ref = reference(kind, n, device, threads, ref_budget, cache, out, fresh, frames, method_table, log=log)
            refs[(kind, n)] = ref
            for method in methods:
                if not accept.accepts(kind, n, method):
                    continue
                for s, k in budgets:
                    try:
                        r = simulate(build_scene(kind, n, method, s, k, frames, method_table), device, threads)
                    except Exception as exc:  # one refused budget (dt below the float32 floor) must not stop the table
                        log(f"{kind} {n}^2 {method} {s} x {k}: {exc}")
                        continue
                    row = _with_error({"scene": kind, "n": n, "device": kind_of_device, "method": method,
                                       "substeps": s, "iterations": k, **r}, ref)
                    rows.append(row)
                    log(_line(row) + f"  [{time.perf_counter() - started:.0f} s]", flush=True)
    if peer:
        for scene in ("hanging", "swinging"):
            if scene in plan:
                rows += peer_rows(peer_sizes or plan[scene], device, refs, peer_solvers, scene)
    for (kind, n), ref in refs.items():
        if ref is not None:
            ref["check"] = self_consistency(ref, rows)
    for r in rows:  # a row's position error is resolved when it is >= 1 / RESOLVED_RATIO x the reference's halves
        ref = refs.get((r["scene"], r["n"]))
        r["pos_resolved"] = bool(ref is not None and math.isfinite(r["pos_rms_m"]) and RESOLVED_RATIO * r["pos_rms_m"]
                                 >= max(ref["half_K"]["rms_m"], ref["half_S"]["rms_m"]))
    return {"rows": rows, "references": refs, "skipped": dict(accept.refused), "cache": cache,
            "elapsed_s": time.perf_counter() - started}


def self_consistency(ref: dict, rows: list[dict]) -> dict:
    """The reference's half-K and half-S differences against the best (smallest) position error of our own
    rows of its scene and size: resolved when both are <= RESOLVED_RATIO of it."""
    own = [r["pos_rms_m"] for r in rows if r["scene"] == ref["scene"] and r["n"] == ref["n"] and not r.get("peer")
           and math.isfinite(r["pos_rms_m"])]
    best = min(own) if own else float("nan")
    worst_half = max(ref["half_K"]["rms_m"], ref["half_S"]["rms_m"])
    ratio = worst_half / best if best > 0 else float("nan")
    return {"best_row_rms_m": best, "ratio": ratio, "resolved": bool(ratio <= RESOLVED_RATIO)}


# ---------------------------------------------------------------- fronts

def pareto(points: list[tuple[float, float]]) -> list[bool]:
    """True for the points no other point beats in both coordinates (lower is better in each)."""
    out = []
    for i, (a, b) in enumerate(points):
        ok = math.isfinite(a) and math.isfinite(b)
        for j, (a2, b2) in enumerate(points):
            if ok and j != i and a2 <= a and b2 <= b and (a2 < a or b2 < b):
                ok = False
        out.append(ok)
    return out


PANELS = (("rms", "RMS structural stretch |D - L| / L"), ("pos_rms_frac", "RMS position error / cloth size"))


def plot_fronts(rows: list[dict], refs: dict, path_for, log=print) -> dict[tuple[str, int], Path]:
    """One PNG per (scene, size): ms/frame against RMS stretch and against position error, a marker series
    per method (and peer), each method's Pareto front as a line. Skipped with a message without matplotlib."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import NullFormatter
    except ImportError:
        log("matplotlib is not installed (pip install matplotlib): plots skipped")
        return {}
    written = {}
    markers = "osD^vP*Xh<>"
    for kind, n in dict.fromkeys((r["scene"], r["n"]) for r in rows):
        group = [r for r in rows if r["scene"] == kind and r["n"] == n]
        methods = list(dict.fromkeys(r["method"] for r in group))
        fig = Figure(figsize=(9, 3.8), dpi=80)
        FigureCanvasAgg(fig)
        axes = fig.subplots(1, 2)
        for ax, (key, label) in zip(axes, PANELS):
            for i, m in enumerate(methods):
                pts = [(r["ms_per_frame"], r[key]) for r in group if r["method"] == m]
                pts = [(x, max(y, 1e-12)) for x, y in pts if math.isfinite(x) and math.isfinite(y)]
                if not pts:
                    continue
                colour = f"C{i % 10}"
                ax.scatter(*zip(*pts), marker=markers[i % len(markers)], color=colour, s=22, label=m)
                front = sorted(p for p, on in zip(pts, pareto(pts)) if on)
                if len(front) > 1:
                    ax.plot(*zip(*front), color=colour, lw=1.2, alpha=0.8)
            ref = refs.get((kind, n))
            if key == "pos_rms_frac" and ref:
                half = max(ref["half_K"]["rms_m"], ref["half_S"]["rms_m"]) / CLOTH_SIZE
                if half > 0:
                    ax.axhline(half, color="grey", ls=":", lw=1, label="reference vs its half budget")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())  # a range under a decade labels every minor tick
            ax.yaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel("ms / frame")
            ax.set_ylabel(label)
            ax.grid(True, which="both", alpha=0.3)
        for ax in axes:
            ax.legend(fontsize=7)
        fig.suptitle(f"{kind} {n}² ({group[0].get('device', '')}): lines are each method's Pareto front", fontsize=9)
        fig.tight_layout()
        path = path_for(kind, n)
        fig.savefig(path)
        written[kind, n] = path
    return written


# ---------------------------------------------------------------- targets (data)

TARGETS: list[dict] = [
    {"name": "hanging 1024² ≤ 0.05% RMS, ≤ 0.5% max, ≤ 6 ms", "device": "cuda", "scene": "hanging", "n": 1024,
     "rms": 5e-4, "max": 5e-3, "ms": 6.0},
    {"name": "hanging 1024² max ≤ 1.2e-4 under Style3D's ms/frame (same run)", "device": "cuda", "scene": "hanging",
     "n": 1024, "max": 1.2e-4, "ms": "newton-style3d"},
    {"name": "hanging 2048² ≤ 0.1% RMS, ≤ 1% max, ≤ 25 ms", "device": "cuda", "scene": "hanging", "n": 2048,
     "rms": 1e-3, "max": 1e-2, "ms": 25.0},
    {"name": "drape 1024² ≤ 0.5% RMS, ≤ 5% max, ≤ 10 ms", "device": "cuda", "scene": "drape", "n": 1024,
     "rms": 5e-3, "max": 5e-2, "ms": 10.0},
    {"name": "CPU one core, hanging 64² ≤ 0.01% RMS, ≤ 0.1% max, ≤ 5 ms", "device": "cpu", "scene": "hanging", "n": 64,
     "rms": 1e-4, "max": 1e-3, "ms": 5.0},
    {"name": "CPU one core, hanging 256² ≤ 0.1% RMS", "device": "cpu", "scene": "hanging", "n": 256, "rms": 1e-3},
]
"""Reference limits the benchmark checks its rows against. "ms" is a number or the method of a peer row whose
ms/frame (same scene, size and run) is the limit. Stretch limits are fractions (0.05% = 5e-4)."""


def judge_targets(rows: list[dict], targets: list[dict] | None = None) -> list[dict]:
    """For each target whose scene, size and device were run: the cheapest own row meeting every limit, or the
    row that comes closest (the smallest worst value / limit) and that factor."""
    out = []
    for t in TARGETS if targets is None else targets:
        own = [r for r in rows if r["scene"] == t["scene"] and r["n"] == t["n"] and r.get("device") == t["device"]
               and not r.get("peer")]
        if not own:
            continue
        res = {"target": t["name"], "row": None, "factor": float("nan"), "status": "", "limit_ms": None}
        limits = {k: t[k] for k in ("rms", "max") if k in t}
        if "ms" in t:
            ms = t["ms"]
            if isinstance(ms, str):
                peer = [r for r in rows if r["method"] == ms and r["scene"] == t["scene"] and r["n"] == t["n"]
                        and math.isfinite(r["ms_per_frame"])]
                if not peer:
                    res["status"] = f"not judged: {ms} was not run (--peer)"
                    out.append(res)
                    continue
                ms = peer[0]["ms_per_frame"]
            limits["ms_per_frame"] = ms
            res["limit_ms"] = ms

        def factor(r):
            vals = [r[k] / lim for k, lim in limits.items()]
            return max(vals) if all(math.isfinite(v) for v in vals) else float("inf")

        meeting = [r for r in own if factor(r) <= 1.0]
        if meeting:
            best = min(meeting, key=lambda r: r["ms_per_frame"])
            res.update(row=best, factor=factor(best), status="met")
        else:
            best = min(own, key=lambda r: (factor(r), r["ms_per_frame"]))
            f = factor(best)
            worst = max(limits, key=lambda k: best[k] / limits[k])
            res.update(row=best, factor=f, status=f"missed by ×{f:.3g} ({'ms' if worst == 'ms_per_frame' else worst})")
        out.append(res)
    return out


# ---------------------------------------------------------------- output

def _pct(v: float) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v * 100:.4g}%"


def _sci(v) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.3g}"


def rows_table(rows: list[dict]) -> list[str]:
    net = any(r.get("torn") is not None for r in rows)
    head = ["method", "S × K", "ms/frame", "RMS stretch", "max stretch", "RMS, 2nd half", "max, 2nd half",
            "pos RMS (m)", "pos max (m)", "pos RMS / size", "pos max / size", "pos resolved",
            "deepest inside (m)"] + (["torn sticks"] if net else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["method"], f"{r['substeps']} × {r['iterations']}", f"{r['ms_per_frame']:.3g}", _pct(r["rms"]),
                 _pct(r["max"]), _pct(r.get("rms_late")), _pct(r.get("max_late")), _sci(r["pos_rms_m"]),
                 _sci(r["pos_max_m"]), _pct(r["pos_rms_frac"]), _pct(r["pos_max_frac"]),
                 "yes" if r.get("pos_resolved") else "no", _inside(r)]
        cells += [str(r["torn"]) if r.get("torn") is not None else "—"] if net else []
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def targets_table(judged: list[dict]) -> list[str]:
    if not judged:
        return ["No reference limit covers the scenes, sizes and device run here."]
    lines = ["| target | row (method, S × K) | ms/frame | RMS stretch | max stretch | result |", "|---|---|---|---|---|---|"]
    for j in judged:
        r = j["row"]
        limit = f" (limit {j['limit_ms']:.3g} ms)" if isinstance(j.get("limit_ms"), float) else ""
        if r is None:
            lines.append(f"| {j['target']} | — | — | — | — | {j['status']} |")
        else:
            lines.append(f"| {j['target']} | {r['method']} {r['substeps']} × {r['iterations']} | "
                         f"{r['ms_per_frame']:.3g}{limit} | {_pct(r['rms'])} | {_pct(r['max'])} | {j['status']} |")
    return lines


def write_outputs(res: dict, out: Path, stem: str, device: str, command: list[str], plot: bool = True,
                  targets: list[dict] | None = None, log=print) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    rows, refs = res["rows"], res["references"]
    m = machine(device)
    pngs = {}
    if plot:
        pngs = {key: p.name for key, p in plot_fronts(rows, refs, lambda k, n: out / f"{stem}-{k}-{n}.png", log=log).items()}
    judged = judge_targets(rows, targets)
    lines = [f"# Convergence: {m}", "", *m.lines(command), f"- device: {device}"
             + (" (one relaxation thread: threads = 1)" if device_kind(device) == "cpu" else ""),
             f"- run time: {res.get('elapsed_s', float('nan')):.0f} s, references included "
             f"({sum(1 for r in refs.values() if r and not r.get('cached'))} computed, "
             f"{sum(1 for r in refs.values() if r and r.get('cached'))} cached)", "",
             "ms/frame: the fastest of up to 6 blocks of frames 3..N, each block's mean (frame 1 initialises, frame 2 "
             "captures the frame's graph; the json's ms_per_frame_mean is the mean over all blocks). Stretch "
             "|D - L| / L over intact structural sticks, and particle distance to the reference, at the last frame "
             "(hanging and torn_net 1 s, drape 1.5 s). Cloth size 1 m. See `bench/convergence.py` for the scenes.", ""]
    if res.get("skipped"):
        why: dict[tuple[str, str], list[str]] = {}
        for (k, m_), problem in res["skipped"].items():
            why.setdefault((m_, problem), []).append(k)
        lines += ["Methods skipped (the installed warp_verlet or the scene refuses them):", "",
                  *(f"- {m_} on {', '.join(ks)}: {problem}" for (m_, problem), ks in why.items()), ""]
    lines += ["## References", "",
              "First accepted method of " + ", ".join(f"{m} ({b[device_kind(device)][0]} × {b[device_kind(device)][1]})"
                                                     for m, b in REFERENCE_ORDER) + " (or --ref); its RMS distance to the same run at half "
              f"its K and at half its S must be ≤ {RESOLVED_RATIO:.2g} × a row's position error for that error "
              "to be resolved (the rows' \"pos resolved\" column; \"resolved\" here: is the best row's). "
              "Stretch needs no reference and is resolved at every row.", "",
              "| scene | grid | method | S × K | RMS / max stretch | torn | vs half K (m) | vs half S (m) | best row (m) | "
              "resolved | run |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for (kind, n), ref in refs.items():
        if ref is None:
            lines.append(f"| {kind} | {n}² | none | — | — | — | — | — | — | no | — |")
            continue
        c = ref.get("check", {})
        lines.append(f"| {kind} | {n}² | {ref['method']} | {ref['substeps']} × {ref['iterations']} | "
                     f"{_pct(ref['rms'])} / {_pct(ref['max'])} | {ref['torn'] if ref['torn'] is not None else '—'} | "
                     f"{_sci(ref['half_K']['rms_m'])} | {_sci(ref['half_S']['rms_m'])} | {_sci(c.get('best_row_rms_m'))} | "
                     f"{'yes' if c.get('resolved') else 'no'} (×{_sci(c.get('ratio'))}) | "
                     f"{'%.0f s' % ref['wall_s']}{' (cached)' if ref.get('cached') else ''} |")
    for kind, n in dict.fromkeys((r["scene"], r["n"]) for r in rows):
        group = [r for r in rows if r["scene"] == kind and r["n"] == n]
        lines += ["", f"## {kind} {n}²", "", *rows_table(group)]
        if (kind, n) in pngs:
            lines += ["", f"![{kind} {n}²]({pngs[kind, n]})"]
    lines += ["", "## Reference limits", "",
              "The cheapest row meeting every limit, else the closest row (smallest worst value / limit) "
              "and the factor it misses by. Own methods only.", "", *targets_table(judged)]
    md = out / f"{stem}.md"
    md.write_text("\n".join(lines) + "\n")
    clean = [{k: v for k, v in r.items() if k != "positions"} for r in rows]
    data = {"machine": str(m), "device": device, "date": m.when.isoformat(timespec="seconds"),
            "command": " ".join(["python", "-m", *command]), "elapsed_s": res.get("elapsed_s"), "rows": clean,
            "references": res["cache"],
            "reference_checks": {f"{k}-{n}": ref.get("check") for (k, n), ref in refs.items() if ref},
            "targets": [{**{k: v for k, v in j.items() if k != "row"},
                         "row": None if j["row"] is None else {k: j["row"][k] for k in
                                                               ("method", "substeps", "iterations", "ms_per_frame",
                                                                "rms", "max")}} for j in judged]}
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1, default=_json_default))
    log(f"wrote {md}, {out / f'{stem}.json'}" + (f" and {len(pngs)} PNGs" if pngs else ""))
    return data


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(type(v))


def load_cache(path: Path) -> dict:
    try:
        return json.loads(path.read_text()).get("references", {}) or {}
    except (OSError, ValueError):
        return {}


# ---------------------------------------------------------------- command line

def _budget(text: str) -> tuple[int, int]:
    s, k = text.lower().replace("×", "x").split("x")
    return int(s), int(k)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    p = arg_parser("bench.convergence", __doc__)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    p.add_argument("--methods", nargs="+", default=list(METHODS),
                   help=f"methods of METHODS ({', '.join(METHODS)}), combined with '+' (default: all)")
    p.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES))
    p.add_argument("--sizes", type=int, nargs="*", default=None, help="hanging and swinging grid sizes")
    p.add_argument("--drape-sizes", type=int, nargs="*", default=None)
    p.add_argument("--net-sizes", type=int, nargs="*", default=None)
    p.add_argument("--budgets", type=_budget, nargs="+", default=None, metavar="SxK")
    p.add_argument("--ref", type=_budget, default=None, metavar="SxK", help="the reference's budget")
    p.add_argument("--frames", type=int, default=None, help="override every scene's frames (smoke tests)")
    p.add_argument("--peer", action="store_true", help="run Newton Style3D and VBD on the hanging cloth too")
    p.add_argument("--peer-sizes", type=int, nargs="*", default=None)
    p.add_argument("--peer-solvers", nargs="+", choices=PEER_SOLVERS, default=list(PEER_SOLVERS),
                   help="which of Newton's solvers --peer runs (default: both)")
    p.add_argument("--out", type=Path, default=Path("bench/results/convergence"))
    p.add_argument("--stem", default="convergence", help="output names: STEM.md, STEM.json, STEM-SCENE-N.png")
    p.add_argument("--fresh", action="store_true", help="recompute the references even when cached")
    p.add_argument("--no-plot", action="store_true")
    args = p.parse_args(argv)
    quiet_warp()
    wp.init()
    device = str(wp.get_device(args.device or ("cuda" if wp.is_cuda_available() else "cpu")))
    kind = device_kind(device)
    for m in args.methods:
        try:
            method_overrides(m)
        except KeyError as exc:
            p.error(str(exc.args[0]))
    sizes = {"hanging": args.sizes, "swinging": args.sizes, "drape": args.drape_sizes, "torn_net": args.net_sizes}
    plan = {s: (sizes[s] if sizes[s] is not None else DEFAULT_SIZES[kind][s]) for s in args.scenes}
    plan = {s: v for s, v in plan.items() if v}
    cache = load_cache(args.out / f"{args.stem}.json")
    res = run(plan, args.methods, args.budgets or DEFAULT_BUDGETS[kind], device, args.ref, args.out, cache,
              args.fresh, args.frames, args.peer, args.peer_sizes, peer_solvers=tuple(args.peer_solvers))
    write_outputs(res, args.out, args.stem, device, ["bench.convergence", *argv], plot=not args.no_plot)
    for j in judge_targets(res["rows"]):
        print(f"target {j['target']}: {j['status']}")
    print(f"{res['elapsed_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
