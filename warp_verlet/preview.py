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

import contextlib
import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection
from pxr import Tf, Usd, UsdGeom

from .errors import OutputError, WarpVerletError, usd_cause
from .memory import available_host_bytes
from .faces import Faces, as_faces, grid_faces, next_corner
from .usd_writer import COLLIDERS_PATH

SUFFIXES = (".png", ".gif")
DEFAULT_SIZE = {".png": (800, 800), ".gif": (480, 480)}  # pixels; a GIF is smaller because it has many frames
MAX_PNG_PANELS = 4
MAX_GIF_FRAMES = 120
MAX_GIF_FPS = 50.0  # GIF delays are in 1/100 s and viewers slow down anything shorter than 2/100 s
# A coarse grid of at most this many quads a side: enough to show folds, and a 1024 x 1024 cloth then costs
# matplotlib what a 64 x 64 one does.
MAX_GRID_QUADS = 64
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


class PreviewError(WarpVerletError):
    """The cache or the preview's options cannot be used as given: a bad argument or input (exit code 2)."""


# The polygons of one cloth, in 3D: a (Q, k, 3) array when every face has the same k corners (every grid,
# the large case, handled whole by numpy), else a list of (k_i, 3) arrays, which matplotlib also draws.
Polygons = np.ndarray | list[np.ndarray]


# --------------------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class ClothPrim:
    """The static part of one cloth mesh: its faces and, when they form the writer's grid, its shape."""

    prim: UsdGeom.Mesh
    faces: Faces  # triangles, quads, n-gons, or a mix
    grid: tuple[int, int] | None  # (rows, cols) of points when the faces are the writer's regular grid
    points_needed: int  # 1 + the largest vertex index the faces use


@dataclass(frozen=True)
class PointCache:
    """An open cache: what does not change from frame to frame."""

    path: Path
    stage: Usd.Stage
    up_axis: str  # "Y" or "Z"
    fps: float  # time codes per second; a time code is a frame
    frames: tuple[int, ...]  # every frame the cache holds, in order
    cloths: tuple[ClothPrim, ...]
    ropes: tuple[UsdGeom.BasisCurves, ...]
    spheres: tuple[UsdGeom.Sphere, ...]
    planes: tuple[UsdGeom.Mesh, ...]


@dataclass(frozen=True)
class FrameGeometry:
    """What one frame draws, in stage coordinates, as plain numpy."""

    frame: int
    seconds: float
    cloths: tuple[Polygons, ...]  # visible polygons of each cloth, decimated when large, in stage coordinates
    ropes: tuple[np.ndarray, ...]  # (N, 3) polyline of each curve
    spheres: tuple[tuple[np.ndarray, float], ...]  # (centre, radius)
    planes: tuple[np.ndarray, ...]  # (4, 3) corners as authored (drawing clips them to the cloth's box)


def grid_shape(faces: Faces | np.ndarray, point_count: int) -> tuple[int, int] | None:
    """(rows, cols) of points when ``faces`` (Faces, or an (F, k) array) are exactly the writer's grid
    (``faces.grid_faces``), else None.

    The grid's first face is (0, cols, cols + 1, 1), so it gives cols; the point count then gives rows, and
    the faces are compared with the grid those imply.
    """
    faces = as_faces(faces)
    if len(faces) == 0 or faces.counts[0] != 4 or faces.indices[0] != 0:
        return None
    cols = int(faces.indices[1])
    if cols < 2 or point_count % cols:
        return None
    rows = point_count // cols
    if rows < 2 or len(faces) != (rows - 1) * (cols - 1):  # also keeps a bogus cols from building a huge grid
        return None
    return (rows, cols) if faces == grid_faces(rows, cols) else None


def _grid_lines(quads: int, limit: int) -> np.ndarray:
    """Indices of the fine grid lines kept by a coarse grid of at most ``limit`` quads: both ends always."""
    return np.round(np.linspace(0, quads, min(quads, limit) + 1)).astype(np.int64)


