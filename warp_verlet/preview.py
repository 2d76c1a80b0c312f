"""Headless previews of a USD point cache: a PNG of up to four frames side by side, or an animated GIF.

The cache is read one frame at a time into plain numpy (``read_frame``), then drawn with matplotlib's Agg
canvas (``draw_frame``). Only ``Figure`` and ``FigureCanvasAgg`` objects are used, never pyplot, so that
importing this module does not choose or change the caller's matplotlib backend.

Every surface drawn for one frame goes into a single ``Poly3DCollection``: matplotlib sorts polygons by
depth only within a collection, so a cloth draped over a sphere is drawn in the right order only if the sphere's
facets and the cloth's faces are sorted together. A cloth's faces may be triangles, quads, n-gons or a mix.

This module never imports warp: previewing a cache must not need the simulator.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from .errors import OutputError
from .memory import available_host_bytes
from .faces import next_corner
# Reading is shared with the browser player; grid_shape and visible_polygons are re-exported for callers of
# this module.
from .cache_reader import (FrameGeometry, Polygons, PointCache, PreviewError, grid_shape,  # noqa: F401
                           open_cache, read_frame, visible_polygons)

SUFFIXES = (".png", ".gif")
DEFAULT_SIZE = {".png": (800, 800), ".gif": (480, 480)}  # pixels; a GIF is smaller because it has many frames
MAX_PNG_PANELS = 4
MAX_GIF_FRAMES = 120
MAX_GIF_FPS = 50.0  # GIF delays are in 1/100 s and viewers slow down anything shorter than 2/100 s
# Seen from above and in front, off to the right: a vertical cloth in the XY plane faces the camera at 30
# degrees instead of edge-on, and a horizontal one still shows its folds.
VIEW_ELEVATION, VIEW_AZIMUTH = 20.0, -60.0
# A power of two, so that W / DPI inches is exact and the image comes out at exactly W x H pixels.
DPI = 128
TITLE_ROOM_PX, CAPTION_ROOM_PX = 26, 12  # room above each panel for its title, below them for the file name
SPHERE_FACETS = (24, 48)  # latitude x longitude quads: small, so that depth sorting against the cloth works
# Memory per pixel while one image is drawn and written: Agg's RGBA canvas (4), its RGB copy (3), the
# palette image of a GIF frame (1) and Pillow's and the encoder's working copies (about 4). GIF frames are
# written one at a time, so this does not grow with the frame count.
BYTES_PER_PIXEL = 12

CLOTH_COLOURS = ((0.80, 0.33, 0.24), (0.23, 0.47, 0.72), (0.36, 0.62, 0.33), (0.85, 0.62, 0.20))
ROPE_COLOUR = (0.15, 0.15, 0.15)
SPHERE_COLOUR = (0.70, 0.72, 0.76)
PLANE_RGBA = (0.45, 0.45, 0.45, 0.25)


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


@dataclass(frozen=True)
class View:
    """The camera of every panel: one box fitted over all drawn frames, so panels and GIF frames align."""

    lo: np.ndarray  # stage coordinates
    hi: np.ndarray
    up_axis: str


def to_display(points: np.ndarray, up_axis: str) -> np.ndarray:
    """Stage coordinates to matplotlib's, whose z is vertical: a Y-up stage is turned by +90 degrees about X,
    (x, y, z) -> (x, -z, y), a rotation, so the cloth keeps its handedness and its front faces the camera."""
    if up_axis == "Z":
        return points
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def _flatten(polygons: Polygons) -> tuple[np.ndarray, np.ndarray]:
    """Every corner of ``polygons`` in one (C, 3) array, and each polygon's corner count: one layout for
    both kinds of Polygons, so that what works on it needs no per-kind code."""
    if isinstance(polygons, np.ndarray):
        return polygons.reshape(-1, 3), np.full(len(polygons), polygons.shape[1], np.int64)
    counts = np.fromiter(map(len, polygons), np.int64, len(polygons))
    return (np.concatenate(polygons) if polygons else np.zeros((0, 3))), counts


def _content_box(geometries: Sequence[FrameGeometry]) -> tuple[np.ndarray, np.ndarray]:
    chunks = [_flatten(p)[0] for g in geometries for p in g.cloths] + [r for g in geometries for r in g.ropes]
    chunks = [c for c in chunks if c.size]
    chunks += [np.stack([c - r, c + r]) for g in geometries for c, r in g.spheres]
    if not chunks:  # everything hidden: a unit box at the origin
        return np.full(3, -0.5), np.full(3, 0.5)
    allp = np.concatenate(chunks)
    return allp.min(axis=0), allp.max(axis=0)


def clip_plane(corners: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """The part of a rectangular plane quad under the box [lo, hi] (its footprint on the plane), so that a
    ground plane meant to look infinite does not shrink the cloth to a dot. None when they do not overlap."""
    origin = corners[0]
    u, v = corners[1] - origin, corners[-1] - origin
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    if lu == 0 or lv == 0:
        return None
    u, v = u / lu, v / lv
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pu, pv = (box - origin) @ u, (box - origin) @ v
    u0, u1 = max(pu.min(), 0.0), min(pu.max(), lu)
    v0, v1 = max(pv.min(), 0.0), min(pv.max(), lv)
    if u1 <= u0 or v1 <= v0:
        return None
    return origin + np.array([u0 * u + v0 * v, u1 * u + v0 * v, u1 * u + v1 * v, u0 * u + v1 * v])


def fit_view(geometries: Sequence[FrameGeometry], up_axis: str) -> tuple[View, list[list[np.ndarray]]]:
    """The camera box over all frames, and each frame's planes clipped to the cloths' footprint."""
    lo, hi = _content_box(geometries)
    pad = 0.15 * max(float((hi - lo).max()), 1e-6)  # the ground shows a little around the cloth
    planes = [[q for q in (clip_plane(p, lo - pad, hi + pad) for p in g.planes) if q is not None]
              for g in geometries]
    chunks = [lo[None], hi[None]] + [q for frame_planes in planes for q in frame_planes]
    allp = np.concatenate(chunks)
    return View(allp.min(axis=0), allp.max(axis=0), up_axis), planes


def _sphere_quads(centre: np.ndarray, radius: float) -> np.ndarray:
    n_lat, n_lon = SPHERE_FACETS
    theta = np.linspace(0, np.pi, n_lat + 1)[:, None]
    phi = np.linspace(0, 2 * np.pi, n_lon + 1)[None, :]
    p = centre + radius * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                    np.cos(theta) * np.ones_like(phi)], axis=-1)
    return np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)


def _normals(polygons: Polygons) -> np.ndarray:
    """(Q, 3) Newell normals, twice each polygon's vector area: one formula for triangles, quads and
    n-gons, the mean normal of a non-planar one (for a quad, the cross product of its diagonals). Corners are
    taken relative to each polygon's first, so that a cloth far from the origin keeps its precision."""
    corners, counts = _flatten(polygons)
    if not len(counts):
        return np.zeros((0, 3))
    starts = np.cumsum(counts) - counts
    rel = corners - np.repeat(corners[starts], counts, axis=0)
    return np.add.reduceat(np.cross(rel, rel[next_corner(counts)]), starts, axis=0)


