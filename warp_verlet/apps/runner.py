"""Batch runs: scene -> simulator -> point cache (the writer of the output's suffix: writer_registry.py), one
frame at a time, with a divergence guard.

The output is checked and locked, and the writer opened, before the first substep, so an unwritable,
busy or too small output fails before any simulation time is spent. Frames are written on a background
thread (``background_writer.py``) while the next frame is simulated, to ``NAME.partial.EXT`` beside the
output, which is renamed over the output only when the run succeeds (``output_file.py``). The cache is
closed (saved) on every exit path: an error, a divergence or Ctrl-C leaves a valid partial file holding the
frames simulated before it, and the previous output untouched; the exception carries an ``output_report``
saying where each went.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .. import __version__
from ..output.background_writer import BackgroundWriter
from ..constraints.line_solve import passes_of, why_no_lines
from ..errors import DivergenceError, SceneError
from ..output.output_file import CacheOutput, input_files
from ..input.scene import Scene
from ..writer_registry import CacheRequest, format_for
from .contact_speed import ContactSpeedWatch


# A structural stick stretched to twice its rest length: far outside anything cloth does, so the solver has
# not converged (the summary says so rather than presenting the result as a cloth).
UNCONVERGED_STRETCH = 1.0
# A cloth whose rigid structural sticks end this much longer than at rest on average (RMS): woven fabric stretches
# well under 1% under its own weight, so what shows is the relaxation's residual, a cloth that reads as rubber.
# Short of the warning above, the summary notes it, with the same advice.
RUBBERY_RMS = 0.01


@dataclass(frozen=True)
class RunSummary:
    scene: str
    output: Path
    device: str
    frames: int
    simulated_seconds: float
    wall_seconds: float
    particles: int
    sticks: int
    colours: int
    colour_balance: float
    stretch_max: float
    stretch_rms: float
    torn: int | None = None  # sticks torn by the end; None when no cloth can tear
    threads: int = 1  # CPU threads the relaxation ran on
    budget: str | None = None  # what a target_stretch budget chose (warp_verlet/core/budget.py)
    notes: tuple[str, ...] = ()  # what the run noticed about its output (leftovers of an earlier run removed)
    startup_seconds: float = 0.0  # before the first frame: the model built and the kernels loaded (not in wall)
    unconverged: str | None = None  # where the stretch check failed, and what to change (unconverged_advice)
    rubbery: str | None = None  # the cloth left over RUBBERY_RMS long, and what to change (rubbery_note)
    kernel_seconds: float = 0.0  # of which Warp's kernel modules, compiled or loaded from its kernel cache
    sweep: str = ""  # how the relaxation swept the sticks (sweep_description)
    contact_speed: str | None = None  # self-colliding particles that outran the contact (ContactSpeedWatch)

    def format(self) -> str:
        rate = self.frames / self.wall_seconds if self.wall_seconds > 0 else float("inf")
        colours = f"{self.colours} (balance max/min {self.colour_balance:.2f})" if self.colours else "none (jacobi)"
        lines = [
            f"scene            {self.scene}",
            f"output           {self.output}",
            f"device           {self.device}" + (f" (relaxation on {self.threads} threads)" if self.threads > 1 else ""),
            f"frames           {self.frames}",
            f"simulated        {self.simulated_seconds:.4f} s",
            f"startup          {self.startup_seconds:.3f} s (of which Warp's kernels {self.kernel_seconds:.3f} s, "
            "compiled or loaded from its cache; not in the wall time)",
            f"wall             {self.wall_seconds:.3f} s ({rate:.1f} frames/s, the frames alone)",
            f"particles        {self.particles}",
            f"sticks           {self.sticks}",
            f"colours          {colours}",
            *([f"sweep            {self.sweep}"] if self.sweep else []),
            f"stretch |D-L|/L  max {self.stretch_max:.3e}, rms {self.stretch_rms:.3e} (structural sticks, last frame)",
        ]
        if self.budget is not None:
            lines.append(f"budget           {self.budget}")
        if self.torn is not None:
            lines.append(f"torn sticks      {self.torn} of {self.sticks}")
        if self.stretch_max > UNCONVERGED_STRETCH:
            lines.append(
                f"warning          the sticks are far from satisfied (a structural stick at {1 + self.stretch_max:.3g} x "
                "its rest length): the relaxation has not converged"
                + (f" {self.unconverged}" if self.unconverged else ""))
        elif self.rubbery:
            lines.append(f"note             {self.rubbery}")
        if self.contact_speed:
            lines.append(f"warning          {self.contact_speed}")
        return "\n".join(lines)


def divergence_reason(point: np.ndarray, bound: float) -> str:
    return "not a finite number" if not np.isfinite(point).all() else f"beyond position_bound = {bound} m"


def run_scene(
    scene: Scene,
    output: Path | None = None,
    device: str | None = None,
    frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    overlap: bool = True,
    threads: int | None = None,
    note: Callable[[str], None] | None = None,
) -> RunSummary:
    """Simulate ``scene`` and write its point cache. ``progress(frame)`` is called after each frame.
    ``overlap=False`` writes each frame before simulating the next (for measuring what overlap saves).
    ``threads`` is the CPU relaxation's thread count (None: chosen from the cores and the grid size).
    ``note(text)`` hears what an earlier run to this output left behind (also in ``RunSummary.notes``).

    A run that does not finish raises, and ``warp_verlet.output.output_file.output_report(exc)`` says which frames
    are in the partial file and that the previous output was left as it was."""
    if frames is not None:
        scene = replace(scene, simulation=replace(scene.simulation, frames=frames))
    output = Path(output) if output is not None else scene.output.path
    target = CacheOutput(output, inputs=input_files(scene), note=note)  # checks the path; opens nothing
    with target:  # the lock: a second run to this output is refused until the cache is in place
        return _simulate(scene, output, target, device, progress, overlap, threads)


def _simulate(scene: Scene, output: Path, target: CacheOutput, device: str | None,
              progress: Callable[[int], None] | None, overlap: bool, threads: int | None) -> RunSummary:
    from ..core.simulator import Simulator, StretchStats  # imports warp

    settings = scene.simulation
    began = time.perf_counter()
    sim = Simulator(scene, device, threads=threads)
    kernel_seconds = load_kernels(sim)
    model = sim.model
    override = scene.output.kind == "override"
    check_initial_state(scene, sim)
    writer = open_writer(scene, sim, target, settings.frames + 1)
    to_cache = CacheVertices(model, scene, override)
    contact_speed = ContactSpeedWatch(scene, model)
    start = time.perf_counter()
    startup = start - began
    points = sim.positions()
    contact_speed.observe(0, points, sim.substeps)
    with writer:
        writer.write_frame(0, to_cache(points), model.colliders.moving_centres(sim.state))
        background = BackgroundWriter(writer.write_frame) if overlap else None
        write = background.submit if background else writer.write_frame
        try:
            _step_loop(sim, settings, write, progress, to_cache, contact_speed)
        finally:
            if background is not None:
                background.close()  # the frames already handed over are written before the cache is saved
    target.commit()
    wall = time.perf_counter() - start
    sim.settle_budget()  # on CUDA the last frame's stretch is read a frame late: count it before reporting
    points = sim.positions()
    per_stick, cloth = structural_by_cloth(sim, points)  # once: the stats and both checks below read it
    stretch = StretchStats.of(per_stick)
    unconverged = unconverged_advice(scene, sim, per_stick, cloth) if stretch.max > UNCONVERGED_STRETCH else None
    rubbery = rubbery_note(scene, sim, per_stick, cloth) if unconverged is None else None
    colouring = model.colouring
    return RunSummary(
        scene=scene.source, output=output, device=str(sim.device), frames=settings.frames,
        simulated_seconds=sim.time, wall_seconds=wall, particles=model.particle_count, sticks=model.stick_count,
        colours=model.colour_count, colour_balance=colouring.balance if colouring else 0.0,
        stretch_max=stretch.max, stretch_rms=stretch.rms, torn=sim.torn_count() if model.tears else None,
        threads=sim.threads, budget=sim.budget.report() if sim.budget is not None else None,
        notes=tuple(target.notes), startup_seconds=startup, kernel_seconds=kernel_seconds, unconverged=unconverged,
        rubbery=rubbery, sweep=sweep_description(model), contact_speed=contact_speed.advice(),
    )


SWEEP_FORMS = {
    "explicit": "stick arrays, a launch per colour",
    "implicit": "grid sticks computed in the kernels, a launch per colour",
    "tiled": "grid sticks computed in the kernels, tile by tile in shared memory",
    "clustered": "stick arrays, cluster by cluster in shared memory",
}


def sweep_description(model) -> str:
    """How the model's sticks are swept (Simulator's ``sticks``, "auto" resolved), and why "auto" did not cluster
    them where it chose to and the layout was refused."""
    if model.stick_count == 0:
        return "no sticks"
    if model.relaxation == "jacobi":
        return "stick arrays, a Jacobi gather per particle"
    form = SWEEP_FORMS[model.sticks_form]
    if model.sticks_form == "clustered" and model.constraints["stick clusters"].neighbour is not None:
        form += ", chained (one launch a sweep)"
    return form if model.clusters_refused is None else f"{form} (clustered refused: {model.clusters_refused})"


def structural_by_cloth(sim, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stretch |D - L| / L of every intact structural stick (what ``sim.stretch`` summarises), and the index of
    the cloth each belongs to."""
    model = sim.model
    torn = sim.torn_sticks() if model.tears else None
    keep = np.flatnonzero(model.structural if torn is None else model.structural & ~torn)
    firsts = np.array([slot.first for slot in model.cloths])
    cloth = np.searchsorted(firsts, model.host_sticks[keep, 0], side="right") - 1
    return model.structural_stretch(points, torn), cloth


