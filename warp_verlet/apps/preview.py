"""Headless previews of a USD point cache: a PNG of up to four frames side by side, or an animated GIF.

The cache is read one frame at a time into plain numpy (``read_frame``); each panel is ray traced on the CPU
by Mitsuba 3 (``preview_render``: a per-pixel depth test, a key light with shadows, smoothed edges), with a
camera fitted to that frame's cloths, so a cloth that travelled far stays large. Pillow lays the panels out,
writes their titles and the caption, and encodes the PNG or the GIF.

A cloth's faces may be triangles, quads, n-gons or a mix; torn faces are holes. A large grid is drawn at about
one grid cell per pixel of its panel.

This module never imports warp: previewing a cache must not need the simulator.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..errors import OutputError
from ..machine import available_host_bytes
# Reading is shared with the browser player; grid_shape is re-exported for callers of this module.
from ..output.cache_reader import (FrameGeometry, PointCache, PreviewError, grid_shape,  # noqa: F401
                           open_cache, read_frame)
from .preview_render import render_frame

SUFFIXES = (".png", ".gif")
DEFAULT_SIZE = {".png": (800, 800), ".gif": (480, 480)}  # pixels; a GIF is smaller because it has many frames
MAX_PNG_PANELS = 4
MAX_GIF_FRAMES = 120
MAX_GIF_FPS = 50.0  # GIF delays are in 1/100 s and viewers slow down anything shorter than 2/100 s
TITLE_ROOM_PX, CAPTION_ROOM_PX = 26, 14  # room above each panel for its title, below them for the file name
# Memory per pixel of the image while one image is drawn and written: Mitsuba's film (R, G, B, A and the filter
# weight, as float32: 20 bytes), the two passes' float64 copies (R, G, B, A: 64) and the sum and its sRGB
# conversion (about 30), the 8-bit panel and the canvas (6), and Pillow's palette image and the encoder's working
# copies of a GIF frame (about 5). GIF frames are written one at a time, so this does not grow with the frame count.
BYTES_PER_PIXEL = 125


# ------------------------------------------------------------------------------------- frame selection


def select_frames(frames: slice | None, available: Sequence[int], cache: Path | str = "the cache") -> list[int]:
    """The frame numbers that ``frames`` picks: A included, B excluded, step S, as in Python, but over frame
    numbers, and a range reaching outside the cache is an error rather than silently clipped."""
    available = list(available)
    first, last = available[0], available[-1]
    if frames is None:
        return available
    start = first if frames.start is None else frames.start
    stop = last + 1 if frames.stop is None else frames.stop
    step = 1 if frames.step is None else frames.step

    def bad(problem: str) -> PreviewError:
        return PreviewError(f"--frames: {problem}; {cache} holds frames {first} to {last} "
                            f"(A:B:S includes A and excludes B)")

    if step < 1:
        raise bad(f"the step must be at least 1, got {step}")
    if not first <= start <= last:
        raise bad(f"frame {start} is not in the cache")
    if stop > last + 1:
        raise bad(f"the end {stop} is past the last frame (at most {last + 1}, which includes frame {last})")
    if stop <= start:
        raise bad(f"selects no frame (the end {stop} is not after the start {start})")
    return [f for f in available if start <= f < stop and (f - start) % step == 0]


def evenly_spaced(frames: Sequence[int], count: int) -> list[int]:
    """At most ``count`` of ``frames``: the first, the last and evenly spaced ones between."""
    frames = list(frames)
    if len(frames) <= count:
        return frames
    return [frames[i] for i in np.round(np.linspace(0, len(frames) - 1, count)).astype(int)]


# ---------------------------------------------------------------------------------------------- drawing


def _panel_grid(panels: int) -> tuple[int, int]:
    return (2, 2) if panels > 2 else (1, panels)


def _font(pixels: int) -> ImageFont.ImageFont:
    """Pillow's own font (no system font needed), at ``pixels`` high where Pillow has FreeType."""
    try:
        return ImageFont.load_default(size=pixels)
    except (TypeError, ImportError, OSError):  # a Pillow without FreeType: its fixed bitmap font
        return ImageFont.load_default()


def _title(geometry: FrameGeometry) -> str:
    return f"frame {geometry.frame}   t = {geometry.seconds:.3f} s"