def _shade(polygons: Polygons, rgb: Sequence[float]) -> np.ndarray:
    """Lambert shading with a light over the camera's shoulder; |n.l| because cloth is seen from both sides."""
    e, a = np.radians(VIEW_ELEVATION + 25), np.radians(VIEW_AZIMUTH + 20)
    light = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    n = _normals(polygons)
    length = np.linalg.norm(n, axis=1)
    lambert = np.abs(n @ light) / np.where(length > 0, length, 1.0)
    shade = 0.35 + 0.65 * lambert
    return np.concatenate([shade[:, None] * np.asarray(rgb)[None], np.ones((len(polygons), 1))], axis=1)


def draw_frame(ax, geometry: FrameGeometry, planes: Sequence[np.ndarray], view: View) -> None:
    """Draw one frame into a 3D axes: cloths, spheres and planes in one depth-sorted collection, ropes as lines."""
    up = view.up_axis
    polygons, faces, edges = [], [], []
    for i, cloth in enumerate(geometry.cloths):
        if not len(cloth):
            continue
        shown = to_display(cloth, up) if isinstance(cloth, np.ndarray) else [to_display(p, up) for p in cloth]
        colours = _shade(shown, CLOTH_COLOURS[i % len(CLOTH_COLOURS)])
        polygons += list(shown)
        faces.append(colours)
        edges.append(colours * [0.75, 0.75, 0.75, 1.0])  # the (coarse) grid lines show the folds
    for centre, radius in geometry.spheres:
        quads = to_display(_sphere_quads(centre, radius), up)
        colours = _shade(quads, SPHERE_COLOUR)
        polygons += list(quads)
        faces.append(colours)
        edges.append(colours)  # no visible facet seams
    for plane in planes:
        polygons.append(to_display(plane, up))
        faces.append(np.array([PLANE_RGBA]))
        edges.append(np.array([(0.3, 0.3, 0.3, 0.5)]))
    if polygons:
        ax.add_collection3d(Poly3DCollection(polygons, facecolors=np.concatenate(faces),
                                             edgecolors=np.concatenate(edges), linewidths=0.3))
    if geometry.ropes:
        ax.add_collection3d(Line3DCollection([to_display(r, up) for r in geometry.ropes], colors=[ROPE_COLOUR],
                                             linewidths=1.5))

    lo, hi = to_display(view.lo, up), to_display(view.hi, up)
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)  # the Y-up turn flips one axis
    span = hi - lo
    floor = 0.05 * max(float(span.max()), 1e-6)  # a flat cloth still gets a box with some depth
    centre, span = (lo + hi) / 2, np.maximum(span, floor)
    ax.set_xlim(centre[0] - span[0] / 2, centre[0] + span[0] / 2)
    ax.set_ylim(centre[1] - span[1] / 2, centre[1] + span[1] / 2)
    ax.set_zlim(centre[2] - span[2] / 2, centre[2] + span[2] / 2)
    ax.set_box_aspect(span, zoom=0.85)  # equal aspect: a metre is as long on every axis
    ax.view_init(elev=VIEW_ELEVATION, azim=VIEW_AZIMUTH)
    labels = ("x", "z", "y") if up == "Y" else ("x", "y", "z")
    for axis, label, length in zip((ax.xaxis, ax.yaxis, ax.zaxis), labels, span / span.max()):
        axis.set_major_locator(MaxNLocator(max(1, round(4 * length))))  # fewer ticks on a short axis: no pile-up
        axis.set_label_text(label, fontsize=7)
        axis.labelpad = -6  # the default pads push the labels out of a small panel
    if up == "Y":  # matplotlib's y is the stage's -z: label the ticks with the stage's coordinate
        ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{-value + 0.0:g}"))
    ax.tick_params(labelsize=6, pad=-2)
    ax.set_title(f"frame {geometry.frame}   t = {geometry.seconds:.3f} s", fontsize=9, pad=2)


