"""A scene simulated in real time, under interactive control: the part of ``warp-verlet live`` that knows no
browser (warp_verlet/apps/live_app.py draws it with viser), so that it is tested and measured on its own.

Time: each ``tick(wall_seconds)`` banks the wall time that passed and runs the fixed substeps it pays for
(``Simulator.advance``, clamped against stalls); the display interpolates between the last two substeps.

Edits arrive from other threads (the GUI's callbacks) and take effect at the next frame boundary, so every
frame stays ``substeps`` equal steps of 1/fps seconds and a recording is a cache like ``run``'s:

- settings the model does not hold (wind, substeps, iterations, target stretch) retune the solver over the
  same model (``Simulator.retune``);
- a released pin or another tear threshold is another scene: it is checked as a scene file would be
  (``scene.check_scene``), built into a new simulator, which continues from the old one's state
  (``Simulator.take_state``; tears carried over by their particle pairs).

A session made with ``waiting=True`` (``warp-verlet live``) holds still until ``start()`` (the live page calls it when
its first page connects): the simulation and its recording begin then, not when the server starts, so that a cloth
drop is not over, and its recording padded with idle frames, before anyone sees it.

Every frame since the last reset is kept (up to ``record_limit`` bytes) and ``save()`` writes them through the
same writer and the same atomic output as ``run`` (warp_verlet/apps/runner.py, output_file.py). The frames are kept on
the simulation's device, as a copy of its positions array: on a GPU that copy costs microseconds, where a copy to
the host of a 1024 x 1024 cloth (12 MB, into freshly allocated pages) cost 10 ms a frame and held the live page
below real time. ``save()`` brings them to the host one at a time.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import SceneError, WarpVerletError
from .runner import CacheVertices, check_initial_state, divergence_reason, open_writer
from ..input.scene import Scene, check_scene

RECORD_LIMIT_BYTES = 2 << 30  # frames kept for save(): 2 GiB (170 frames of a 1024 x 1024 cloth)
RECORD_DEVICE_SHARE = 0.5  # and at most this share of the GPU memory free when the recording starts
NEVER_TEARS = 1e30  # the tear threshold that "tearing off" becomes once sticks have torn: none tears again
EVENT_LOG_LENGTH = 12
# Stalls are summed into one line of the event log, rewritten at most this often and replacing the previous stall
# line, so that a simulation slower than real time does not push the user's own edits out of the log.
STALL_REPORT_SECONDS = 1.0


@dataclass(frozen=True)
class Pin:
    """One pinned particle of one cloth, as the scene names it."""

    cloth: int  # index into scene.cloths
    key: tuple[int, int] | int  # (row, col) of a grid, or the particle index of a mesh

    def label(self, scene: Scene) -> str:
        name = scene.cloths[self.cloth].name
        if isinstance(self.key, tuple):
            return f"{name}: row {self.key[0]}, col {self.key[1]}"
        return f"{name}: particle {self.key}"


@dataclass(frozen=True)
class Readout:
    """What the screen shows, sampled once per display update."""

    frame: int  # frames simulated since the last reset
    seconds: float  # simulated seconds since the last reset
    paused: bool
    waiting: bool  # not started yet (``LiveSession.start``): nothing is simulated or recorded
    frames_per_second: float  # simulated frames per wall second, over the last second
    ms_per_frame: float  # wall milliseconds of simulation per simulated frame, over the last second
    stretch_rms: float
    stretch_max: float
    torn: int
    substeps: int
    iterations: int
    recorded: int  # frames held for save()
    recording_full: bool


@dataclass(frozen=True)
class RecordedFrame:
    frame: int
    positions: "warp.array"  # every particle's position at the frame, a copy on the simulation's device (its order)
    to_cache: CacheVertices  # positions -> each cloth's cache vertices, for the simulator that made them
    centres: np.ndarray  # every collider's sample (each sphere's centre), as a cache of dragged colliders takes them
    hidden: list[np.ndarray] | None  # per cloth, faces beside torn sticks, when they changed this frame

    def points(self) -> list[np.ndarray]:
        """Per cloth, its cache vertices, float32, on the host."""
        return self.to_cache(self.to_cache.model.to_scene_order(self.positions.numpy()))


class _Stalls:
    """The stalls since the event log's last stall line."""

    def __init__(self):
        self.count = 0
        self.worst = 0.0  # the most wall seconds one tick dropped
        self.dropped = 0.0  # wall seconds dropped in all
        self.since = math.inf  # when the first of them began

    def add(self, dropped: float, began: float) -> None:
        self.count += 1
        self.worst = max(self.worst, dropped)
        self.dropped += dropped
        self.since = min(self.since, began)