def unconverged_advice(scene: Scene, sim, stretch: np.ndarray, cloth: np.ndarray) -> str:
    """Where the stretch check failed (the cloth of the longest structural stick; ``stretch`` and ``cloth`` from
    structural_by_cloth) and what would help that cloth, from what the scene already has. Whether a budget
    converges depends on the run (how far the sweeps of a frame carry a correction against the load), so this is
    said after it, not predicted."""
    where, advice = _advice(scene, sim, int(cloth[int(np.argmax(stretch))]))
    return f"in {where} {advice}"


def rubbery_note(scene: Scene, sim, stretch: np.ndarray, cloth: np.ndarray) -> str | None:
    """The cloth whose rigid structural sticks end longest on average (RMS; ``stretch`` and ``cloth`` from
    structural_by_cloth), where that is over RUBBERY_RMS, and what would help it; None where every such cloth is
    within it. A cloth with soft structural sticks (``compliance``) stretches by its own stiffness, and is not
    counted."""
    worst, worst_rms = None, RUBBERY_RMS
    for index, spec in enumerate(scene.cloths):
        mine = stretch[cloth == index]
        if not len(mine) or "structural" in spec.compliance:
            continue
        rms = float(np.sqrt(np.mean(mine ** 2)))
        if rms > worst_rms:
            worst, worst_rms = index, rms
    if worst is None:
        return None
    where, advice = _advice(scene, sim, worst)
    return (f"{where} ends {worst_rms:.1%} longer than at rest (RMS over its structural sticks; woven cloth stretches "
            f"under 1%): the relaxation has not converged {advice}")


