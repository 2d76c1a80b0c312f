"""Command line: ``warp-verlet run|sweep|validate|preview`` (also ``python -m warp_verlet``).

Exit codes: 0 success, 1 a run failed (divergence, unwritable, busy or full output, device), 2 invalid scene,
cache or arguments (an output name that is no USD file or names an input, a port in use), 130 interrupted
(Ctrl-C), 143 terminated (SIGTERM), 141 standard output closed by its reader (``| head``: 128 + SIGPIPE, as a
tool that signal ends; quietly, no traceback). A run that does not finish says where its frames went
(``NAME.partial.EXT``) and that the previous output was left as it was.

Heavy modules are imported by the command that needs them: validate imports none of warp, pxr and
Mitsuba, and preview imports pxr and its renderer (Mitsuba) but never warp.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import warnings
from pathlib import Path

from .. import __version__
from ..core.cpu_team import MAX_THREADS, usable_cores
from ..errors import SceneError, ServerError, WarpVerletError
from ..output.output_file import OutputNameError, check_output_names, output_report, refuse_long_names
from ..input.scene import load_scene


def _count(plural: str, too_few: str, most: int | None = None):
    """An argparse type: a whole number of ``plural`` from 1 (to ``most``), each error naming what it counts.
    ``too_few`` is the message for a value under 1 (``{value}`` filled in)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number of {plural}, got {text!r}") from None
        if value < 1:
            raise argparse.ArgumentTypeError(too_few.format(value=value))
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"expected a number of {plural} in 1 .. {most}, got {value}")
        return value

    return parse


_positive_int = _count("frames", "expected at least 1 frame, got {value}")
_thread_count = _count("threads", f"expected a number of threads in 1 .. {MAX_THREADS}, got {{value}}", MAX_THREADS)


def _gibibytes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of GiB, got {text!r}") from None
    if not 0.0 < value < 1e6:  # finite, and more than nothing
        raise argparse.ArgumentTypeError(f"expected a number of GiB in (0, 1e6), got {text}")
    return value


def _at_least_one(what: str):
    return _count(what, f"expected at least 1 ({what}), got {{value}}")


_SLICE_PART = re.compile(r"\s*(-?\d+)?\s*")  # a whole number, or nothing