def _panel_grid(panels: int) -> tuple[int, int]:
    return (2, 2) if panels > 2 else (1, panels)


def _figure(size: tuple[int, int]) -> Figure:
    fig = Figure(figsize=(size[0] / DPI, size[1] / DPI), dpi=DPI)
    FigureCanvasAgg(fig)  # Agg, attached to this figure only: the global backend is left alone
    return fig


def _draw_panels(fig: Figure, cache: PointCache, geometries: Sequence[FrameGeometry],
                 planes: Sequence[Sequence[np.ndarray]], view: View) -> None:
    fig.clear()
    rows, cols = _panel_grid(len(geometries))
    for i, (geometry, frame_planes) in enumerate(zip(geometries, planes)):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        draw_frame(ax, geometry, frame_planes, view)
    fig.text(0.01, 0.01, cache.path.name, fontsize=7, color="0.4", ha="left", va="bottom")
    # Margins in pixels, not fractions, so that a title fits above every panel whatever the image's height.
    height = fig.get_figheight() * fig.dpi
    title, caption = min(TITLE_ROOM_PX / height, 0.1), min(CAPTION_ROOM_PX / height, 0.05)  # thumbnails too
    panel = (1 - caption - rows * title) / rows  # a panel's height as a figure fraction, a title above each
    fig.subplots_adjust(left=0.0, right=0.96, bottom=caption, top=1 - title, wspace=0.08,
                        hspace=title / panel if rows > 1 else 0.0)


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
    (matplotlib's PillowWriter keeps every frame until the end: 120 frames at 8192 x 8192 are 32 GB). Each
    frame is quantised to its own 256-colour palette (the first frame's is the global colour table, later
    frames carry a local one); the animation loops forever."""

    def __init__(self, path: Path, fps: float):
        self._file = open(path, "wb")
        self._duration = int(1000 / fps)  # ms, as PillowWriter wrote it; GIF keeps 1/100 s
        self.frames = 0

    def add(self, fig: Figure) -> None:
        from PIL import GifImagePlugin, Image

        fig.canvas.draw()
        rgb = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3])  # opaque: the figure is white
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
    geometries = [read_frame(cache, f) for f in shown]
    view, planes = fit_view(geometries, cache.up_axis)
    width, height = size or DEFAULT_SIZE[suffix]

    # Same suffix, so Pillow and savefig pick the same format as for the real name; dot-prefixed, so it
    # does not show up as a finished preview.
    partial = output.with_name(f".{output.stem}.{os.getpid()}.partial{output.suffix}")
    try:
        fig = _figure((width, height))
        if suffix == ".png":
            _draw_panels(fig, cache, geometries, planes, view)
            fig.savefig(partial, format="png", dpi=DPI)
        else:
            gif = GifStream(partial, _gif_fps(shown, cache.fps))
            try:
                for geometry, frame_planes in zip(geometries, planes):
                    _draw_panels(fig, cache, [geometry], [frame_planes], view)
                    gif.add(fig)
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
