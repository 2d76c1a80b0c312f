"""``warp-verlet live`` and ``warp-verlet view`` in a real browser: headless Chromium driven by Playwright.

Skipped, with the reason, where viser, Playwright or Chromium is missing. UPDATE_SCREENSHOTS=1 copies the
screenshots to docs/images (the README's pictures)."""

import time

import numpy as np
import pytest

from browser import (CHROMIUM_ARGS, REPO, Served, browser_or_skip, free_port, keep_for_docs, open_page, project,
                     read_text, reddish, screenshot, set_number, wait_until)
from warp_verlet.output.cache_reader import open_cache
from warp_verlet.apps.runner import run_scene
from warp_verlet.input.scene import load_scene
from warp_verlet.output.usd_writer import validate_cache

pytestmark = pytest.mark.slow  # each test drives a real Chromium


@pytest.fixture(scope="module")
def browser():
    playwright, chromium = browser_or_skip()
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def page_of(browser):
    """open_page for this test; its pages are closed after it (a page left open keeps rendering, in software,
    on the CI's two cores)."""
    pages = []

    def open_(url):
        pages.append(open_page(browser, url))
        return pages[-1]
    yield open_
    for page in pages:
        page.close()


@pytest.fixture
def live(tmp_path):
    """The shipped hanging cloth, live on the CPU, served on a free port."""
    from warp_verlet.apps.live_app import LiveApp
    from warp_verlet.apps.live_session import LiveSession

    # Waiting, as `warp-verlet live` makes it: the simulation starts when the test's page connects.
    session = LiveSession(load_scene(REPO / "scenes" / "hanging_cloth.toml"), "cpu", waiting=True)
    app = LiveApp(session, port=free_port(), record_path=tmp_path / "live.usdc")
    with Served(app):
        yield app


def frame_number(page) -> int:
    return int(read_text(page, "Frame").split()[0])


def test_live_page_shows_the_cloth(page_of, live, tmp_path):
    page = page_of(live.url)
    wait_until(lambda: frame_number(page) > 10, what="the frame counter")
    live.session.pause()
    wait_until(lambda: "paused" in read_text(page, "Frame"), what="the pause")
    page.wait_for_timeout(500)  # the last draw reaches the page
    image = screenshot(page, tmp_path / "live.png")
    # Where the cloth's vertices project (the camera is the page's initial one), the pixels are cloth-coloured;
    # the panel on the right and the notifications on the left are left out.
    points = live.session.current_points()[0].reshape(64, 64, 3)[4:-4:6, 4:-4:6].reshape(-1, 3)
    xy = np.round(project(points, live.server.initial_camera)).astype(int)
    inside = (xy[:, 0] > 320) & (xy[:, 0] < 790) & (xy[:, 1] > 0) & (xy[:, 1] < 800)
    assert inside.sum() >= 20, "most of the cloth should be in view, left of the panel"
    on_cloth = reddish(image[xy[inside, 1], xy[inside, 0]])
    assert on_cloth.mean() > 0.95, f"{(~on_cloth).sum()} of {inside.sum()} cloth points are not cloth-coloured"
    # And not everywhere: below the cloth's lowest point the page is background.
    lowest = int(project(live.session.current_points()[0], live.server.initial_camera)[:, 1].max())
    assert lowest < 760 and not reddish(image[lowest + 20:, 330:780]).any()
    keep_for_docs(tmp_path / "live.png", "live.png")


def test_the_simulation_starts_when_the_page_opens(page_of, live):
    time.sleep(1.0)  # served for a second, no page yet
    assert live.session.waiting and live.session.frame == 0 and live.session.sim.steps == 0
    page = page_of(live.url)
    wait_until(lambda: frame_number(page) > 5, what="the frame counter")
    assert not live.session.waiting and any("started" in line for line in live.session.event_lines())


