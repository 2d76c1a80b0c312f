"""Driving the viser pages of ``live`` and ``view`` from headless Chromium (Playwright), for the browser tests.

Chromium comes from Debian's packages (``apt-get install chromium``), since Playwright's own download cannot
be reached here; WebGL runs in software (SwiftShader). ``browser_or_skip()`` says why a test cannot run.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
IMAGES = REPO / "docs" / "images"
VIEWPORT = {"width": 1200, "height": 800}
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


def chromium_path() -> str | None:
    return os.environ.get("CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def browser_or_skip():
    """(playwright's sync API, the Chromium executable), or skip the test saying what is missing."""
    pytest.importorskip("viser", reason="the browser views need viser: pip install 'warp-verlet[live]'")
    playwright = pytest.importorskip("playwright.sync_api", reason="pip install playwright to run the browser tests")
    path = chromium_path()
    if path is None:
        pytest.skip("no Chromium: apt-get install chromium (or set CHROMIUM to its path)")
    return playwright, path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """An app (LiveApp or CachePlayer) served from a thread for the length of a ``with`` block."""

    def __init__(self, app):
        self.app = app
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        try:
            self.app.run()
        except BaseException as exc:  # noqa: BLE001 (re-raised in the test's thread on exit)
            self.error = exc

    def __enter__(self):
        self.thread.start()
        return self.app

    def __exit__(self, *exc):
        self.app.stop()
        self.thread.join(timeout=30)
        if self.error is not None:
            raise AssertionError(f"the served app failed: {self.error!r}") from self.error


def open_page(browser, url: str):
    page = browser.new_page(viewport=VIEWPORT)
    page.goto(url)
    page.get_by_text("Connected").wait_for(timeout=30_000)
    close = page.locator("#webgl-software-rendering button")  # "Software WebGL rendering detected"
    try:
        close.click(timeout=10_000)
        close.wait_for(state="detached", timeout=5_000)
    except Exception:  # noqa: BLE001 (no notification: a browser on a GPU)
        pass
    page.wait_for_timeout(1_500)  # the scene's first draw
    return page


def row_input(page, label: str):
    """The text or number box of the GUI row labelled ``label`` (viser lays out a label and its inputs in a
    row; a slider's row also has its number box, which is the last input)."""
    row = page.locator(f"xpath=//label[normalize-space(.)='{label}']/ancestor::div[contains(@class,"
                       "'mantine-Flex-root')][1]")
    return row.locator("input:not([type=hidden])").last


def read_text(page, label: str) -> str:
    return row_input(page, label).input_value()


def set_number(page, label: str, value) -> None:
    box = row_input(page, label)
    box.fill(str(value))
    box.press("Enter")


def wait_until(condition, timeout: float = 20.0, what: str = "condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def project(points: np.ndarray, camera, size=(VIEWPORT["width"], VIEWPORT["height"]), up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Pixel coordinates (x right, y down) of ``points`` seen by viser's initial camera (three.js: vertical
    fov, the scene's up as the camera's up)."""
    eye, target = np.asarray(camera.position, float), np.asarray(camera.look_at, float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    rel = np.asarray(points, float) - eye
    depth = rel @ forward
    half_height = np.tan(camera.fov / 2)
    half_width = half_height * size[0] / size[1]
    x = (rel @ right) / depth / half_width
    y = (rel @ true_up) / depth / half_height
    return np.stack([(x + 1) / 2 * size[0], (1 - y) / 2 * size[1]], axis=1)


def reddish(rgb: np.ndarray) -> np.ndarray:
    """The first cloth colour (204, 84, 61) under any lighting: red well above green and blue."""
    rgb = rgb.astype(int)
    return (rgb[..., 0] > rgb[..., 1] + 40) & (rgb[..., 0] > rgb[..., 2] + 40)


def screenshot(page, path: Path) -> np.ndarray:
    from PIL import Image

    page.screenshot(path=str(path))
    return np.asarray(Image.open(path).convert("RGB"))


def keep_for_docs(shot: Path, name: str) -> None:
    """With UPDATE_SCREENSHOTS=1, the screenshot becomes the README's docs/images/NAME."""
    if os.environ.get("UPDATE_SCREENSHOTS") == "1":
        IMAGES.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shot, IMAGES / name)
