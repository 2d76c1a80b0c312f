"""What ``warp-verlet live`` costs per frame, and how many frames per second it shows, at each grid size.

For the benchmark's hanging cloth at each size, at the README's throughput budget (4 substeps x 8 iterations,
no tethers: the rubber sheet at scale) or, with ``--substeps 32 --iterations 1 --tethers``, at the budget the
convergence section recommends (what a user who wants cloth, not rubber, runs live), the cloth then starting
level and swinging down about its pinned edge (hung where it hangs, tethers hold it still):

- sim ms/frame: one real-time tick of 1/60 s through ``LiveSession.tick`` (``Simulator.advance``, the
  divergence check and the recording's copy of the frame, kept on the device), synchronised;
- copy ms: ``drawn_points``: the drawn vertices (a grid over 256 quads a side is drawn as 256 x 256)
  interpolated between the last two substeps and gathered on the device, then copied to the host (every draw);
- reduce ms: making them one contiguous float32 array per cloth (nothing left to do once gathered);
- readout ms: the readouts shown 4 times a second (the stretch reduced on the device);
- send ms: those vertices assigned to the viser mesh (serialised and queued, on the loop's thread), and
  arrives ms: until a connected websocket client (a Python client reading every message, as a browser's
  would) has the message, which viser's sender flushes at its own pace (about 60 times a second);
- KB/draw: the message as it crossed the socket, beside the raw float32 KB;
- live frames/s and draws/s: the real app (``LiveApp.run``) for a few wall seconds with that client
  connected: simulated frames per wall second (60 is real time) and draws sent per second;
- the stretch the cloth reached by the end, beside the speed (RMS and max, structural sticks).

The browser's own decoding and drawing are not in these numbers: they happen in another process (and, on a
GPU machine, there is no browser). docs and the README report them beside the machine and the command.
"""

from __future__ import annotations

import statistics
import threading
import time

import warp as wp

from bench.common import arg_parser, hanging_cloth, machine, quiet_warp, write_table


class SocketClient:
    """A websocket client of the viser page that reads and counts every message, as a browser's would."""

    def __init__(self, url: str):
        import viser
        from websockets.sync.client import connect

        # The page's own subprotocol: viser refuses a client of another version.
        self.socket = connect(url.replace("http://", "ws://"), max_size=None,
                              subprotocols=[f"viser-v{viser.__version__}"])
        self.bytes = 0
        self.messages = 0
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        try:
            while True:
                data = self.socket.recv()
                self.bytes += len(data)
                self.messages += 1
        except Exception:  # noqa: BLE001 (closed)
            pass

    def wait_for_message(self, count: int, timeout: float = 60.0) -> None:
        end = time.perf_counter() + timeout
        while self.messages < count:
            if time.perf_counter() > end:
                raise TimeoutError("the page's update did not arrive")
            time.sleep(0.0001)

    def close(self):
        self.socket.close()


def median_seconds(work, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(n: int, device: str, seconds: float, port: int, substeps: int = 4, iterations: int = 8,
            tethers: bool = False) -> dict:
    from dataclasses import replace

    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    scene = hanging_cloth(n, substeps=substeps, iterations=iterations)
    # With tethers the cloth starts level and swings down: hung where it hangs, its tethers hold it still, and a
    # still cloth sends the page nothing to measure.
    scene = replace(scene, cloths=tuple(replace(c, tethers=tethers, orientation="horizontal" if tethers else
                                                c.orientation) for c in scene.cloths))
    session = LiveSession(scene, device)
    dev = session.sim.device
    for _ in range(3):  # compile and capture outside the timings
        session.tick(1 / 60)
    wp.synchronize_device(dev)
    ticks = 30 if n <= 256 or dev.is_cuda else 5

    def tick():
        session.tick(1 / 60)
        wp.synchronize_device(dev)
    sim_s = median_seconds(tick, ticks)

    app = LiveApp(session, port=port)
    display = app.displays[0]
    points = session.drawn_points(0.5)
    copy_s = median_seconds(lambda: session.drawn_points(0.5), 10)
    reduce_s = median_seconds(lambda: display.vertices(points[0]), 10)
    stretch_s = median_seconds(session.readout, 5)
    frames = []  # distinct consecutive frames: what the page is sent while the cloth moves
    for _ in range(10):
        session.tick(1 / 60)
        frames.append(display.vertices(session.drawn_points(0.5)[0]))

    client = SocketClient(app.url)
    time.sleep(1.0)  # the initial scene reaches the client
    assigns, arrivals, sizes = [], [], []
    for vertices in frames:
        before_messages, before_bytes = client.messages, client.bytes
        start = time.perf_counter()
        app.cloths[0].handle.vertices = vertices
        assigns.append(time.perf_counter() - start)
        client.wait_for_message(before_messages + 1)
        arrivals.append(time.perf_counter() - start)
        sizes.append(client.bytes - before_bytes)
    assign_s, arrive_s, received = statistics.median(assigns), statistics.median(arrivals), statistics.median(sizes)

    frame0, draws0 = session.frame, app.draws
    app.run(seconds)  # stops the server and closes the session at the end
    live_frames = (session.frame - frame0) / seconds
    draws = (app.draws - draws0) / seconds
    client.close()
    r = session.readout()
    return {
        "grid": f"{n}^2", "device": str(dev), "budget": f"{substeps}x{iterations}{' tethers' if tethers else ''}",
        "sim ms/frame": f"{1e3 * sim_s:.2f}",
        "copy ms": f"{1e3 * copy_s:.2f}", "readout ms": f"{1e3 * stretch_s:.2f}", "reduce ms": f"{1e3 * reduce_s:.2f}",
        "drawn": f"{display.drawn_vertex_count}", "raw KB": f"{frames[0].nbytes / 1024:.0f}",
        "KB/draw": f"{received / 1024:.0f}",
        "send ms": f"{1e3 * assign_s:.2f}", "arrives ms": f"{1e3 * arrive_s:.1f}", "live frames/s": f"{live_frames:.1f}", "draws/s": f"{draws:.1f}",
        "stretch RMS": f"{100 * r.stretch_rms:.3f}%", "stretch max": f"{100 * r.stretch_max:.2f}%",
    }


def main(argv=None) -> int:
    parser = arg_parser("bench.live_throughput", __doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 256, 1024])
    parser.add_argument("--device", default=None, help="cpu or cuda (default: CUDA when present)")
    parser.add_argument("--seconds", type=float, default=5.0, help="wall seconds of the live app per size")
    parser.add_argument("--port", type=int, default=8123)
    parser.add_argument("--substeps", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--tethers", action="store_true", help="tethers from the pins (off in the throughput scene)")
    parser.add_argument("--out", type=__import__("pathlib").Path, help="folder for the .md and .csv")
    args = parser.parse_args(argv)
    quiet_warp()
    rows = [measure(n, args.device, args.seconds, args.port + i, args.substeps, args.iterations, args.tethers)
            for i, n in enumerate(args.sizes)]
    m = machine(args.device)
    budget = rows[0]["budget"]
    write_table(rows, args.out, f"live-{rows[0]['device'].split(':')[0]}-{budget.replace(' ', '-')}",
                f"warp-verlet live, hanging cloth {budget}, on {m.describe() if hasattr(m, 'describe') else m}\n\n"
                f"`python -m bench.live_throughput --sizes {' '.join(map(str, args.sizes))}"
                f"{' --device ' + args.device if args.device else ''} --substeps {args.substeps} "
                f"--iterations {args.iterations}{' --tethers' if args.tethers else ''}`")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
