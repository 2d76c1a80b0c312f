"""``warp-verlet live`` and ``view`` from the command line, no browser needed: the server's safety (a port in
use, binding beyond localhost), bad caches, and a player that never imports Warp."""

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from browser import REPO, free_port


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "warp_verlet", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


@pytest.fixture
def viser():
    return pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")


@pytest.fixture
def busy_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.fixture
def rope_cache(tmp_path):
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.input.scene import load_scene

    cache = tmp_path / "rope.usdc"
    run_scene(load_scene(REPO / "scenes" / "rope.toml"), cache, device="cpu", frames=3)
    return cache


def test_a_port_in_use_is_one_clear_error(viser, busy_port, rope_cache):
    for command in (["live", REPO / "scenes" / "rope.toml", "--device", "cpu"], ["view", rope_cache]):
        result = cli(*command, "--port", busy_port, "--seconds", 1)
        assert result.returncode == 2, result.stderr
        assert f"port {busy_port} on 127.0.0.1 is already in use" in result.stderr
        assert "--port" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_serves_on_localhost_and_warns_beyond_it(viser, rope_cache):
    cache = rope_cache
    port = free_port()
    local = cli("view", cache, "--port", port, "--seconds", 0.5)
    assert local.returncode == 0, local.stderr
    assert f"http://127.0.0.1:{port}" in local.stdout and "warning" not in local.stderr
    anywhere = cli("view", cache, "--host", "0.0.0.0", "--port", free_port(), "--seconds", 0.5)
    assert anywhere.returncode == 0, anywhere.stderr
    assert "warning: serving on 0.0.0.0" in anywhere.stderr and "reachable from other machines" in anywhere.stderr


@pytest.mark.slow
def test_view_refuses_what_is_not_a_cache(tmp_path):
    missing = cli("view", tmp_path / "nothing.usdc", "--port", free_port())
    assert missing.returncode == 2 and "nothing.usdc: no such file" in missing.stderr
    text = tmp_path / "notes.usda"
    text.write_text("hello")
    bad = cli("view", text, "--port", free_port())
    assert bad.returncode == 2 and "not a USD file" in bad.stderr


@pytest.mark.slow
def test_the_player_never_imports_warp(viser, rope_cache):
    # The player serves a cache and plays it to its end, all without Warp (the cache was made in this process).
    code = ("import sys\n"
            "from warp_verlet.apps.cache_player import CachePlayer\n"
            f"player = CachePlayer({str(rope_cache)!r}, port={free_port()})\n"
            "player.show(player.cache.frames[-1]); player.slider.value = 0; player.toggle(); player.run(0.3)\n"
            "assert player.frame > 0, 'did not play'\n"
            "assert 'warp' not in sys.modules, 'warp imported'; print('ok')")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.stdout.strip().endswith("ok"), result.stderr


def test_live_refuses_a_bad_scene_before_serving(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[cloth]]\nresolution = [4]\nsize = [1.0, 1.0]\n")
    result = cli("live", bad, "--port", free_port(), "--seconds", 1)
    assert result.returncode == 2 and "cloth[0].resolution" in result.stderr


def test_live_refuses_a_bad_record_path_before_starting(tmp_path):
    for record, problem in ((tmp_path / "missing" / "x.usdc", "does not exist"),
                            (tmp_path / "x.abc", "must end in .usd, .usda, .usdc")):
        result = cli("live", REPO / "scenes" / "rope.toml", "--record", record, "--port", free_port(), "--seconds", 1)
        assert result.returncode == 2, result.stderr
        assert f"error: --record: cannot write {record}" in result.stderr and problem in result.stderr
        assert "open http" not in result.stdout  # refused before serving
    assert not list(tmp_path.iterdir())  # nothing written