def _advice(scene: Scene, sim, index: int) -> tuple[str, str]:
    """Cloth ``index`` named, and the run's budget with what would help that cloth converge."""
    spec, settings = scene.cloths[index], sim.settings
    shape = f"a {spec.resolution[0]} x {spec.resolution[1]} grid" if spec.mesh is None else \
        f"a mesh of {spec.particle_count} particles"
    load = float(np.linalg.norm(np.add(settings.gravity, settings.wind)))
    fixes = []
    if settings.iterations == 0:
        fixes.append("iterations (0 relaxes no stick)")
    elif settings.target_stretch is None:
        fixes.append("more substeps (smaller steps converge more per sweep than more iterations do), or "
                     "target_stretch to choose them")
    else:
        fixes.append("a higher max_substeps (see the budget line)")
    if spec.pin_count and not spec.uses_tethers:
        fixes.append("tethers = true (with a tether_scale above its tear_threshold)" if spec.tear_threshold
                     else "tethers = true")
    if not passes_of(spec) and why_no_lines(spec) is None:
        fixes.append(line_pass_advice(spec))
    # The multilevel pass moves fine particles by their coarse neighbours' moves, which knows nothing of contact:
    # a cloth that only colliders hold up stretches more with it (docs/method.md), so it is offered to pinned cloth.
    if spec.mesh is None and spec.pin_count and not spec.tears and not settings.multilevel:
        fixes.append("multilevel = true")
    fixes.append(f"or a lighter load (gravity + wind: {load:.3g} m/s^2)")
    return (f"cloth '{spec.name}' ({shape})",
            f"at {sim.substeps} substeps x {settings.iterations} iterations a frame; what helps: {'; '.join(fixes)}")


