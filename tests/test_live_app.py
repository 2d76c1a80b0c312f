"""The pages' controls without a browser: what ``LiveApp`` and ``CachePlayer`` do when their controls change or
their readouts refresh (viser runs a control's callback also when the server sets its value)."""

import numpy as np
import pytest

from browser import REPO, free_port, wait_until
from conftest import make_scene
from warp_verlet.input.scene import parse_scene

pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")

HANGING = dict(resolution=[12, 12], pins=["top-left", "top-right"], sticks=["structural", "shear"], tethers=False)


@pytest.fixture
def app_of(tmp_path):
    """A LiveApp of a scene, served on a free port, its loop not running (the tests drive it)."""
    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    apps = []

    def make(scene, waiting=False):
        apps.append(LiveApp(LiveSession(scene, "cpu", waiting=waiting), port=free_port(),
                            record_path=tmp_path / "live.usdc"))
        return apps[-1]
    yield make
    for app in apps:
        app.server.stop()
        app.session.close()


def test_the_budgets_substeps_shown_on_the_slider_are_not_an_edit(app_of):
    app = app_of(make_scene({"target_stretch": 1e-6, "max_substeps": 64}, **HANGING))
    session = app.session
    first = session.sim.substeps
    for _ in range(4):
        session.tick(1 / 60)
    assert session.sim.substeps > first  # the budget raised them
    history = dict(session.sim.budget.frames_at)
    app.show_readouts(0.0)
    assert app.substeps.value == session.sim.substeps
    assert not session._pending and not any("substeps" in line for line in session.event_lines())
    session.tick(1 / 60)
    # The budget's history goes on (a retune would have reset it).
    assert all(session.sim.budget.frames_at[s] >= n for s, n in history.items())


def test_the_pin_list_follows_a_release_once_it_applies(app_of):
    app = app_of(make_scene(**HANGING))
    first = app.pin_choice.options[0]
    app._release_pin()  # the first pin is the one chosen
    app.show_readouts(0.0)  # a refresh before the release has applied (it waits for a frame boundary)
    app.session.tick(1 / 60)
    app.show_readouts(0.0)
    assert first not in app.pin_choice.options and len(app.pin_choice.options) == 1


def test_the_drag_gizmo_goes_back_with_its_sphere_on_reset(app_of):
    scene = parse_scene({"cloth": [{"resolution": [4, 4], "size": [1.0, 1.0]}],
                         "collider": [{"type": "sphere", "name": "ball", "radius": 0.2, "centre": [0.0, -3.0, 0.0]}]},
                        file="<test>")
    app = app_of(scene)
    sphere = app._sphere_list[0]
    sphere.gizmo.position = (1.0, 2.0, 3.0)  # where the user dragged it
    app.session.move_sphere(0, (1.0, 2.0, 3.0))
    app.draw(0.0)
    np.testing.assert_allclose(sphere.handle.position, (1.0, 2.0, 3.0))
    app.session.reset()
    app.draw(0.0)
    np.testing.assert_allclose(sphere.handle.position, (0.0, -3.0, 0.0))
    np.testing.assert_allclose(sphere.gizmo.position, (0.0, -3.0, 0.0))


def test_play_at_the_last_frame_plays_again_from_the_first(tmp_path):
    from warp_verlet.apps.cache_player import CachePlayer
    from warp_verlet.apps.runner import run_scene
    from warp_verlet.input.scene import load_scene

    cache = tmp_path / "rope.usdc"
    run_scene(load_scene(REPO / "scenes" / "rope.toml"), cache, device="cpu", frames=5)
    player = CachePlayer(cache, port=free_port())
    try:
        player.slider.value = 5
        assert player.frame == 5
        player.toggle()
        assert player.playing and player.frame == 0
    finally:
        player.server.stop()


def connect_page(url: str):
    """A websocket client of the page, as a browser's: it sends its camera, which is when viser counts a page as
    connected (viser's own message, encoded as its browser client encodes it)."""
    import msgspec
    import viser
    from viser._messages import ViewerCameraMessage
    from websockets.sync.client import connect

    page = connect(url.replace("http://", "ws://"), max_size=None, subprotocols=[f"viser-v{viser.__version__}"])
    camera = ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 3.0), fov=1.0, near=0.01, far=100.0,
                                 image_height=800, image_width=1200, look_at=(0.0, 0.0, 0.0),
                                 up_direction=(0.0, 1.0, 0.0))
    page.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
    return page


def test_a_waiting_session_starts_when_the_first_page_connects(app_of):
    app = app_of(make_scene({"fps": 60, "substeps": 4}, **HANGING), waiting=True)
    session = app.session
    for _ in range(30):  # half a second of the server's loop with no page
        session.tick(1 / 60)
    app.show_readouts(0.0)
    assert session.frame == 0 and session.sim.steps == 0
    assert app.frame_text.value == "0  (0.00 s)  waiting for a page"
    page = connect_page(app.url)
    try:
        wait_until(lambda: not session.waiting, timeout=30, what="the page's connection to start the session")
        assert app.frame_text.value == "0  (0.00 s)  starting"  # until the loop's next readout
        for _ in range(3):
            session.tick(1 / 60)
        app.show_readouts(0.0)
        assert session.frame == 3 and app.frame_text.value == "3  (0.05 s)"
        assert session.readout().recorded == 4  # recorded from the start: frame 0 and three frames
    finally:
        page.close()


def test_live_from_the_command_line_waits_for_a_page(monkeypatch, capsys):
    from warp_verlet.apps import cli

    made = []

    class Unserved:  # stands for LiveApp: serves nothing
        url = "http://127.0.0.1"

        def __init__(self, session, *args):
            made.append(session)

        def run(self, seconds):
            pass

    monkeypatch.setattr("warp_verlet.apps.live_app.LiveApp", Unserved)
    assert cli.main(["live", str(REPO / "scenes" / "rope.toml"), "--device", "cpu", "--port", str(free_port()),
                     "--seconds", "0"]) == 0
    assert made[0].waiting and made[0].frame == 0
    assert "the simulation starts when a page connects" in capsys.readouterr().out
    made[0].close()