def visible_polygons(points: np.ndarray, faces: Faces | np.ndarray, hidden: Sequence[int] = (),
                     grid: tuple[int, int] | None = None, max_quads: int = MAX_GRID_QUADS) -> Polygons:
    """The polygons to draw: every face not in ``hidden``, or, for a grid, a coarse grid of at most
    ``max_quads`` x ``max_quads`` quads in which a quad is hidden if any fine face it covers is.

    ``faces`` is Faces or an (F, k) array. The result is a (Q, k, 3) array when every face has k corners
    (one fancy index, however many faces), else a list of (k_i, 3) arrays in face order."""
    faces = as_faces(faces)
    hidden_mask = np.zeros(len(faces), bool)
    hidden = np.asarray(hidden, dtype=np.int64)
    hidden_mask[hidden[(hidden >= 0) & (hidden < len(faces))]] = True  # out-of-range indices hide nothing
    if grid is None:
        return _face_polygons(points, faces, ~hidden_mask)
    rows, cols = grid
    ri, ci = _grid_lines(rows - 1, max_quads), _grid_lines(cols - 1, max_quads)
    p = points.reshape(rows, cols, 3)[np.ix_(ri, ci)]
    quads = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2)  # the writer's winding
    fine_hidden = hidden_mask.reshape(rows - 1, cols - 1)
    coarse_hidden = np.logical_or.reduceat(np.logical_or.reduceat(fine_hidden, ri[:-1], axis=0), ci[:-1], axis=1)
    return quads[~coarse_hidden]


def _face_polygons(points: np.ndarray, faces: Faces, keep: np.ndarray) -> Polygons:
    """The corner positions of the faces where ``keep`` is True, as ``visible_polygons`` returns them."""
    uniform = faces.as_uniform()
    if uniform is not None:
        return points[uniform[keep]]
    corners = points[faces.indices[np.repeat(keep, faces.counts)]]
    counts = faces.counts[keep]
    return np.split(corners, np.cumsum(counts)[:-1]) if len(counts) else []


def open_cache(path: str | os.PathLike[str]) -> PointCache:
    """Open a point cache and find its cloths and colliders; PreviewError when it is not one."""
    path = Path(path)
    if not path.exists():
        raise PreviewError(f"{path}: no such file")
    if not path.is_file():
        raise PreviewError(f"{path}: not a file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as e:  # USD's own message names its C++ source line, nothing a user can act on
        raise PreviewError(f"{path}: not a USD file, or a damaged one: USD cannot open it") from e
    if stage is None:
        raise PreviewError(f"{path}: not a USD file, or a damaged one: USD cannot open it")

    cloths, ropes, spheres, planes = [], [], [], []
    for prim in stage.Traverse():
        collider = prim.GetPath().HasPrefix(COLLIDERS_PATH)
        if prim.IsA(UsdGeom.Sphere):
            spheres.append(UsdGeom.Sphere(prim))
        elif prim.IsA(UsdGeom.Mesh) and collider:
            planes.append(UsdGeom.Mesh(prim))  # the writer draws a plane collider as a one-quad mesh
        elif prim.IsA(UsdGeom.Mesh):
            cloths.append(_cloth_prim(path, UsdGeom.Mesh(prim)))
        elif prim.IsA(UsdGeom.BasisCurves):
            ropes.append(UsdGeom.BasisCurves(prim))
    if not cloths and not ropes:
        raise PreviewError(f"{path}: no cloth in the cache (expected a UsdGeom.Mesh or BasisCurves under /World)")

    layer = stage.GetRootLayer()
    if layer.HasStartTimeCode() and layer.HasEndTimeCode():
        frames = tuple(range(int(np.ceil(stage.GetStartTimeCode())), int(np.floor(stage.GetEndTimeCode())) + 1))
    else:  # no range authored: the frames the cloths were sampled at
        times = {t for c in cloths for t in c.prim.GetPointsAttr().GetTimeSamples()}
        times |= {t for r in ropes for t in r.GetPointsAttr().GetTimeSamples()}
        frames = tuple(sorted({int(t) for t in times if float(t).is_integer()}))
    up_axis = "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"
    return PointCache(path=path, stage=stage, up_axis=up_axis, fps=stage.GetTimeCodesPerSecond(),
                      frames=frames or (0,), cloths=tuple(cloths), ropes=tuple(ropes), spheres=tuple(spheres),
                      planes=tuple(planes))


def _cloth_prim(path: Path, mesh: UsdGeom.Mesh) -> ClothPrim:
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int32)  # USD's int: no copy
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int32)
    try:
        faces = Faces(counts, indices)
        faces.validate(None, f"mesh {mesh.GetPath()}")  # the point count may differ from frame to frame
    except ValueError as e:
        raise PreviewError(f"{path}: {e}") from e
    points = mesh.GetPointsAttr()
    times = points.GetTimeSamples()
    first = _read(path, mesh, "points", lambda: points.Get(times[0]) if times else points.Get(),
                  f"frame {times[0]:g}" if times else "its points")
    return ClothPrim(prim=mesh, faces=faces, grid=grid_shape(faces, len(first) if first is not None else 0),
                     points_needed=int(faces.indices.max()) + 1 if len(faces.indices) else 0)