def _draw_panels(cache: PointCache, geometries: Sequence[FrameGeometry], size: tuple[int, int]) -> Image.Image:
    """One image of ``size``: a panel per frame (side by side for two, 2 x 2 for three or four), each titled
    with its frame and time and framed on its own cloths; the cache's file name in the bottom-left corner."""
    width, height = size
    rows, cols = _panel_grid(len(geometries))
    # Margins in pixels, not fractions, so that a title fits above every panel whatever the image's height;
    # a thumbnail gives them at most a tenth (titles) and a twentieth (caption) of its height.
    caption = min(CAPTION_ROOM_PX, height // 20)
    cell_h = (height - caption) // rows
    title = min(TITLE_ROOM_PX, cell_h // 10)
    cell_w = width // cols
    image = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    for i, geometry in enumerate(geometries):
        r, c = divmod(i, cols)
        x0, y0 = c * cell_w, r * cell_h
        w = cell_w if c < cols - 1 else width - x0  # the last column and row take the odd pixels
        h = (cell_h if r < rows - 1 else height - caption - y0) - title
        if w >= 1 and h >= 1:
            image.paste(Image.fromarray(render_frame(geometry, cache.up_axis, w, h)), (x0, y0 + title))
        if title >= 6:
            draw.text((x0 + w / 2, y0 + title / 2), _title(geometry), fill=(0, 0, 0), anchor="mm",
                      font=_font(round(title * 0.55)))
    if caption >= 6:
        draw.text((4, height - caption / 2), cache.path.name, fill=(102, 102, 102), anchor="lm",
                  font=_font(round(caption * 0.8)))
    return image


# ---------------------------------------------------------------------------------------------- writing


def _check_output(output: Path) -> str:
    suffix = output.suffix.lower()
    if suffix not in SUFFIXES:
        raise PreviewError(f"{output}: the preview must be a .png (still) or a .gif (animation), "
                           f"got {repr(output.suffix) if output.suffix else 'no suffix'}")
    parent = output.parent
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"cannot write preview {output}: {parent} is not a directory")
    if not parent.is_dir():
        raise OutputError(f"cannot write preview {output}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write preview {output}: directory {parent} is not writable")
    if output.is_dir():
        raise OutputError(f"cannot write preview {output}: it is a directory")
    return suffix


def _check_memory(size: tuple[int, int], available: int | None) -> None:
    """Refuse an image size whose one frame would not fit in the memory available now."""
    need = size[0] * size[1] * BYTES_PER_PIXEL
    if available is not None and need > available:
        raise PreviewError(f"--size {size[0]}x{size[1]}: drawing one image of that size needs about "
                           f"{need / 1e9:.2g} GB of memory and {available / 1e9:.2g} GB are available; "
                           "choose a smaller --size")


class GifStream:
    """An animated GIF written one frame at a time, so that memory holds one frame and not the animation
    (an animation held whole until the end would be 24 GB at 120 frames of 8192 x 8192). Each
    frame is quantised to its own 256-colour palette (the first frame's is the global colour table, later
    frames carry a local one); the animation loops forever."""

    def __init__(self, path: Path, fps: float):
        self._file = open(path, "wb")
        self._duration = int(1000 / fps)  # ms, as PillowWriter wrote it; GIF keeps 1/100 s
        self.frames = 0

    def add(self, rgb: Image.Image) -> None:
        from PIL import GifImagePlugin

        frame = rgb.convert("P", palette=Image.Palette.ADAPTIVE)
        del rgb
        if self.frames == 0:
            header, _ = GifImagePlugin.getheader(frame, info={"loop": 0, "duration": self._duration})
            chunks = header + GifImagePlugin.getdata(frame, duration=self._duration)
        else:
            chunks = GifImagePlugin.getdata(frame, duration=self._duration, include_color_table=True)
        self._file.write(b"".join(chunks))
        self._file.flush()
        self.frames += 1

    def close(self) -> None:
        """End the file (the GIF trailer) and close it."""
        if not self._file.closed:
            self._file.write(b";")
            self._file.close()

    def abandon(self) -> None:
        self._file.close()


def render_preview(cache_path: str | os.PathLike[str], output: str | os.PathLike[str],
                   frames: slice | None = None, size: tuple[int, int] | None = None) -> Path:
    """Render ``cache_path`` to ``output`` (.png: up to 4 evenly spaced frames of the selection as panels;
    .gif: every selected frame, at most 120 evenly spaced ones, written one at a time). Returns the output path.

    The image is written to a hidden file in the output's directory and renamed into place, so an error
    never leaves a partial preview behind. A size whose one frame would not fit in the memory available is
    refused before anything is read.
    """
    output = Path(output)
    suffix = _check_output(output)
    _check_memory(size or DEFAULT_SIZE[suffix], available_host_bytes())
    cache = open_cache(cache_path)
    selected = select_frames(frames, cache.frames, cache.path)
    shown = evenly_spaced(selected, MAX_GIF_FRAMES if suffix == ".gif" else MAX_PNG_PANELS)
    size = size or DEFAULT_SIZE[suffix]

    # Same suffix, so Pillow picks the same format as for the real name; dot-prefixed, so it does not show up
    # as a finished preview.
    partial = output.with_name(f".{output.stem}.{os.getpid()}.partial{output.suffix}")
    try:
        if suffix == ".png":
            _draw_panels(cache, [read_frame(cache, f) for f in shown], size).save(partial, format="PNG")
        else:
            gif = GifStream(partial, _gif_fps(shown, cache.fps))
            try:
                for frame in shown:  # one frame read, drawn and written at a time
                    gif.add(_draw_panels(cache, [read_frame(cache, frame)], size))
            except BaseException:
                gif.abandon()
                raise
            gif.close()
        os.replace(partial, output)
    except OSError as e:
        raise OutputError(f"cannot write preview {output}: {e.strerror or e}") from e
    finally:
        if partial.exists():
            partial.unlink()
    return output


def _gif_fps(frames: Sequence[int], fps: float) -> float:
    """Real time where the GIF format allows it: the cache's rate divided by the average frame stride."""
    if len(frames) < 2:
        return 1.0
    stride = (frames[-1] - frames[0]) / (len(frames) - 1)
    return float(min(max(fps / stride, 1.0), MAX_GIF_FPS))
