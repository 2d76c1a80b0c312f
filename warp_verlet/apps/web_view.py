"""What the two browser views share (``warp-verlet live`` and ``warp-verlet view``): the local web server, the
camera, and the drawing of cloths, ropes and colliders.

The server is viser's (https://viser.studio): a Python 3D viewer served to a web page over one websocket, with
GUI controls (buttons, sliders, dropdowns), three.js rendering and transform gizmos, kept up by its authors and
used by nerfstudio and others. Writing our own WebGL page and websocket protocol would be a second product;
viser gives both, and sends numpy arrays as binary (msgpack), so a frame's positions travel as raw float32, not
JSON text. It is an optional extra (``pip install warp-verlet[live]``); nothing else imports it.

Safety: the server binds to 127.0.0.1 unless ``--host`` says otherwise, with a warning (the page controls the
simulation and writes files where it is told), and a port in use is one clear error rather than viser's silent
move to the next port.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import warnings
from typing import Sequence
from urllib.parse import urlsplit

import numpy as np

from .display_mesh import DisplayMesh, rope_segments
from ..errors import ServerError

LOCALHOST = "127.0.0.1"
DEFAULT_PORT = 8080
# Cloths take the preview's colours (warp_verlet/apps/preview.py), as 0-255 RGB.
CLOTH_COLOURS = ((204, 84, 61), (59, 120, 184), (92, 158, 84), (217, 158, 51))
ROPE_COLOUR = (38, 38, 38)
ROPE_THICKNESS_M = 0.005
# The camera aims this fraction of the half-height of the view right of the content: the control panel covers
# the right of the page.
PANEL_SHIFT = 0.45


def import_viser():
    try:
        import viser
    except ImportError as exc:
        raise ServerError("the browser views need viser: pip install 'warp-verlet[live]'") from exc
    return viser


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_port(host: str, port: int) -> None:
    """One clear error when ``port`` cannot be bound on ``host`` (viser would quietly take the next one)."""
    if not 1 <= port <= 65535:
        raise ServerError(f"--port must be in 1 .. 65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ServerError(f"--host {host!r} is not an address this machine can bind: {exc.strerror}") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        if os.name != "nt":  # as the server binds: a port whose old connections linger (TIME_WAIT) is free
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except PermissionError:
            raise ServerError(f"port {port} on {host} needs privileges to bind: choose --port 1024 or above") from None
        except OSError as exc:
            raise ServerError(f"port {port} on {host} is already in use (another warp-verlet live or view, or "
                              f"another server): choose another with --port, e.g. --port {port + 1}"
                              if exc.errno in (98, 48, 10048) else f"cannot bind {host}:{port}: {exc}") from None


def start_server(host: str = LOCALHOST, port: int = DEFAULT_PORT, up_axis: str = "Y"):
    """A viser server on ``host:port``, or ServerError. Binding beyond this machine warns."""
    viser = import_viser()
    if not is_loopback(host):
        warnings.warn(f"serving on {host}:{port}, reachable from other machines: anyone who can reach it can "
                      "drive this session and save files on this machine. Use the default host (127.0.0.1) "
                      "and an SSH tunnel instead where you can.", stacklevel=2)
    check_port(host, port)
    server = viser.ViserServer(host=host, port=port, verbose=False)
    if server.get_port() != port:  # taken between the check and the bind
        server.stop()
        raise ServerError(f"port {port} on {host} was taken while starting: choose another with --port")
    refuse_foreign_origins(server, is_loopback(host))
    server.scene.set_up_direction("+z" if up_axis == "Z" else "+y")
    server.gui.configure_theme(control_width="large")
    return server


class ForeignOriginError(Exception):
    """A websocket opened by a page of another web origin: raised to end viser's handler for that connection
    before it reads a message (never seen by the user: its log record is filtered out)."""


def same_origin(origin: str | None, host_header: str | None, loopback: bool) -> bool:
    """Whether a websocket handshake comes from this server's own page, or from no page at all.

    A browser lets any page open a websocket to any address, 127.0.0.1 included, and sends the page's Origin;
    only a page this server served has an Origin whose host and port are the Host it connected to. A client
    that is no browser page sends no Origin and is let in: it runs on a machine that can reach the port, which
    on the loopback is this user's own. On the loopback the host must also be a loopback name: a page whose
    own name resolves to 127.0.0.1 (DNS rebinding) would otherwise have matching Origin and Host."""
    if origin is None:
        return True
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.netloc or host_header is None:
        return False  # "null" (a file or a sandboxed frame), or no Host to compare with
    if parts.netloc.lower() != host_header.strip().lower():
        return False
    return not loopback or is_loopback((parts.hostname or "").strip("[]"))


def refuse_foreign_origins(server, loopback: bool) -> None:
    """Close, before it is read, every websocket that :func:`same_origin` refuses (code 1008, policy).

    viser 1.1 offers no hook into the handshake, so the check runs as the first of its connection callbacks
    (its internal ``WebsockServer``), which run before the connection's first message is read; raising there
    ends its handler, so nothing the page sent is ever handled."""
    import logging

    sockets = getattr(server, "_websock_server", None)
    if not all(hasattr(sockets, name) for name in ("_live_connections", "_client_state_from_id",
                                                      "_client_connect_cb")):
        warnings.warn("this viser version gives no way to check a connection's web origin: any page open in "
                      "this machine's browser can drive the session (viser 1.1 does)", stacklevel=3)
        return

    async def check(connection) -> None:
        live = sockets._live_connections.get(connection.client_id)
        if live is None:
            return
        headers = live.request.headers
        if same_origin(headers.get("Origin"), headers.get("Host"), loopback):
            return
        sockets._client_state_from_id.pop(connection.client_id, None)
        sockets._live_connections.pop(connection.client_id, None)
        await live.close(1008, "a page of another origin may not drive this session")
        raise ForeignOriginError(headers.get("Origin"))

    sockets._client_connect_cb.insert(0, check)
    logger = logging.getLogger("websockets.server")
    if not any(isinstance(f, _DropForeignOrigin) for f in logger.filters):
        logger.addFilter(_DropForeignOrigin())


class _DropForeignOrigin:
    """A logging filter: websockets logs a handler's exception with its traceback; a refused origin is none."""

    def filter(self, record) -> bool:
        return not (record.exc_info and isinstance(record.exc_info[1], ForeignOriginError))


