"""``warp-verlet live``: a scene simulated in real time and shown in the browser, with its controls.

The page (viser, warp_verlet/apps/web_view.py) holds the controls; a :class:`~warp_verlet.apps.live_session.LiveSession`
holds the simulation. A session made waiting (``warp-verlet live`` makes it so) starts when the first page
connects. The loop here ticks the session with the wall time that passed, and sends the cloth's
interpolated vertices (float32, binary) at most ``DRAW_HZ`` times a second and the readouts four times a second.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..colliders import by_kind
from .display_mesh import DisplayMesh
from ..errors import WarpVerletError
from .live_session import LiveSession, Pin
from ..input.scene import Scene
from .web_view import CLOTH_COLOURS, LOCALHOST, DEFAULT_PORT, ClothDrawing, frame_camera, start_server

DRAW_HZ = 60.0
READOUT_HZ = 4.0
MAX_WIND = 50.0  # m/s^2 on the strength slider (gravity is 9.81)
MAX_SUBSTEPS_SLIDER = 64
MAX_ITERATIONS_SLIDER = 128


class LiveApp:
    """The page of one live session. ``run()`` serves it until ``stop()`` (or Ctrl-C)."""

    def __init__(self, session: LiveSession, host: str = LOCALHOST, port: int = DEFAULT_PORT,
                 record_path: Path | None = None, max_grid_quads: int | None = None):
        self.session = session
        scene = session.scene
        self.server = start_server(host, port, up_axis="Y")
        self.url = f"http://{host}:{self.server.get_port()}"
        self._stop = threading.Event()
        self.send_seconds = 0.0  # wall time of the last update's sends (serialising and queueing)
        self.draws = 0
        self._showing_budget = False  # show_readouts is setting the substeps slider to the budget's choice
        self._saves: list[threading.Thread] = []  # Save runs on its own thread; run() waits for them at exit
        model = session.sim.model
        kwargs = {} if max_grid_quads is None else {"max_grid_quads": max_grid_quads}
        start = session.current_points()  # a large mesh is decimated for display on its starting pose
        self.displays = [DisplayMesh(s.topology.cache_faces, s.topology.vertex_count,
                                     (s.topology.rows, s.topology.cols) if s.topology.is_grid else None,
                                     rest_points=points, **kwargs)
                         for s, points in zip(model.cloths, start)]
        session.set_drawn([d.vertex_index for d in self.displays])
        points = session.drawn_points(0.0)
        self.cloths = [ClothDrawing(self.server, spec.name, display, p, CLOTH_COLOURS[i % len(CLOTH_COLOURS)])
                       for i, (spec, display, p) in enumerate(zip(scene.cloths, self.displays, points))]
        self._add_colliders(scene)
        everything = np.concatenate(points + [np.asarray(p)[None] for d in self._collider_drawings.values()
                                              for p in d.points])
        frame_camera(self.server, everything.min(0), everything.max(0))
        self._build_gui(scene, record_path or default_record_path(scene))
        self.server.on_client_connect(self._page_connected)

    def _page_connected(self, _client) -> None:
        """A page connected (on viser's thread): a session waiting for one starts now, and the page says so until
        the first readout (the first steps load the kernels, which can take seconds)."""
        if self.session.waiting:
            self.frame_text.value = "0  (0.00 s)  starting"
            self.session.start()

    # ------------------------------------------------------------------ scene
    def _add_colliders(self, scene: Scene) -> None:
        """Each kind draws its colliders (warp_verlet/colliders: add_to_live)."""
        self._collider_drawings = {kind.type: kind.add_to_live(self, specs)
                                   for kind, specs in by_kind(scene.colliders)}

    @property
    def _sphere_list(self) -> list:
        """The spheres drawn (their handles and gizmos), as the live page's tests reach them."""
        drawing = self._collider_drawings.get("sphere")
        return drawing.items if drawing is not None else []

    def guarded(self, action: Callable[[], None]) -> None:
        """Run an action of a control that a collider kind added (a drag), as the page's own (:meth:`_guard`)."""
        self._guard(action)

    # ------------------------------------------------------------------ GUI
    def _build_gui(self, scene: Scene, record_path: Path) -> None:
        gui, session = self.server.gui, self.session
        sim = session.sim
        with gui.add_folder("Simulation"):
            self.play_button = gui.add_button("Pause")
            self.play_button.on_click(lambda _: self._guard(self._toggle_play))
            step = gui.add_button("Step frame")
            step.on_click(lambda _: self._guard(session.step_frame))
            reset = gui.add_button("Reset")
            reset.on_click(lambda _: self._guard(session.reset))
        with gui.add_folder("Readouts"):
            self.frame_text = gui.add_text("Frame", self._frame_line(session.readout()), disabled=True)
            self.rate_text = gui.add_text("Sim rate", "", disabled=True, hint="simulated frames per wall second "
                                          "and wall ms per simulated frame (1 s average)")
            self.stretch_text = gui.add_text("Stretch", "", disabled=True,
                                             hint="RMS and max |D - L| / L over the structural sticks")
            self.torn_text = gui.add_text("Torn sticks", "0", disabled=True)
            self.draw_text = gui.add_text("Display", "", disabled=True,
                                          hint="draws per second, ms and KB to send one draw's vertices (float32)")
            notes = [d.note for d in self.displays if d.note]
            if notes:
                gui.add_markdown("**Reduced for display:** " + "; ".join(notes)
                                 + ". The simulation runs at full size.")
        with gui.add_folder("Wind"):
            wind = np.asarray(sim.settings.wind, float)
            strength = float(np.linalg.norm(wind))
            direction = wind / strength if strength > 0 else np.array([0.0, 0.0, 1.0])
            self.wind_direction = gui.add_vector3("Direction", tuple(float(v) for v in direction), step=0.1)
            self.wind_strength = gui.add_slider("Strength m/s²", 0.0, MAX_WIND, 0.1, min(strength, MAX_WIND))
            for handle in (self.wind_direction, self.wind_strength):
                handle.on_update(lambda _: self._guard(lambda: session.set_wind(self.wind_direction.value,
                                                                                self.wind_strength.value)))
        with gui.add_folder("Solver"):
            self.substeps = gui.add_slider("Substeps", 1, max(MAX_SUBSTEPS_SLIDER, sim.substeps), 1, sim.substeps)
            self.substeps.on_update(self._substeps_edited)
            iterations = sim.settings.iterations
            self.iterations = gui.add_slider("Iterations", 0, max(MAX_ITERATIONS_SLIDER, iterations), 1, iterations)
            self.iterations.on_update(lambda _: self._guard(lambda: session.set_iterations(self.iterations.value)))
            target = sim.settings.target_stretch
            self.target = gui.add_number("Target stretch %", 100 * target if target else 0.0, min=0.0, max=99.0,
                                         step=0.01, hint="RMS stretch the substeps are chosen to stay under; 0: "
                                         "the fixed substeps above")
            self.target.on_update(lambda _: self._guard(
                lambda: session.set_target_stretch(self.target.value / 100 if self.target.value > 0 else None)))
        with gui.add_folder("Tearing"):
            threshold = scene.cloths[0].tear_threshold
            self.tear = gui.add_number("Tear threshold", threshold or 0.0, min=0.0, step=0.05,
                                       hint="a stick tears beyond this multiple of its rest length (> 1); 0: never")
            self.tear.on_update(lambda _: self._guard(
                lambda: session.set_tear_threshold(self.tear.value if self.tear.value > 0 else None)))
        with gui.add_folder("Pins"):
            self._pins: dict[str, Pin] = {}
            self.pin_choice = gui.add_dropdown("Pin", ["(none)"])
            self.release = gui.add_button("Release pin")
            self.release.on_click(lambda _: self._guard(self._release_pin))
            self._refresh_pins()
        with gui.add_folder("Record"):
            self.record_path = gui.add_text("Cache path", str(record_path))
            self.recorded_text = gui.add_text("Recorded", "1 frame", disabled=True)
            save = gui.add_button("Save cache", hint="write every frame since the last reset as a USD point cache")
            save.on_click(lambda _: self._guard(self._save))
        with gui.add_folder("Log"):
            self.log_text = gui.add_markdown("")

    def _guard(self, action: Callable[[], None]) -> None:
        """Run a control's action; a refusal goes to the event log instead of a traceback on the server."""
        try:
            action()
        except WarpVerletError as exc:
            self.session.log(f"refused: {exc}")
        except OSError as exc:  # a path the checks let through that the system refuses: said, not a traceback
            where = f" {exc.filename}" if exc.filename else ""
            self.session.log(f"refused: cannot write{where}: {exc.strerror or exc}")

    def _substeps_edited(self, _) -> None:
        # viser calls this also when show_readouts sets the slider to what the target-stretch budget chose: that
        # is no edit (retuning would reset the budget's history and log substeps the user never set).
        if not self._showing_budget:
            self._guard(lambda: self.session.set_substeps(self.substeps.value))

    def _toggle_play(self) -> None:
        if self.session.paused:
            self.session.play()
        else:
            self.session.pause()

    def _refresh_pins(self) -> None:
        scene = self.session.scene
        self._pins = {pin.label(scene): pin for pin in self.session.pins()}
        options = list(self._pins) or ["(none)"]
        self.pin_choice.options = options
        self.pin_choice.value = options[0]

    def _release_pin(self) -> None:
        pin = self._pins.get(self.pin_choice.value)
        if pin is not None:
            self.session.release_pin(pin)  # the dropdown follows once the release has applied (show_readouts)

    def _save(self) -> None:
        from ..output.output_file import check_output_names  # the checks `live --record` had at start, for a path typed in the page

        path = Path(self.record_path.value).expanduser()

        def save() -> None:
            check_output_names(path)
            self.session.save(path)
        thread = threading.Thread(target=self._guard, args=(save,), daemon=True)
        self._saves.append(thread)
        thread.start()

    # ------------------------------------------------------------------ loop
    def draw(self, alpha: float) -> None:
        """Send the cloths' vertices (interpolated by ``alpha``) and the spheres' centres."""
        points = self.session.drawn_points(alpha)
        hidden = self.session.hidden_faces()
        start = time.perf_counter()
        for drawing, p, h in zip(self.cloths, points, hidden):
            drawing.update(p, h)
        for drawing in self._collider_drawings.values():
            if drawing.update is not None:
                drawing.update()
        self.send_seconds = time.perf_counter() - start
        self.draws += 1

    def show_readouts(self, draw_rate: float) -> None:
        r = self.session.readout()
        self.play_button.label = "Play" if r.paused else "Pause"
        self.frame_text.value = self._frame_line(r)
        self.rate_text.value = f"{r.frames_per_second:.0f} frames/s, {r.ms_per_frame:.2f} ms/frame"
        self.stretch_text.value = f"RMS {100 * r.stretch_rms:.3f}%, max {100 * r.stretch_max:.2f}%"
        self.torn_text.value = str(r.torn)
        kb = sum(c.bytes_sent for c in self.cloths) / 1024
        self.draw_text.value = f"{draw_rate:.0f} draws/s, {1e3 * self.send_seconds:.2f} ms, {kb:.0f} KB"
        self.recorded_text.value = (f"{r.recorded} frame{'s' if r.recorded != 1 else ''}"
                                    + ("  (full)" if r.recording_full else ""))
        if r.substeps != self.substeps.value and self.session.sim.budget is not None:
            self._showing_budget = True
            try:
                self.substeps.value = r.substeps  # what the target_stretch budget chose
            finally:
                self._showing_budget = False
        self.log_text.content = "\n".join(f"`{line}`  " for line in reversed(self.session.event_lines()))
        if list(self._pins.values()) != self.session.pins():  # a release has applied
            self._refresh_pins()

    @staticmethod
    def _frame_line(r) -> str:
        state = "  waiting for a page" if r.waiting else "  paused" if r.paused else ""
        return f"{r.frame}  ({r.seconds:.2f} s){state}"

    def run(self, seconds: float | None = None) -> None:
        """Tick, draw and show readouts until ``stop()``, Ctrl-C, or ``seconds`` of wall time."""
        start = last = last_draw = last_readout = time.perf_counter()
        draws_at_readout = 0
        alpha = 0.0
        try:
            while not self._stop.is_set():
                now = time.perf_counter()
                if seconds is not None and now - start >= seconds:
                    break
                alpha = self.session.tick(now - last)
                last = now
                if now - last_draw >= 1.0 / DRAW_HZ:
                    self.draw(alpha)
                    last_draw = now
                if now - last_readout >= 1.0 / READOUT_HZ:
                    self.show_readouts((self.draws - draws_at_readout) / (now - last_readout))
                    draws_at_readout, last_readout = self.draws, now
                # Sleep until the next draw is due (the simulation catches up through the accumulator).
                time.sleep(max(0.0, 1.0 / DRAW_HZ - (time.perf_counter() - now)))
        finally:
            saving = [t for t in self._saves if t.is_alive()]
            if saving:
                print(f"waiting for {len(saving)} cache save(s) to finish", file=sys.stderr)
                for thread in saving:
                    thread.join()
            self.server.stop()
            self.session.close()

    def stop(self) -> None:
        self._stop.set()


def default_record_path(scene: Scene) -> Path:
    """Beside the scene's output, named NAME_live.EXT, so that saving never replaces a batch run's cache."""
    out = scene.output.path
    return out.with_name(f"{out.stem}_live{out.suffix}")