def test_pause_button_stops_the_frame_counter(page_of, live):
    page = page_of(live.url)
    wait_until(lambda: frame_number(page) > 5, what="the frame counter")
    first = frame_number(page)
    # Running: the counter moves (software WebGL on two busy cores can lag the page by seconds, so no fixed wait).
    wait_until(lambda: frame_number(page) > first, what="the counter to move")
    page.get_by_role("button", name="Pause").click()
    wait_until(lambda: "paused" in read_text(page, "Frame"), what="the pause")
    paused = frame_number(page)
    page.wait_for_timeout(1500)
    assert frame_number(page) == paused and live.session.frame == paused
    page.get_by_role("button", name="Step frame").click()
    wait_until(lambda: frame_number(page) == paused + 1, what="one frame stepped")
    page.get_by_role("button", name="Play").click()
    wait_until(lambda: frame_number(page) > paused + 5, what="playing again")


def test_wind_set_in_the_page_moves_the_cloth_along_it(page_of, live):
    page = page_of(live.url)
    wait_until(lambda: frame_number(page) > 60, what="the cloth to settle a little")
    before = np.concatenate(live.session.current_points()).mean(axis=0)
    set_number(page, "Strength m/s²", 20)  # along the default direction, +Z: out of the cloth's plane
    wait_until(lambda: any("wind 20" in line for line in live.session.events), what="the wind edit")
    frame = live.session.frame
    wait_until(lambda: live.session.frame > frame + 60, what="a second of wind")
    shift = np.concatenate(live.session.current_points()).mean(axis=0) - before
    assert shift[2] > 0.05, f"the cloth's centre moved by {shift} m"
    assert abs(shift[0]) < 0.01


def test_save_cache_writes_a_valid_cache(page_of, live, tmp_path):
    page = page_of(live.url)
    wait_until(lambda: frame_number(page) > 20, what="some frames")
    target = tmp_path / "saved" / "from_page.usdc"
    target.parent.mkdir()
    box = page.locator("xpath=//label[normalize-space(.)='Cache path']/ancestor::div[contains(@class,"
                       "'mantine-Flex-root')][1]//input")
    box.fill(str(target))
    box.press("Enter")
    page.get_by_role("button", name="Save cache").click()
    wait_until(lambda: any("saved" in line for line in live.session.events), what="the save")
    assert validate_cache(target) == []
    frames = open_cache(target).frames
    assert frames[0] == 0 and len(frames) > 20 and frames == tuple(range(len(frames)))


@pytest.fixture
def shipped_cache(tmp_path_factory):
    """A cache of the shipped ball-through-net scene (a cloth, a moving sphere, a plane and torn faces)."""
    out = tmp_path_factory.mktemp("cache") / "ball_through_net.usdc"
    run_scene(load_scene(REPO / "scenes" / "ball_through_net.toml"), out, device="cpu", frames=60)
    return out


def test_view_slider_changes_the_drawing(page_of, shipped_cache, tmp_path):
    from warp_verlet.apps.cache_player import CachePlayer

    player = CachePlayer(shipped_cache, port=free_port())
    with Served(player):
        page = page_of(player.url)
        first = screenshot(page, tmp_path / "view0.png")
        set_number(page, "Frame", 60)
        wait_until(lambda: player.frame == 60, what="frame 60")
        page.wait_for_timeout(800)
        last = screenshot(page, tmp_path / "view60.png")
        assert read_text(page, "Time").startswith("1.000")
        scene_area = (slice(0, 800), slice(0, 790))  # left of the panel
        changed = np.abs(first[scene_area].astype(int) - last[scene_area].astype(int)).sum(axis=2) > 60
        assert changed.mean() > 0.01, "the drawing did not change between frames 0 and 60"
        assert reddish(last[scene_area]).mean() > 0.005  # the net is drawn
        keep_for_docs(tmp_path / "view60.png", "view.png")
        page.get_by_role("button", name="Play").click()
        wait_until(lambda: player.frame != 60, what="playing")