class LiveSession:
    """``scene`` running on ``device`` under interactive control. Every public method is thread-safe.

    ``waiting``: hold still (nothing simulated, nothing recorded but the starting pose) until :meth:`start`."""

    def __init__(self, scene: Scene, device: str | None = None, record_limit: int = RECORD_LIMIT_BYTES,
                 clock: Callable[[], float] = time.perf_counter, waiting: bool = False):
        from ..core.simulator import Simulator  # imports warp

        self.device = device
        self.scene = scene
        self.sim = Simulator(scene, device)
        check_initial_state(scene, self.sim)
        self.record_limit = record_limit
        self._clock = clock
        self._lock = threading.RLock()
        self._pending: list[Callable[[], None]] = []
        self._pause_requested = False
        self.paused = False
        self.diverged = False
        self.waiting = waiting
        self.events: collections.deque[str] = collections.deque(maxlen=EVENT_LOG_LENGTH)
        # Per tick over the last second: (when it ended, wall seconds it simulated for, frames it completed).
        self._ticks: collections.deque[tuple[float, float, int]] = collections.deque()
        self._stalls = _Stalls()
        self._stall_reported = -math.inf  # when the last stall line was written
        self._stall_line: str | None = None  # that line, as the event log holds it
        self._stall_most = 0.0  # the wall seconds a tick banks at most, when the last stall happened
        self._drawn: tuple[np.ndarray, np.ndarray] | None = None  # set_drawn: particles, split points per cloth
        self._start_recording()
        self.log(f"built on {self.sim.device}: {self.sim.model.particle_count} particles, "
                 f"{self.sim.model.stick_count} sticks")
        if waiting:
            self.log("waiting for a page to connect: the simulation and its recording start then")

    def start(self) -> None:
        """End the wait of a session made with ``waiting=True``: from now on ticks simulate, and the recording
        starts again from this moment's frame 0 (the wall time spent waiting is not caught up). Nothing happens
        when the session is running already (a second page connecting)."""
        with self._lock:
            if not self.waiting:
                return
            self.waiting = False
            self._apply_pending()
            self._start_recording()
            self.log("started: simulating and recording from frame 0")

    # ------------------------------------------------------------------ time
    def tick(self, wall_seconds: float) -> float:
        """Run the substeps that ``wall_seconds`` of real time pays for (none while paused); apply edits at
        the frame boundaries they wait for. Returns the display's interpolation factor in [0, 1).

        One tick banks at most two frames (``max_frame_time`` when that is less): when the simulation is slower
        than real time it runs in slow motion, drawn after every tick or two frames, instead of queueing
        ``max_frame_time`` of substeps per tick (seconds between draws on a large grid). What is dropped is
        logged as a stall."""
        with self._lock:
            start = self._clock()
            if self.paused or self.diverged or self.waiting:
                self._apply_pending()
                self._note_wall(start)  # no frames: the rate readout falls to 0 within a second
                self._report_stalls(start)
                return 1.0  # paused at a frame boundary: draw that frame itself
            most = min(2.0 / self.sim.settings.fps, self.sim.settings.max_frame_time)
            dropped = max(wall_seconds - most, 0.0)
            alpha = self.sim.advance(min(wall_seconds, most), on_frame=self._on_frame)
            while (self._pending or self._pause_requested) and not self.diverged:
                if not self.sim.at_frame_boundary:
                    break
                self._apply_pending()
                if self._pause_requested:
                    self.paused, self._pause_requested = True, False
                    self.log(f"paused at frame {self.frame}")
                    break
                alpha = self.sim.advance(0.0, on_frame=self._on_frame)
            dropped += self.sim.clamped_seconds
            now = self._clock()
            if dropped > 0.0:
                self._stalls.add(dropped, began=now - wall_seconds)
                self._stall_most = most
            self._report_stalls(now)
            self._note_wall(start)
            return alpha

    def _report_stalls(self, now: float) -> None:
        """The stalls so far as one line of the event log, in place of the previous stall line: the first stall
        at once, then at most one line every STALL_REPORT_SECONDS, counting the stalls since the last line."""
        stalls = self._stalls
        if not stalls.count or now - self._stall_reported < STALL_REPORT_SECONDS:
            return
        why = (f"(a tick banks at most {self._stall_most * 1e3:.0f} ms of wall time); the simulation runs slower "
               "than real time")
        if stalls.count == 1:
            text = f"stalled: {stalls.worst * 1e3:.0f} ms of wall time dropped {why}"
        else:
            span = now - max(stalls.since, self._stall_reported)
            text = (f"stalled {stalls.count} times in the last {span:.1f} s, worst {stalls.worst * 1e3:.0f} ms, "
                    f"{stalls.dropped * 1e3:.0f} ms of wall time dropped in all {why}")
        if self._stall_line is not None and self._stall_line in self.events:
            self.events.remove(self._stall_line)
        self.log(text)
        self._stall_line = self.events[-1]
        self._stall_reported = now
        self._stalls = _Stalls()

    def _note_wall(self, start: float) -> None:
        now = self._clock()
        self._ticks.append((now, now - start, self._frames_done))
        self._frames_done = 0
        while now - self._ticks[0][0] > 1.0:
            self._ticks.popleft()

    def _on_frame(self) -> bool:
        """At each frame boundary: count it, guard against divergence, note tears, record. True stops the
        stepping there (an edit or a pause is waiting, or the simulation diverged)."""
        self.frame += 1
        self._frames_done += 1
        model = self.sim.model
        particle = self.sim.diverged_particle()
        if particle is not None:
            slot = next(s for s in model.cloths if s.first <= particle < s.first + s.count)
            point = self.sim.positions()[particle]
            self.diverged = True
            self.log(f"diverged at frame {self.frame}: particle {particle - slot.first} of cloth '{slot.name}' is "
                     f"{divergence_reason(point, self.sim.settings.position_bound)}; paused, press Reset")
            return True
        hidden = None
        if model.tears:
            count = self.sim.torn_count()
            if count != self._torn:
                self.log(f"frame {self.frame}: {count - self._torn} stick(s) tore ({count} torn)")
                self._torn = count
                hidden = self._hidden = model.hidden_faces(self.sim.sync_tears())
                self._tears_seen = True
        self._record(hidden)
        return bool(self._pending) or self._pause_requested

    # ------------------------------------------------------------------ controls
    def pause(self) -> None:
        """Pause at the end of the frame being simulated."""
        with self._lock:
            if not self.paused:
                self._pause_requested = True
                if self.sim.at_frame_boundary:
                    self.paused, self._pause_requested = True, False
                    self.log(f"paused at frame {self.frame}")

    def play(self) -> None:
        with self._lock:
            self._pause_requested = False
            if self.paused:
                self.paused = False
                self.log(f"playing from frame {self.frame}")

    def step_frame(self) -> None:
        """One frame, while paused (to the next frame boundary)."""
        with self._lock:
            if self.diverged or self.waiting:
                return
            self._apply_pending()
            start = self._clock()
            self.sim.finish_frame(on_frame=self._on_frame)
            self._note_wall(start)
            if self._pause_requested:  # a pause asked for mid-frame: this frame's boundary is where it stops
                self.paused, self._pause_requested = True, False
                self.log(f"paused at frame {self.frame}")

    def reset(self) -> None:
        """Back to the scene's start: rest pose, nothing torn, spheres at their start, recording emptied. Edits
        made since (wind, pins released, ...) stay."""
        with self._lock:
            self.sim.reset()
            self.diverged = False
            self._apply_pending()
            self._start_recording()
            self.log("reset")

    def set_wind(self, direction, strength: float) -> None:
        """Wind as an acceleration of ``strength`` m/s^2 along ``direction`` (any length)."""
        d = np.asarray(direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if not (np.isfinite(strength) and strength >= 0.0) or not np.isfinite(norm):
            raise WarpVerletError(f"wind strength must be a finite number >= 0 m/s^2, got {strength}")
        wind = tuple(float(v) for v in (d / norm * strength if norm > 0.0 else np.zeros(3)))
        self._edit(f"wind {strength:g} m/s^2 along ({', '.join(f'{v:.2f}' for v in d / max(norm, 1e-30))})",
                   lambda: self.sim.retune(wind=wind))

    def set_substeps(self, substeps: int) -> None:
        self._edit(f"substeps {substeps}", lambda: self.sim.retune(substeps=int(substeps)))

    def set_iterations(self, iterations: int) -> None:
        self._edit(f"iterations {iterations}", lambda: self.sim.retune(iterations=int(iterations)))

    def set_target_stretch(self, target: float | None) -> None:
        """Let the budget choose the substeps to keep RMS stretch under ``target`` (a fraction); None: the
        fixed substeps again."""
        if target is not None and not 0.0 < target < 1.0:
            raise WarpVerletError(f"target stretch must be a fraction in (0, 1), got {target}")
        self._edit(f"target stretch {target:g}" if target else "fixed substeps",
                   lambda: self.sim.retune(target_stretch=target))

    def set_tear_threshold(self, threshold: float | None) -> None:
        """Every cloth tears beyond ``threshold`` x a stick's rest length (None: none tears)."""
        if threshold is not None and not (np.isfinite(threshold) and threshold > 1.0):
            raise WarpVerletError(f"tear threshold must be a number > 1 (a multiple of the rest length), got {threshold}")
        for spec in self.scene.cloths:
            if threshold is not None and spec.mesh is not None and spec.mesh.mesh.non_manifold_edges:
                raise WarpVerletError(f"cloth '{spec.name}' has non-manifold edges, and tearing needs a manifold mesh")

        def edited() -> Scene:  # from the state when the edit applies
            value = threshold
            if value is None and self.sim.torn_count() > 0:
                value = NEVER_TEARS  # no more tears, and the torn sticks stay torn (a model without tearing has none)
            return replace(self.scene, cloths=tuple(replace(c, tear_threshold=value) for c in self.scene.cloths))
        self._edit(f"tear threshold {threshold:g}" if threshold else "tearing off", lambda: self._rebuild(edited()))

    def pins(self) -> list[Pin]:
        """The pins still holding, in scene order."""
        with self._lock:
            out = []
            for i, spec in enumerate(self.scene.cloths):
                keys = spec.mesh.pins if spec.mesh is not None else spec.pins
                out += [Pin(i, tuple(k) if isinstance(k, tuple) else int(k)) for k in keys]
            return out

    def release_pin(self, pin: Pin) -> None:
        """Let one pinned particle go (and the tethers that hung from it)."""
        def edited() -> Scene:  # from the scene as it is when the edit applies (after earlier releases)
            spec = self.scene.cloths[pin.cloth]
            if spec.mesh is not None:
                spec = replace(spec, mesh=replace(spec.mesh, pins=tuple(p for p in spec.mesh.pins if p != pin.key)))
            else:
                spec = replace(spec, pins=tuple(p for p in spec.pins if tuple(p) != pin.key))
            return replace(self.scene, cloths=self.scene.cloths[:pin.cloth] + (spec,) + self.scene.cloths[pin.cloth + 1:])
        self._edit(f"released {pin.label(self.scene)}", lambda: self._rebuild(edited()))

    def move_sphere(self, index: int, centre) -> None:
        """Put sphere ``index`` (scene order) at ``centre`` (m) now. Spheres with a path keep to their path."""
        with self._lock:
            sphere = self.scene.spheres[index]
            if sphere.moving:
                raise WarpVerletError(f"sphere '{sphere.name}' follows its keyframed path and cannot be dragged")
            centres = self.sim.state.sphere_centres.numpy()
            centres[index] = np.asarray(centre, dtype=np.float32)
            self.sim.state.sphere_centres.assign(centres)

    def sphere_centres(self) -> np.ndarray:
        with self._lock:
            state = self.sim.state
            return state.sphere_centres.numpy().copy() if state.sphere_centres is not None else np.zeros((0, 3))

    def _edit(self, what: str, apply: Callable[[], None]) -> None:
        """Queue ``apply`` for the next frame boundary (now, when the simulation is at one and not running)."""
        def run():
            try:
                apply()
                self.log(what)
            except (WarpVerletError, SceneError) as exc:
                self.log(f"refused: {what}: {exc}")
        with self._lock:
            self._pending.append(run)
            if self.sim.at_frame_boundary and (self.paused or self.diverged or self.waiting):
                self._apply_pending()

    def _apply_pending(self) -> None:
        pending, self._pending = self._pending, []
        for run in pending:
            run()

    def _rebuild(self, scene: Scene) -> None:
        """A new simulator for an edited scene, continuing from the current state."""
        check_scene(scene)
        from ..core.simulator import Simulator

        old = self.sim
        new = Simulator(scene, self.device, threads=old.threads if old.device.is_cpu else None)
        new.retune(**{k: getattr(old.settings, k) for k in ("wind", "substeps", "iterations", "target_stretch")})
        new.take_state(old)  # its reset() still goes back to the scene's start
        old.close()
        self.sim, self.scene = new, scene
        self._torn = new.torn_count()
        # The same faces as before: tears carry over (take_state), and "tearing off" keeps them (NEVER_TEARS).
        self._hidden = new.model.hidden_faces(new.torn_sticks()) if self._torn else self._no_faces()
        self._to_cache = CacheVertices(new.model, scene, override=False)

    # ------------------------------------------------------------------ reading
    def log(self, text: str) -> None:
        with self._lock:
            self.events.append(f"{self.frame / self.sim.settings.fps:7.2f} s  {text}")

    def event_lines(self) -> list[str]:
        """The event log, oldest first: a copy, since other threads append to it."""
        with self._lock:
            return list(self.events)

    def readout(self) -> Readout:
        with self._lock:
            stretch = self.sim.device_stretch()
            frames = sum(n for _, _, n in self._ticks)
            spent = sum(w for _, w, _ in self._ticks)
            window = self._clock() - self._ticks[0][0] + self._ticks[0][1] if self._ticks else 0.0
            return Readout(
                frame=self.frame, seconds=self.frame / self.sim.settings.fps, paused=self.paused or self.diverged,
                waiting=self.waiting,
                frames_per_second=frames / window if window > 0 else 0.0,
                ms_per_frame=1e3 * spent / frames if frames else 0.0,
                stretch_rms=stretch.rms, stretch_max=stretch.max, torn=self.sim.torn_count(),
                substeps=self.sim.substeps, iterations=self.sim.settings.iterations,
                recorded=len(self._recording), recording_full=self._recording_full)

    def current_points(self) -> list[np.ndarray]:
        """Each cloth's cache vertices now (float32, all of them): what a frame of the recording holds."""
        with self._lock:
            return self._to_cache(self.sim.positions())

    def set_drawn(self, vertices: list[np.ndarray | None]) -> None:
        """Which vertices of each cloth :meth:`drawn_points` returns (None: all of them)."""
        particles, sizes = [], []
        for slot, chosen in zip(self.sim.model.cloths, vertices):
            topology = slot.topology
            chosen = np.arange(topology.vertex_count) if chosen is None else np.asarray(chosen)
            of_vertex = chosen if topology.vertex_particle is None else topology.vertex_particle[chosen]
            particles.append(slot.first + of_vertex)
            sizes.append(len(chosen))
        with self._lock:
            self._drawn = (np.concatenate(particles).astype(np.int32), np.cumsum(sizes)[:-1])

    def drawn_points(self, alpha: float) -> list[np.ndarray]:
        """The drawn vertices of each cloth (``set_drawn``; all by default), ``alpha`` of the way through the last
        substep (``Simulator.render_positions``), float32, gathered on the device: only they cross to the
        host."""
        with self._lock:
            if self._drawn is None:
                self.set_drawn([None] * len(self.sim.model.cloths))
            particles, splits = self._drawn
            return np.split(self.sim.render_points(particles, alpha), splits)

    def hidden_faces(self) -> list[np.ndarray]:
        """Per cloth, the faces beside torn sticks (as of the last frame boundary)."""
        with self._lock:
            return self._hidden

    # ------------------------------------------------------------------ recording
    def _start_recording(self) -> None:
        self.frame = 0
        self._frames_done = 0
        self._torn = self.sim.torn_count()
        self._hidden = self._no_faces()
        self._tears_seen = False
        self._to_cache = CacheVertices(self.sim.model, self.scene, override=False)
        self._recording: list[RecordedFrame] = []
        self._recorded_bytes = 0
        self._record_budget = self.record_limit
        device = self.sim.device
        if device.is_cuda:  # the frames live in GPU memory: leave the rest of it to the simulation and others
            self._record_budget = min(self.record_limit, int(RECORD_DEVICE_SHARE * device.free_memory))
        self._recording_full = False
        self._recorded_scene = self.scene
        self._record(None)

    def _no_faces(self) -> list[np.ndarray]:
        return [np.zeros(0, np.int32) for _ in self.sim.model.cloths]

    def _record(self, hidden) -> None:
        import warp as wp  # imported by the simulator already

        if self._recording_full:
            return
        positions = self.sim.state.particle_q
        size = positions.capacity
        if self._recorded_bytes + size > self._record_budget:
            self._recording_full = True
            self.log(f"recording full at frame {self.frame - 1} ({self._record_budget / 2**20:.0f} MiB); Save "
                     f"writes frames 0-{self.frame - 1}")
            return
        copy = wp.clone(positions)  # on the device, in the stream's order: no wait for the GPU
        with self._lock:
            samples = self.sim.colliders.moving_centres(self.sim.state, always_moving=True)
        self._recording.append(RecordedFrame(self.frame, copy, self._to_cache, samples, hidden))
        self._recorded_bytes += size

    def save(self, path: str | Path, note: Callable[[str], None] | None = None) -> int:
        """Write the frames since the last reset to ``path`` as a point cache (the output is replaced only when
        the whole cache is written); returns the frame count."""
        from ..output.output_file import CacheOutput, input_files

        with self._lock:
            frames = list(self._recording)
            scene, sim, tears = self.scene, self.sim, self._tears_seen
        path = Path(path)
        scene = replace(scene, output=replace(scene.output, path=path, kind="cache", torn_faces="remove"))
        target = CacheOutput(path, inputs=input_files(scene), note=note)
        with target:
            writer = open_writer(scene, sim, target, len(frames), every_sphere_moves=True, tears=tears)
            with writer:
                for f in frames:
                    # Save runs on its own thread: each frame's copy to the host is a Warp call, made under the
                    # lock so that it never runs beside the simulation's own (one frame at a time, so the live
                    # page waits a copy, not the whole save).
                    with self._lock:
                        points = f.points()
                    writer.write_frame(f.frame, points, f.centres, f.hidden)
            target.commit()
        self.log(f"saved frames 0-{frames[-1].frame} to {path}")
        return len(frames)

    def close(self) -> None:
        with self._lock:
            self.sim.close()