def parse_frame_slice(text: str) -> slice:
    """``A:B:S`` over frame numbers (any part may be empty), or ``N`` for frame N alone."""
    parts = [_SLICE_PART.fullmatch(part) for part in text.split(":")]
    if len(parts) > 3 or not all(parts) or (len(parts) == 1 and parts[0][1] is None):
        raise argparse.ArgumentTypeError(f"expected A:B:S or N in whole frame numbers (e.g. 0:61:20), got {text!r}")
    values = [int(m[1]) if m[1] is not None else None for m in parts]
    if len(values) == 1:
        return slice(values[0], values[0] + 1)
    start, stop, step = values + [None] * (3 - len(values))
    if step is not None and step < 1:
        raise argparse.ArgumentTypeError(f"the step S must be at least 1, got {step} in {text!r}")
    return slice(start, stop, step)


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` in pixels."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected WxH in pixels (e.g. 800x600), got {text!r}")
    width, height = int(match[1]), int(match[2])
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"width and height must lie in 16 .. 8192 pixels, got {text!r}")
    return width, height


DEVICE_HELP = "cpu, cuda or cuda:N (default: CUDA when present, else CPU)"


def _device_name(text: str) -> str:
    """An argparse type: a device's name as simulator.resolve_device takes it. A name of another form is a bad
    argument (exit 2); a well-formed one that this machine lacks fails the run (exit 1)."""
    if text == "cpu" or text == "cuda" or re.fullmatch(r"cuda:\d+", text):
        return text
    raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warp-verlet",
        description="Verlet cloth simulation on NVIDIA Warp (CPU or CUDA), written as a USD point cache.",
        epilog="A scene is a TOML file: `warp-verlet validate SCENE` checks one, naming the file, the key and "
               "what was expected for each problem, and warns about settings that will not do what they say. "
               "Each command's --help lists its options.",
    )
    parser.add_argument("--version", action="version", version=f"warp-verlet {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = commands.add_parser("run", help="simulate a scene and write its USD point cache")
    run.add_argument("scene", type=Path, help="scene file (TOML; `warp-verlet validate SCENE` checks it)")
    run.add_argument("-o", "--output", type=Path, help="output .usd/.usdc/.usda (default: the scene's [output] path)")
    run.add_argument("--device", type=_device_name, help=DEVICE_HELP)
    run.add_argument("--frames", type=_positive_int, help="number of frames (default: the scene's)")
    run.add_argument("--threads", type=_thread_count,
                     help=f"CPU threads for the relaxation, 1 .. {MAX_THREADS} (default: the cores, when the grid is "
                          "large enough to gain; more than the cores only slows it down; results are "
                          "bit-identical for any count)")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    run.add_argument("-v", "--verbose", action="store_true", help="show Warp's device and kernel-compilation messages")
    run.add_argument("--preview", action="store_true",
                     help="after a successful run, also render <cache stem>.png next to the cache (as "
                          "`warp-verlet preview CACHE -o <cache stem>.png` would)")

    sweep = commands.add_parser(
        "sweep", help="run every variant of a parameter sweep (locally, or on a Ray cluster)",
        description="Run a sweep file's variants (a base scene and the keys to vary; --dry-run lists them): "
                    "one cache per variant, sweep.csv and sweep.md in the output directory. A re-run "
                    "skips the variants already done with the same parameters.",
    )
    sweep.add_argument("sweep", type=Path, help="sweep file (TOML)")
    sweep.add_argument("-o", "--output", type=Path, help="output directory (default: the sweep's [sweep] output)")
    sweep.add_argument("--device", type=_device_name, help=DEVICE_HELP)
    sweep.add_argument("--workers", type=_at_least_one("workers"),
                       help="local pool size (default: one per GPU on CUDA, one per core on the CPU)")
    sweep.add_argument("--threads", type=_thread_count,
                       help="CPU relaxation threads per variant (default: the cores shared among the workers)")
    sweep.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                       help="run each variant as a Ray task: --ray alone starts a local Ray instance, --ray auto "
                            "joins the cluster started on this machine with `ray start`, --ray ADDRESS joins that "
                            "cluster (needs pip install 'warp-verlet[ray]')")
    sweep.add_argument("--gpus-per-variant", type=float, help="Ray: num_gpus of each task on CUDA (default 1)")
    sweep.add_argument("--cpus-per-variant", type=float, help="Ray: num_cpus of each task (default 1)")
    sweep.add_argument("--restart", action="store_true", help="run every variant again (default: resume)")
    sweep.add_argument("--dry-run", action="store_true", help="list the variants and exit without running")
    sweep.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    sweep.add_argument("--frames", type=_positive_int,
                       help="every variant's number of frames (default: [sweep] frames, else the base scene's); "
                            "a resumed sweep runs again the variants done with another count")
    sweep.add_argument("-v", "--verbose", action="store_true",
                       help="show Warp's and Ray's start-up messages from the workers")

    validate = commands.add_parser("validate", help="check a scene file without running it")
    validate.add_argument("scene", type=Path)

    preview = commands.add_parser(
        "preview", help="render a USD point cache to a PNG or an animated GIF (no simulator needed)",
        description="Render a point cache headlessly, ray traced on the CPU by Mitsuba 3: a .png shows up to 4 "
                    "frames as panels, a .gif animates the frames.",
    )
    preview.add_argument("cache", type=Path, help="point cache (.usd, .usdc or .usda) written by `warp-verlet run`")
    preview.add_argument("-o", "--output", type=Path, required=True,
                         help="output image: .png (still) or .gif (animation)")
    preview.add_argument("--frames", type=parse_frame_slice, metavar="A:B:S",
                         help="frames to draw, as a Python slice over frame numbers: from A (included) to B "
                              "(excluded) every S; any part may be left out (A: the first frame, B: one past the "
                              "last, S: 1); N alone means frame N. Must lie within the cache's frames. "
                              "Default: all frames. A PNG draws at most 4 of the selected frames (the first, the "
                              "last and evenly spaced ones between) as panels; a GIF at most 120, evenly spaced")
    preview.add_argument("--size", type=parse_size, metavar="WxH",
                         help="image size in pixels (default: 800x800 for a PNG, 480x480 for a GIF)")

    live = commands.add_parser(
        "live", help="simulate a scene in real time in the browser, with controls (needs the live extra)",
        description="Serve a live page of the scene at http://HOST:PORT: play, pause, step, reset; wind, "
                    "substeps, iterations, target stretch, tear threshold; release pins; drag spheres; save "
                    "what was simulated since the last reset as a USD cache.",
    )
    live.add_argument("scene", type=Path, help="scene file (TOML; `warp-verlet validate SCENE` checks it)")
    live.add_argument("--device", type=_device_name, help=DEVICE_HELP)
    _server_arguments(live)
    live.add_argument("--record", type=Path, metavar="PATH",
                      help="where Save cache writes (default: beside the scene's output, as NAME_live.EXT); "
                           "the page can change it")
    live.add_argument("--record-limit", type=_gibibytes, metavar="GIB",
                      help="most GiB of frames kept for Save cache, on the simulation's device (default 2, "
                           "live_session.RECORD_LIMIT_BYTES; on a GPU also at most half of its free memory; a "
                           "1024 x 1024 cloth takes 12 MiB a frame)")
    live.add_argument("--seconds", type=float, help="stop after this many wall seconds (default: until Ctrl-C)")

    view = commands.add_parser(
        "view", help="play a USD point cache in the browser: timeline, play/pause, frame slider (no GPU, no Warp)",
        description="Serve a page that plays a cache written by `warp-verlet run` or by live's Save cache: "
                    "cloths, ropes, torn faces and colliders.",
    )
    view.add_argument("cache", type=Path, help="point cache (.usd, .usdc or .usda)")
    _server_arguments(view)
    view.add_argument("--seconds", type=float, help="stop after this many wall seconds (default: until Ctrl-C)")
    return parser


def _server_arguments(command) -> None:
    command.add_argument("--host", default="127.0.0.1",
                         help="address to serve on (default 127.0.0.1: this machine only). Another address, "
                              "such as 0.0.0.0, lets other machines drive the page, and warns")
    command.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080)")
    command.add_argument("--max-grid-quads", type=_at_least_one("max-grid-quads"), metavar="N",
                         help="draw a larger grid as a coarser one of N quads a side (default 256), and a mesh "
                              "of more than (N + 1)^2 vertices decimated to about that many; the simulation and "
                              "caches keep every vertex")


def _serve(app, what: str, seconds: float | None) -> int:
    print(f"{what}: open {app.url} in a browser (Ctrl-C to stop)", flush=True)
    try:
        app.run(seconds)
    except KeyboardInterrupt:
        pass
    return 0


def _live(args) -> int:
    from ..errors import OutputError
    from .live_app import default_record_path  # live_app imports neither warp nor viser at its top
    from ..output.output_file import CacheOutput, input_files
    from .web_view import check_port
    from ..core.warp_setup import start_warp

    # What can be refused is refused before Warp starts and the simulator is built (seconds on a large scene).
    scene = load_scene(args.scene)
    check_port(args.host, args.port)
    record = args.record or default_record_path(scene)
    try:
        CacheOutput(record, inputs=input_files(scene))  # checks the path only: nothing is written
        _check_creatable(record)
    except OutputError as exc:
        raise ServerError(f"{'--record' if args.record else 'the default recording path'}: {exc}") from None
    start_warp(verbose=False, cpu=args.device in (None, "cpu"), note=_note)
    from .live_app import LiveApp
    from .live_session import LiveSession

    limit = {} if args.record_limit is None else {"record_limit": int(args.record_limit * 2**30)}
    session = LiveSession(scene, args.device, waiting=True, **limit)  # starts when the first page connects
    app = LiveApp(session, args.host, args.port, record, args.max_grid_quads)
    return _serve(app, f"{args.scene}: live (the simulation starts when a page connects)", args.seconds)


def _check_creatable(path: Path) -> None:
    """Create and remove a file beside ``path``: a directory can pass the permission check and still refuse a
    new file (/proc, a read-only mount seen by root), which live would only learn at the first Save."""
    import tempfile

    from ..errors import OutputError

    try:
        with tempfile.NamedTemporaryFile(dir=Path(path).parent, prefix=".warp-verlet-probe-"):
            pass
    except OSError as exc:
        raise OutputError(f"cannot write {path}: cannot create a file in {Path(path).parent} "
                          f"({exc.strerror or exc})") from None


def _view(args) -> int:
    from .cache_player import CachePlayer
    from ..output.cache_reader import PreviewError

    try:
        app = CachePlayer(args.cache, args.host, args.port, args.max_grid_quads)
    except PreviewError as exc:  # a bad cache: the same exit code as a bad scene
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return _serve(app, f"{args.cache}", args.seconds)


def _validate(args) -> int:
    scene = load_scene(args.scene)
    check_output_names(scene.output.path, f" (output.path in {args.scene})")
    sim = scene.simulation
    print(f"{args.scene}: valid scene, {len(scene.cloths)} cloth(s), {scene.particle_count} particles, "
          f"{sim.frames} frames at {sim.fps:g} fps, {sim.substeps} substeps x {sim.iterations} iterations, "
          f"relaxation {sim.relaxation}")
    for spec in scene.cloths:
        if spec.mesh is not None:
            mesh = spec.mesh.mesh
            print(f"cloth {spec.name}: {mesh.source.description}, {len(mesh.faces)} faces, {mesh.vertex_count} "
                  f"vertices welded into {mesh.particle_count} particles (weld_distance {mesh.weld_distance:.3g} m), "
                  f"{len(spec.mesh.pins)} pinned")
    from ..core.memory import estimate  # counts only: no warp

    need = estimate(scene)
    print(f"memory: {need.describe()}")
    how = " (auto: dt is below the float32 limit)" if need.precision == "float64" and sim.precision == "auto" else ""
    print(f"positions: {need.precision}{how}")
    _warn_about(scene)
    return 0


def _warn_about(scene) -> None:
    """What the scene will not do as written (scene_warnings.py), one ``warning:`` line each on stderr."""
    from ..input.scene_warnings import scene_warnings  # numpy only

    for text in scene_warnings(scene):
        print(f"warning: {text}", file=sys.stderr)


def _note(text: str) -> None:
    print(f"note: {text}", file=sys.stderr)


def _run(args) -> int:
    scene = load_scene(args.scene)
    if args.frames is not None:  # the warnings speak of the run as it will be
        from dataclasses import replace

        scene = replace(scene, simulation=replace(scene.simulation, frames=args.frames))
    _warn_about(scene)
    from ..output.output_file import CacheOutput, input_files

    # A bad output path is refused before Warp starts (a second or more); it only checks: nothing is written.
    CacheOutput(args.output if args.output is not None else scene.output.path, inputs=input_files(scene))
    from ..core.warp_setup import start_warp

    # Quiet unless -v (Warp's banner, per-module load timings and, on a CPU run, its CUDA-driver warning),
    # and a kernel cache it can write.
    start_warp(verbose=args.verbose, cpu=args.device in (None, "cpu"), note=_note)
    from .runner import run_scene

    cores = usable_cores()
    if args.threads is not None and args.threads > cores and not (args.device or "").startswith("cuda"):
        print(f"warning: --threads {args.threads} is more than the {cores} core(s) this process can use: the "
              "relaxation will run slower, not faster (its result is the same for any count)", file=sys.stderr)

    frames = args.frames or scene.simulation.frames
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=frames, unit="frame", desc=scene.cloths[0].name if len(scene.cloths) == 1 else "scene",
                   file=sys.stderr, dynamic_ncols=True)
    try:
        summary = run_scene(scene, output=args.output, device=args.device, frames=args.frames, threads=args.threads,
                            progress=(lambda frame: bar.update(1)) if bar else None, note=_note)
    finally:
        if bar is not None:
            bar.close()
    print(summary.format())
    if args.preview:
        image = _preview_module().render_preview(summary.output, summary.output.with_suffix(".png"))
        print(f"{'preview':<17}{image}")
    return 0


def _sweep(args) -> int:
    from .sweep import load_sweep, show

    sweep = load_sweep(args.sweep, args.output, args.frames)
    if args.dry_run:
        for v in sweep.variants:
            params = ", ".join(f"{k} = {show(val)}" for k, val in v.params.items())
            print(f"{v.index:5d}  {v.name}  {params}  [{v.hash}]")
        print(f"{args.sweep}: valid sweep, {len(sweep.variants)} variants of {sweep.base}, output {sweep.output}")
        return 0
    from .sweep import run_sweep
    from .sweep_backends import make_backend

    backend = make_backend(args.device, args.workers, args.threads, args.ray, args.gpus_per_variant,
                           args.cpus_per_variant, verbose=args.verbose)
    print(f"{args.sweep}: {len(sweep.variants)} variants of {sweep.base}; {backend.description}", file=sys.stderr)
    try:
        with backend:
            result = run_sweep(sweep, backend, resume=not args.restart, progress=not args.quiet,
                               log=lambda text: print(text, file=sys.stderr))
    except KeyboardInterrupt:
        print(f"interrupted: {sweep.output}/sweep.csv and sweep.md list what finished; run the same command "
              "again to resume", file=sys.stderr)
        return 130
    statuses = {}
    for row in result.rows:
        statuses[row["status"]] = statuses.get(row["status"], 0) + 1
    tally = ", ".join(f"{n} {s}" for s, n in statuses.items())
    print(f"{len(result.rows)} variants: {tally} ({len(result.ran)} run now, {len(result.resumed)} done before) "
          f"in {result.elapsed:.1f} s")
    for row in result.rows:
        if row["status"] != "ok":
            print(f"  {row['name']}: {row['status']}: {row.get('error')}")
    print(f"summary          {result.csv}, {result.md}")
    return 0 if not result.failed else 1


def _preview_module():
    """warp_verlet.apps.preview (pxr, Mitsuba and Pillow; never warp), or one clear error when the install lacks the
    renderer (the base install brings it; an install with --no-deps does not)."""
    try:
        from . import preview
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] in ("mitsuba", "PIL"):
            raise WarpVerletError(f"the preview needs {exc.name.split('.')[0]}, part of warp-verlet's base "
                                  "install, which is missing here: pip install warp-verlet") from None
        raise
    return preview


def _preview(args) -> int:
    preview = _preview_module()
    # preview.render_preview writes the image as .NAME.PID.partial.EXT, renamed when it is complete.
    output = Path(args.output)
    refuse_long_names(output, (output.name, f".{output.stem}.{os.getpid()}.partial{output.suffix}"))
    try:
        image = preview.render_preview(args.cache, args.output, frames=args.frames, size=args.size)
    except preview.PreviewError as exc:  # a bad cache or option: the same exit code as a bad scene
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.cache}: preview written to {image}")
    return 0


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one plain line (a non-manifold mesh, say), not Python's file:line: Category: format."""
    print(f"warning: {message}", file=sys.stderr if file is None else file)


class Terminated(BaseException):
    """SIGTERM arrived: stop as Ctrl-C does (the frames so far are saved), exit 143."""


def _terminate(signum, frame):
    raise Terminated


def _where_the_frames_went(exc: BaseException) -> str:
    report = output_report(exc)
    return report.describe() if report is not None else "nothing was written"


STDOUT_CLOSED = 128 + signal.SIGPIPE if hasattr(signal, "SIGPIPE") else 141


def _stdout_closed() -> int:
    """The reader of standard output went away (``warp-verlet validate scene.toml | head -1``): stop quietly.
    Python's recipe (the library reference's note on SIGPIPE): point stdout at devnull, so that the interpreter's
    own flush at exit does not raise again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout is no file (captured by a test harness)
        pass
    return STDOUT_CLOSED


def main(argv: list[str] | None = None) -> int:
    """The console script: the command's exit code (see the module's docstring)."""
    try:
        try:
            return _main(argv)
        finally:  # also after --help and argparse's errors (SystemExit), whose text may sit in the buffer
            sys.stdout.flush()
    except BrokenPipeError:
        return _stdout_closed()


def _main(argv: list[str] | None) -> int:
    warnings.showwarning = _show_warning
    args = build_parser().parse_args(argv)
    command = {"run": _run, "validate": _validate, "preview": _preview, "sweep": _sweep, "live": _live,
               "view": _view}[args.command]
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if in_main_thread else None
    try:
        return command(args)
    except BrokenPipeError:
        raise  # main's: the reader of stdout went away
    except (SceneError, ServerError, OutputNameError) as exc:  # bad input: nothing was run
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except WarpVerletError as exc:
        print(f"error: {exc}", file=sys.stderr)
        report = output_report(exc)
        if report is not None and report.partial is not None:
            print(report.describe(), file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"interrupted: {_where_the_frames_went(exc)}", file=sys.stderr)
        return 130
    except Terminated as exc:
        print(f"terminated: {_where_the_frames_went(exc)}", file=sys.stderr)
        return 143
    except Exception as exc:  # a bug: its traceback follows, and where the frames went before it
        report = output_report(exc)
        if report is not None:
            print(f"error: {report.describe()}", file=sys.stderr)
        raise
    finally:
        if in_main_thread and previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