def _read(path: Path, prim, what: str, get, where: str):
    """``get()``, a read of one attribute of ``prim``; a damaged cache (USD cannot read the value) becomes one
    PreviewError naming the file, the frame and the prim, rather than USD's traceback."""
    noise = io.StringIO()  # a damaged value also makes USD's Python binding print a TypeError of its own
    try:
        with contextlib.redirect_stderr(noise):
            return get()
    except (Tf.ErrorException, TypeError, RuntimeError) as e:  # TypeError: a value USD decoded as the wrong type
        cause = usd_cause(e) if isinstance(e, Tf.ErrorException) else str(e)
        raise PreviewError(f"{path}: {where} is damaged: USD cannot read {prim.GetPath()}.{what} ({cause})") from None


def _finite(path: Path, prim, values, frame: int) -> np.ndarray:
    """``values`` as float64, or a PreviewError when the frame holds NaN or inf (a damaged or diverged cache)."""
    array = np.asarray(values, dtype=np.float64)
    if not np.isfinite(array).all():
        raise PreviewError(f"{path}: frame {frame} is damaged: {prim.GetPath()} holds non-finite values "
                           "(NaN or inf), which cannot be drawn")
    return array


def _to_world(prim: UsdGeom.Xformable, time: Usd.TimeCode, points: np.ndarray) -> np.ndarray:
    """Apply the prim's world transform (the writer authors none, so usually nothing to do)."""
    m = np.array(prim.ComputeLocalToWorldTransform(time))
    if np.array_equal(m, np.eye(4)):
        return points
    return points @ m[:3, :3] + m[3, :3]  # USD matrices act on row vectors


def read_frame(cache: PointCache, frame: int) -> FrameGeometry:
    """One frame of the cache as numpy, with holeIndices applied (held between their samples)."""
    time = Usd.TimeCode(frame)
    where = f"frame {frame}"
    cloths = []
    for cloth in cache.cloths:
        points = _read(cache.path, cloth.prim, "points", lambda: cloth.prim.GetPointsAttr().Get(time), where)
        if points is None or len(cloth.faces) == 0:
            continue
        if len(points) < cloth.points_needed:
            raise PreviewError(f"{cache.path}: mesh {cloth.prim.GetPath()} has {len(points)} points at frame {frame}, "
                               f"but its faces use {cloth.points_needed}")
        # The grid was recognised on the first sample; a mesh whose point count changes is drawn face by face.
        grid = cloth.grid if cloth.grid and len(points) == cloth.grid[0] * cloth.grid[1] else None
        hidden = _read(cache.path, cloth.prim, "holeIndices", lambda: cloth.prim.GetHoleIndicesAttr().Get(time),
                       where)  # None or empty when the mesh never tears
        world = _to_world(cloth.prim, time, _finite(cache.path, cloth.prim, points, frame))
        cloths.append(visible_polygons(world, cloth.faces, hidden if hidden is not None else (), grid))
    ropes = []
    for curves in cache.ropes:
        points = _read(cache.path, curves, "points", lambda: curves.GetPointsAttr().Get(time), where)
        if points is None:
            continue
        points = _to_world(curves, time, _finite(cache.path, curves, points, frame))
        counts = curves.GetCurveVertexCountsAttr().Get(time) or [len(points)]
        ropes += np.split(points, np.cumsum(counts)[:-1])
    spheres = []
    for sphere in cache.spheres:
        centre = _read(cache.path, sphere, "xformOp:translate",
                       lambda: np.array(sphere.ComputeLocalToWorldTransform(time).ExtractTranslation()), where)
        radius = _read(cache.path, sphere, "radius", lambda: sphere.GetRadiusAttr().Get(time), where)
        spheres.append((_finite(cache.path, sphere, centre, frame), float(_finite(cache.path, sphere, radius, frame))))
    planes = []
    for plane in cache.planes:
        points = _read(cache.path, plane, "points", lambda: plane.GetPointsAttr().Get(time), where)
        if points is not None and len(points) >= 3:
            corners = np.asarray(points, dtype=np.float64)
            if np.isfinite(corners).all():  # older caches of an overflowing normal hold NaN corners
                planes.append(_to_world(plane, time, corners))
    return FrameGeometry(frame=frame, seconds=frame / cache.fps, cloths=tuple(cloths), ropes=tuple(ropes),
                         spheres=tuple(spheres), planes=tuple(planes))


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