def line_pass_advice(spec) -> str:
    """What line passes would take for the grid cloth ``spec``: a cloth that colliders hold up drapes only if its
    shear and bend sticks are soft, and its landing converges only while it moves under about a sixth of its
    spacing a substep (bench/results/line_solve/README.md)."""
    advice = "line_passes = 1"
    if spec.pin_count == 0:
        spacing = min(size / (n - 1) for size, n in zip(spec.size, spec.resolution) if n > 1)
        rigid = [f for f in ("shear", "bend") if f in spec.sticks and f not in spec.compliance]
        soft = (f" and a compliance on its {' and '.join(rigid)} sticks (rigid, they make it a plate that cannot "
                f"drape)") if rigid else ""
        advice += (f"{soft}; a cloth landing on a collider holds its length with line passes once it moves under "
                   f"about a sixth of its spacing, {spacing / 6 * 1000:.2g} mm, a substep")
    return advice


def load_kernels(sim) -> float:
    """Load the Warp kernel modules the run launches onto its device before the clock starts (Warp loads a
    module at its first launch, compiling it when its kernel cache has no copy: seconds, which would count as
    the first frame's). Binding the solver's stages records their launches, which loads their modules; the
    simulator itself launches the divergence check, the first step's start and, with a target_stretch budget,
    the stretch reduction. Only these: a module imported but never launched is not compiled. Returns the seconds
    it took."""
    import warp as wp

    from warp_verlet.kernels import guard, integrate

    start = time.perf_counter()
    sim.solver.bind(sim.state)
    modules = [guard, integrate]
    if sim.budget is not None:
        from warp_verlet.kernels import readback

        modules.append(readback)
    for module in modules:
        wp.load_module(module, device=sim.device)
    return time.perf_counter() - start


def open_writer(scene: Scene, sim, target: CacheOutput, samples: int, every_sphere_moves: bool = False,
                tears: bool = False):
    """The cache writer for ``scene``, writing to ``target``'s partial file in the format of its suffix
    (writer_registry.py), once its disk space for ``samples`` frames is checked. ``every_sphere_moves``: sample every sphere's centre per frame (a live
    session, where spheres are dragged); ``tears``: author torn faces even for cloths whose scene cannot tear
    (a live session whose tear threshold was set later)."""
    from ..colliders import by_kind

    override = scene.output.kind == "override"
    shapes = [cached_shape(s.topology, spec, override, tears) for s, spec in zip(sim.model.cloths, scene.cloths)]
    colliders = [] if override else [kind.cached(c, every_sphere_moves) for kind, specs in by_kind(scene.colliders)
                                     for c in specs]  # in clamp order, as ColliderModel.moving_centres samples
    cache_format = format_for(target.partial, override)
    request = CacheRequest(
        shapes, fps=scene.simulation.fps, colliders=colliders, up_axis=scene.output.up_axis,
        meters_per_unit=scene.output.meters_per_unit, save_every=scene.output.save_every,
        metadata={"generator": f"warp-verlet {__version__}", "scene": scene.source, "device": str(sim.device)},
        torn_faces=scene.output.torn_faces, before_save=target.before_save,
        override_asset=scene.cloths[0].mesh.mesh.source.file if override else None,
    )
    target.check_space(cache_format.estimate(request, target.partial), samples, scene.output.save_every)
    return cache_format.open(target.partial, request)