def test_record_limit_takes_gibibytes_and_its_help_names_the_default(monkeypatch):
    from warp_verlet.apps import cli as cli_module
    from warp_verlet.apps.live_session import RECORD_LIMIT_BYTES

    parser = cli_module.build_parser()
    live = parser._subparsers._group_actions[0].choices["live"]
    assert f"default {RECORD_LIMIT_BYTES / 2**30:g}," in live.format_help().replace("\n", " ").replace("  ", " ")
    for bad in ("0", "-1", "nan", "lots"):
        result = cli("live", REPO / "scenes" / "rope.toml", "--record-limit", bad, "--port", free_port())
        assert result.returncode == 2 and "--record-limit" in result.stderr and "GiB" in result.stderr, bad
    # The limit reaches the session: 1 byte holds no frame, so the recording is full at once.
    made = []
    monkeypatch.setattr("warp_verlet.apps.live_app.LiveApp", lambda session, *a: made.append(session) or _Stopped())
    assert cli_module.main(["live", str(REPO / "scenes" / "rope.toml"), "--device", "cpu", "--port",
                            str(free_port()), "--record-limit", str(1 / 2**30), "--seconds", "0"]) == 0
    assert made[0].record_limit == 1 and made[0].readout().recording_full
    made[0].close()


class _Stopped:
    """Stands for LiveApp: serves nothing."""
    url = "http://127.0.0.1"

    def run(self, seconds):
        pass


def test_live_refuses_a_record_directory_that_takes_no_new_file():
    # /proc passes the permission check (as root, every directory does) but creates no file: live learns it at
    # start, not at the first Save.
    if not Path("/proc/self").is_dir():
        pytest.skip("needs Linux's /proc")
    result = cli("live", REPO / "scenes" / "rope.toml", "--record", "/proc/x.usdc", "--port", free_port(),
                 "--seconds", 1)
    assert result.returncode == 2, result.stderr
    assert "error: --record: cannot write /proc/x.usdc: cannot create a file in /proc" in result.stderr
    assert "open http" not in result.stdout and "Traceback" not in result.stderr


def test_a_page_of_another_origin_cannot_open_the_websocket(viser, caplog):
    # Any page in the user's browser may open a websocket to 127.0.0.1; only this server's own page (its Origin
    # is the Host it connected to, a loopback name) and clients that are no page (no Origin) are let in. A
    # refused one is closed with 1008 before anything it sent is read.
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from warp_verlet.apps.web_view import start_server

    server = start_server(port=free_port())
    port = server.get_port()
    protocol = [f"viser-v{viser.__version__}"]

    def opened(uri: str, origin: str | None) -> bool:
        """Whether the server keeps the connection and sends it the scene; False when it closes it with 1008."""
        sock = socket.create_connection(("127.0.0.1", port))  # whatever name the URI gives, as DNS rebinding would
        with connect(uri, sock=sock, origin=origin, subprotocols=protocol, open_timeout=10) as ws:
            try:
                ws.recv(timeout=10)
                return True
            except ConnectionClosed as closed:
                assert closed.rcvd is not None and closed.rcvd.code == 1008, closed
                return False

    try:
        local = f"ws://127.0.0.1:{port}"
        assert opened(local, f"http://127.0.0.1:{port}")  # the served page
        assert opened(f"ws://localhost:{port}", f"http://localhost:{port}")
        assert opened(local, None)  # no page: a script on this machine
        assert not opened(local, "https://example.com")  # any other site
        assert not opened(local, "null")  # a local file or a sandboxed frame
        assert not opened(local, f"http://127.0.0.1:{port + 1}")  # another port is another origin
        assert not opened(f"ws://rebound.example:{port}", f"http://rebound.example:{port}")  # DNS rebinding
    finally:
        server.stop()
    logged = [r.getMessage() for r in caplog.records if r.name.startswith("websockets")]
    assert "connection handler failed" not in logged, logged  # a refusal is no error: no traceback is printed


def test_a_viser_without_the_internals_the_origin_check_needs_warns_instead():
    from types import SimpleNamespace

    from warp_verlet.apps.web_view import refuse_foreign_origins

    with pytest.warns(UserWarning, match="no way to check a connection's web origin"):
        refuse_foreign_origins(SimpleNamespace(), loopback=True)
