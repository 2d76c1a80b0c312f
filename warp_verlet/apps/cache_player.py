"""``warp-verlet view CACHE``: play a point cache in the browser, with a frame slider, play and pause.

Reads the cache with pxr (warp_verlet/output/cache_reader.py, as the PNG/GIF preview does) and draws its cloths,
ropes, torn faces and colliders with viser (warp_verlet/apps/web_view.py). Never imports Warp: a cache plays on
any machine, GPU or not.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from ..output.cache_reader import FrameGeometry, PreviewError, open_cache, read_frame
from .display_mesh import DisplayMesh, rope_segments
from ..colliders.mesh import draw_mesh
from ..colliders.plane import draw_plane
from ..colliders.sphere import draw_sphere
from .web_view import (CLOTH_COLOURS, DEFAULT_PORT, LOCALHOST, ROPE_COLOUR, ROPE_THICKNESS_M, ClothDrawing,
                       frame_camera, start_server)

TICK_SECONDS = 1 / 120  # how often the loop looks at the clock while playing


class CachePlayer:
    """The page of one cache. ``run()`` serves it until ``stop()`` (or Ctrl-C)."""

    def __init__(self, cache_path: str | Path, host: str = LOCALHOST, port: int = DEFAULT_PORT,
                 max_grid_quads: int | None = None):
        self.cache = cache = open_cache(cache_path)  # PreviewError for anything that is not a cache
        first = read_frame(cache, cache.frames[0])  # a damaged first frame fails before the server starts
        if not any(len(c.points) for c in first.cloth_frames) and not any(len(r) for r in first.ropes):
            # The camera is framed on the first frame's points; a cache with none there has nothing to show.
            raise PreviewError(f"{cache.path}: frame {cache.frames[0]}, the first, holds no readable points for "
                               "any cloth or rope: a damaged or empty cache, nothing to draw")
        last = read_frame(cache, cache.frames[-1]) if len(cache.frames) > 1 else first  # as the first frame
        self.server = start_server(host, port, up_axis=cache.up_axis)
        self.url = f"http://{host}:{self.server.get_port()}"
        self._stop = threading.Event()
        self._lock = threading.Lock()
        kwargs = {} if max_grid_quads is None else {"max_grid_quads": max_grid_quads}
        self.displays = {}
        self.cloths = {}
        for i, c in enumerate(first.cloth_frames):
            name = str(c.cloth.prim.GetPath().name)
            self.displays[name] = DisplayMesh(c.cloth.faces, len(c.points), c.grid, rest_points=c.points, **kwargs)
            self.cloths[name] = ClothDrawing(self.server, name, self.displays[name], c.points,
                                             CLOTH_COLOURS[i % len(CLOTH_COLOURS)])
        self.ropes = [self.server.scene.add_line_segments(f"/ropes/{i}", rope_segments(r), colors=ROPE_COLOUR,
                                                          thickness=ROPE_THICKNESS_M / max(self._metres(), 1e-12))
                      for i, r in enumerate(first.ropes)]
        self.spheres = [draw_sphere(self.server, f"sphere{i}", centre, radius)
                        for i, (centre, radius) in enumerate(first.spheres)]
        for i, corners in enumerate(first.planes):
            draw_plane(self.server, f"plane{i}", corners)
        self.meshes = [draw_mesh(self.server, f"mesh{i}", points, triangles) for i, (points, triangles)
                       in enumerate(first.meshes)]
        self._mesh_points = [points for points, _ in first.meshes]  # as drawn: a moving mesh is drawn again
        everything = np.concatenate([g for frame in (first, last) for g in
                                     [c.points for c in frame.cloth_frames] + list(frame.ropes)
                                     + [c[None] for c, _ in frame.spheres]])
        frame_camera(self.server, everything.min(0), everything.max(0), cache.up_axis)  # the first and last frames
        self.frame = cache.frames[0]
        self.playing = False
        self._build_gui()

    def _metres(self) -> float:
        from pxr import UsdGeom

        return UsdGeom.GetStageMetersPerUnit(self.cache.stage)

    def _build_gui(self) -> None:
        gui, frames = self.server.gui, self.cache.frames
        gui.add_markdown(f"**{self.cache.path.name}**: frames {frames[0]}-{frames[-1]} at {self.cache.fps:g} fps")
        self.play_button = gui.add_button("Play")
        self.play_button.on_click(lambda _: self.toggle())
        self.slider = gui.add_slider("Frame", frames[0], max(frames[-1], frames[0] + 1), 1, frames[0],
                                     disabled=len(frames) < 2)
        self.slider.on_update(lambda _: self.show(int(self.slider.value)))
        self.loop = gui.add_checkbox("Loop", True)
        self.time_text = gui.add_text("Time", f"{frames[0] / self.cache.fps:.3f} s", disabled=True)
        notes = [d.note for d in self.displays.values() if d.note]
        if notes:
            gui.add_markdown("**Reduced for display:** " + "; ".join(notes) + ". The cache holds every vertex.")

    def toggle(self) -> None:
        self.playing = not self.playing
        self.play_button.label = "Pause" if self.playing else "Play"
        if self.playing and self.frame >= self.cache.frames[-1]:  # Play at the end plays again from the start
            self.slider.value = self.cache.frames[0]

    def show(self, frame: int) -> None:
        """Draw ``frame`` (the nearest frame the cache holds)."""
        frames = self.cache.frames
        frame = min(max(frame, frames[0]), frames[-1])
        with self._lock:
            try:
                geometry = read_frame(self.cache, frame)
            except PreviewError as exc:  # a damaged frame between good ones: said on the page, the last one kept
                self.time_text.value = f"{frame / self.cache.fps:.3f} s: cannot draw it ({exc})"
                self.frame = frame
                return
            self._draw(geometry)
            self.frame = frame
        self.time_text.value = f"{frame / self.cache.fps:.3f} s"

    def _draw(self, geometry: FrameGeometry) -> None:
        for c in geometry.cloth_frames:
            drawing = self.cloths.get(str(c.cloth.prim.GetPath().name))
            if drawing is not None and len(c.points) == drawing.display.vertex_count:
                drawing.update(c.points, c.hidden)
        for handle, rope in zip(self.ropes, geometry.ropes):
            handle.points = rope_segments(rope)
        for handle, (centre, _) in zip(self.spheres, geometry.spheres):
            handle.position = tuple(float(v) for v in centre)
        for k, (handle, (points, _)) in enumerate(zip(self.meshes, geometry.meshes)):
            if len(points) == len(self._mesh_points[k]) and not np.array_equal(points, self._mesh_points[k]):
                handle.vertices = points.astype(np.float32)
                self._mesh_points[k] = points

    def run(self, seconds: float | None = None) -> None:
        """Serve until ``stop()``, Ctrl-C or ``seconds``; while playing, frames follow the cache's fps."""
        start = time.perf_counter()
        clock = start
        frames = self.cache.frames
        try:
            while not self._stop.is_set() and (seconds is None or time.perf_counter() - start < seconds):
                time.sleep(TICK_SECONDS)
                now = time.perf_counter()
                if not self.playing or len(frames) < 2:
                    clock = now
                    continue
                due = int((now - clock) * self.cache.fps)
                if due < 1:
                    continue
                clock += due / self.cache.fps
                nxt = self.frame + due
                if nxt > frames[-1]:
                    if not self.loop.value:  # stop on the last frame, drawn
                        if self.frame != frames[-1]:
                            self.slider.value = frames[-1]
                        self.toggle()
                        continue
                    nxt = frames[0] + (nxt - frames[-1] - 1) % len(frames)
                self.slider.value = nxt  # its on_update draws the frame
        finally:
            self.server.stop()

    def stop(self) -> None:
        self._stop.set()