def cached_shape(topology, spec, override: bool, tears: bool = False):
    """What the cache writes of one cloth, from its topology: the vertices, faces and UVs of its source."""
    from ..output.usd_writer import CachedShape

    return CachedShape(topology.name, topology.cache_faces, topology.uvs, topology.vertex_count,
                       tears=tears or spec.tears, uv_interpolation=topology.uv_interpolation,
                       left_handed=topology.left_handed,
                       prim_path=spec.mesh.mesh.source.prim_path if override else None)


def check_initial_state(scene: Scene, sim) -> None:
    """Refuse, as a bad input, a scene whose rest pose is already not finite or beyond ``position_bound``,
    rather than report it as a divergence at frame 1. One integer comes back from the device."""
    particle = sim.diverged_particle()
    if particle is None:
        return
    index, slot = next((i, s) for i, s in enumerate(sim.model.cloths) if s.first <= particle < s.first + s.count)
    point = sim.positions()[particle]
    reason = divergence_reason(point, scene.simulation.position_bound)
    raise SceneError(scene.source, f"cloth[{index}]", f"particle {particle - slot.first} of cloth '{slot.name}' "
                     f"starts at {tuple(float(v) for v in point)} ({reason}): its origin, size or mesh "
                     "positions must put every particle within simulation.position_bound")


class CacheVertices:
    """All particles' positions, in the scene's order (Simulator.positions), -> each cloth's cache vertices,
    float32: a mesh's welded particles gathered to its vertices and, for an override layer, moved back into its
    prim's own space. A grid in float32 costs nothing: views of the one array."""

    def __init__(self, model, scene, override: bool):
        self.model = model
        self.to_local = [spec.mesh.mesh.source.to_local if override else None for spec in scene.cloths]

    def __call__(self, points: np.ndarray) -> list[np.ndarray]:
        out = []
        for slot, to_local, particles in zip(self.model.cloths, self.to_local, self.model.split(points)):
            vertices = slot.topology.cache_points(particles)
            if to_local is not None:
                vertices = vertices.astype(np.float64) @ to_local[:3, :3].T + to_local[:3, 3]
            # Converted here, once per frame, when the simulation runs in float64 (no copy in float32).
            # Divergence and stretch checks use the simulation's own precision.
            out.append(np.asarray(vertices, dtype=np.float32))
        return out


def _step_loop(sim, settings, write: Callable[..., None], progress: Callable[[int], None] | None,
               to_cache: Callable[[np.ndarray], list[np.ndarray]], contact_speed: ContactSpeedWatch) -> None:
    """Simulate frames 1 .. frames, handing each one to ``write`` (frame, points per cloth, moving sphere
    centres, hidden faces or None) and to ``contact_speed``."""
    model = sim.model
    torn = 0
    for frame in range(1, settings.frames + 1):
        substeps = sim.substeps  # a target_stretch budget may choose others for the next frame
        sim.step_frame()
        points = sim.positions()  # the one host copy per frame, which the writer needs anyway
        particle = sim.diverged_particle()  # checked on the device: one integer comes back
        if particle is not None:
            slot = next(s for s in model.cloths if s.first <= particle < s.first + s.count)
            reason = divergence_reason(points[particle], settings.position_bound)
            raise DivergenceError(frame, slot.name, particle - slot.first, points[particle], reason)
        contact_speed.observe(frame, points, substeps)
        hidden = None
        if model.tears:  # one integer per frame; the stick flags only when it changed
            count = sim.torn_count()
            if count != torn:
                torn = count
                hidden = model.hidden_faces(sim.sync_tears())
        write(frame, to_cache(points), model.colliders.moving_centres(sim.state), hidden)
        if progress is not None:
            progress(frame)