def frame_camera(server, lo: np.ndarray, hi: np.ndarray, up_axis: str = "Y") -> None:
    """Point every new client's camera at the box [lo, hi]: from the front, a little above and to the right,
    far enough that the whole box fits, and aimed a little right of its centre so that the box sits left of the
    control panel."""
    centre = (np.asarray(lo, float) + np.asarray(hi, float)) / 2
    radius = max(float(np.linalg.norm(np.asarray(hi, float) - np.asarray(lo, float))) / 2, 1e-3)
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "Y" else np.array([0.0, 0.0, 1.0])
    view = np.array([0.45, 0.35, 1.0]) if up_axis == "Y" else np.array([0.45, -1.0, 0.35])
    view /= np.linalg.norm(view)
    fov = np.radians(50.0)  # vertical, as three.js counts it
    distance = 1.1 * radius / np.sin(fov / 2)
    right = np.cross(-view, up)
    right /= np.linalg.norm(right)
    aim = centre + right * PANEL_SHIFT * distance * np.tan(fov / 2)
    server.initial_camera.fov = float(fov)
    server.initial_camera.look_at = tuple(aim)
    server.initial_camera.position = tuple(aim + view * distance)


class ClothDrawing:
    """One cloth in the browser: a double-sided mesh whose vertices are sent each update (float32, binary),
    and whose triangles are sent again only when the torn faces change. A rope (no faces) is line segments."""

    def __init__(self, server, name: str, display: DisplayMesh, points: np.ndarray, colour=CLOTH_COLOURS[0]):
        self.display = display
        self._hidden: np.ndarray | None = None
        self.bytes_sent = 0  # positions sent by the last update
        if display.rope:
            self.handle = server.scene.add_line_segments(
                f"/cloths/{name}", rope_segments(points), colors=ROPE_COLOUR, thickness=ROPE_THICKNESS_M)
        else:
            self.handle = server.scene.add_mesh_simple(
                f"/cloths/{name}", display.vertices(points), display.triangles(), color=colour, side="double")

    def update(self, points: np.ndarray, hidden: Sequence[int] | np.ndarray = ()) -> None:
        if self.display.rope:
            segments = rope_segments(points)
            self.handle.points = segments
            self.bytes_sent = segments.nbytes
            return
        hidden = np.asarray(hidden, dtype=np.int64)
        if self._hidden is None or not np.array_equal(hidden, self._hidden):
            self.handle.faces = self.display.triangles(hidden)
            self._hidden = hidden
        vertices = self.display.vertices(points)
        self.handle.vertices = vertices
        self.bytes_sent = vertices.nbytes


